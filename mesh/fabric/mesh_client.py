"""The consuming side: read, write, invoke, observe and subscribe by affordance name over Zenoh.

Used by the CLI, the HTTP adapter, the recorder and the workflows. Error replies come back as the
same `Problem` the device raised; no reply at all becomes 503 when the Thing is gone from the
mesh and 504 when it is alive but did not answer in time.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import msgspec

from mesh.fabric.directory import Directory
from mesh.fabric.keys import Keys
from mesh.fabric.settings import MeshSettings
from mesh.wot.consumed import NOTHING, Callback
from mesh.wot.invocation import FINISHED, ID, ActionStatus
from mesh.wot.payload import JSON_ERRORS
from mesh.wot.problem import BadGateway, NotFound, Problem, TimedOut, Unavailable
from mesh.wot.thing_description import AffordanceKind, Form, ThingDescription, decode_td

POLL = 2.0  # s one status query of a synchronous invocation waits for its end, at most


@dataclass
class Reply:
    """A raw reply: the payload bytes and the encoding the peer gave them."""

    payload: bytes
    encoding: str


class MeshClient:
    """A consumer bound to one open session."""

    def __init__(self, session, settings: MeshSettings | None = None):
        self.session = session
        self.settings = settings or MeshSettings()
        # a Directory the owner keeps (the adapter, tdgen): who is alive is known without asking the
        # router, which lists every token of the mesh to answer one liveliness query
        self.presence: Directory | None = None
        self.keys: Keys = self.settings.keys

    # --- discovery ---------------------------------------------------------------------
    def things(self, timeout: float = 2.0) -> list[str]:
        """Names of the Things alive now, sorted."""
        return sorted(self.iter_things(timeout))

    def iter_things(self, timeout: float = 2.0) -> Iterator[str]:
        """Names of the Things alive now, each as soon as its answer arrives (a fleet of thousands streams)."""
        seen = set()
        for r in self.session.liveliness().get(self.keys.all_alive(), timeout=timeout):
            if r.ok is not None:
                parsed = self.keys.parse(str(r.ok.key_expr))
                if parsed and parsed.kind == "alive" and parsed.thing not in seen:
                    seen.add(parsed.thing)
                    yield parsed.thing

    def is_alive(self, thing: str, timeout: float = 1.0) -> bool:
        if self.presence is not None:
            return self.presence.is_alive(thing)
        return any(r.ok is not None for r in self.session.liveliness().get(self.keys.alive(thing), timeout=timeout))

    # --- raw requests ------------------------------------------------------------------
    def request(self, key: str, payload: bytes | None = None, timeout: float | None = None,
                thing: str | None = None, what: tuple[AffordanceKind, str] | None = None,
                parameters: str = "") -> Reply:
        """One query, one reply; Problems for errors, silence and timeouts.

        `what` (kind, name) is the affordance the key stands for: when a live Thing does not answer
        at once, its TD tells whether it has that affordance at all (404 listing what it has).
        `parameters` go into the selector (`key?parameters`).
        """
        timeout = self.settings.query_timeout if timeout is None else timeout
        started = time.monotonic()
        kwargs: dict[str, Any] = {"timeout": timeout}
        if payload is not None:
            kwargs["payload"] = payload
        for r in self.session.get(f"{key}?{parameters}" if parameters else key, **kwargs):
            if r.ok is not None:
                return Reply(r.ok.payload.to_bytes(), str(r.ok.encoding))
            err = r.err.payload.to_bytes()
            if str(r.err.encoding).startswith("application/problem+json"):
                raise Problem.from_json(err)
            if time.monotonic() - started >= timeout * 0.95:
                break  # Zenoh's own timeout error
            raise BadGateway(f"{key}: {err[:200].decode(errors='replace')}")
        elapsed = time.monotonic() - started
        parsed = self.keys.parse(key)
        name = thing or (parsed.thing if parsed else key)
        if not self.is_alive(name):
            raise Unavailable(f"{name} is not on the mesh", reason="not-on-mesh")
        if elapsed >= timeout * 0.95:
            raise TimedOut(f"{name} did not answer {key} within {timeout:g} s")
        if what is not None:  # alive, yet nothing serves the key: most likely a wrong name
            self.check_affordance(name, *what)
        # no such key, or a fresh peer session whose routes to the Thing are not there yet: retryable
        raise Unavailable(f"{name} did not answer {key}")

    # --- affordances -------------------------------------------------------------------
    def td(self, thing: str) -> ThingDescription:
        return decode_td(self.td_bytes(thing))

    def td_bytes(self, thing: str) -> bytes:
        return self.request(self.keys.td(thing), thing=thing).payload

    def check_affordance(self, thing: str, kind: AffordanceKind, name: str) -> Any:
        """The affordance from the Thing's TD; NotFound (naming what it has) if it has none of that name,
        Unavailable if the Thing is gone."""
        td = self.td(thing)
        found = td.affordance(kind, name)
        if found is None:
            raise NotFound(td.no_such(thing, kind, name))
        return found

    def read(self, thing: str, prop: str) -> Any:
        return _json(self.request(self.keys.property(thing, prop), thing=thing, what=("properties", prop)).payload)

    def write(self, thing: str, prop: str, value: Any) -> None:
        self.request(self.keys.property(thing, prop), msgspec.json.encode(value), thing=thing,
                     what=("properties", prop))

    def invoke(self, thing: str, action: str, input: Any = NOTHING, timeout: float | None = None) -> Any:
        """The action's output once it is over (its problem raised if it failed), within `timeout`
        (default: the settings' action timeout). Carried as an asynchronous invocation with long-poll
        queries of at most `POLL` s each, so that no Zenoh query lives as long as a robot's motion."""
        return self._invoke(thing, action, None if input is NOTHING else msgspec.json.encode(input), timeout)

    def invoke_bytes(self, thing: str, action: str, payload: bytes | None, timeout: float | None = None) -> bytes:
        """`invoke` with the input and the output as JSON bytes (b"" for none): the HTTP adapter's, whose
        input is already checked and encoded."""
        out = self._invoke(thing, action, payload, timeout)
        return b"" if out is None else msgspec.json.encode(out)

    def _invoke(self, thing: str, action: str, payload: bytes | None, timeout: float | None) -> Any:
        timeout = self.settings.action_timeout if timeout is None else timeout
        deadline = time.monotonic() + timeout
        key = self.keys.action(thing, action)
        what: tuple[AffordanceKind, str] = ("actions", action)
        poll = min(POLL, timeout)
        status = self.decode_status(self.request(key, payload, poll + self.settings.query_timeout, thing=thing,
                                                 what=what, parameters=f"async;sync;wait={poll:g}").payload)
        while status.status not in FINISHED:
            left = deadline - time.monotonic()
            if left <= 0:
                raise TimedOut(f"{thing} did not finish {action} within {timeout:g} s (it is {status.status})")
            poll = min(POLL, left)
            status = self.decode_status(self.request(key, None, poll + self.settings.query_timeout, thing=thing,
                                                     what=what, parameters=f"id={status.id};wait={poll:g}").payload)
        if status.status != "completed":
            raise Problem.from_json(msgspec.json.encode(status.error or {}))
        return status.output

    # --- asynchronous actions (mesh.fabric.server's selectors) ---------------------------------------
    def invoke_async(self, thing: str, action: str, input: Any = NOTHING) -> ActionStatus:
        """Start the action; its status at once (`pending` or `running`); bad input is refused here."""
        payload = None if input is NOTHING else msgspec.json.encode(input)
        return self.decode_status(self.request(self.keys.action(thing, action), payload, thing=thing,
                                         what=("actions", action), parameters="async").payload)

    def query_action(self, thing: str, action: str, id: str) -> ActionStatus:
        return self.decode_status(self._by_id(thing, action, id, ""))

    def cancel_action(self, thing: str, action: str, id: str) -> ActionStatus:
        """Ask the invocation to stop; its status once it has (or after 5 s): 409 if it had already ended."""
        return self.decode_status(self._by_id(thing, action, id, ";cancel"))

    def query_all_actions(self, thing: str, timeout: float | None = None) -> dict[str, list[ActionStatus]]:
        """Every invocation the Thing keeps, by action (actions with none left out)."""
        out: dict[str, list[ActionStatus]] = {}
        replied = False
        key = f"{self.keys.action(thing, '*')}?calls"
        for r in self.session.get(key, timeout=self.settings.query_timeout if timeout is None else timeout):
            if r.ok is None:
                continue
            replied = True
            for status in msgspec.json.decode(r.ok.payload.to_bytes(), type=list[ActionStatus]):
                out.setdefault(status.action, []).append(status)
        if not replied and not self.is_alive(thing):
            raise Unavailable(f"{thing} is not on the mesh", reason="not-on-mesh")
        return out

    def _by_id(self, thing: str, action: str, id: str, extra: str) -> bytes:
        if not re.fullmatch(ID, id):  # never a ';' or wildcard into the selector
            raise NotFound(f"no invocation {id!r} (ids are 32 hex digits)")
        return self.request(self.keys.action(thing, action), thing=thing, what=("actions", action),
                            parameters=f"id={id}{extra}").payload

    @staticmethod
    def decode_status(payload: bytes) -> ActionStatus:
        try:
            return msgspec.json.decode(payload, type=ActionStatus)
        except (msgspec.DecodeError, msgspec.ValidationError):
            raise BadGateway(f"a peer replied with no action status: {payload[:100]!r}") from None

    def file(self, thing: str, name: str) -> Reply:
        return self.request(self.keys.file(thing, name), thing=thing)

    def observe(self, thing: str, prop: str, callback: Callable[[Any], None]):
        """Call `callback(value)` on each published change; returns the subscriber (undeclare to stop)."""
        return self.subscribe_key(self.keys.property(thing, prop), callback)

    def subscribe(self, thing: str, event: str, callback: Callable[[Any], None]):
        return self.subscribe_key(self.keys.event(thing, event), callback)

    def subscribe_key(self, key: str, callback: Callable[[Any], None]):
        return self.session.declare_subscriber(key, lambda s: callback(_json(s.payload.to_bytes())))


def _json(payload: bytes) -> Any:
    if not payload:
        return None
    try:
        return msgspec.json.decode(payload)
    except JSON_ERRORS:
        raise BadGateway(f"a peer replied with invalid JSON: {payload[:100]!r}") from None


class ZenohClient:
    """A `mesh.wot.consumed.ProtocolClient` for `zenoh:` forms (`zenoh:<key>[?parameters]`, as
    `mesh.fabric.server` serves them) on one open session."""

    schemes = ("zenoh",)

    def __init__(self, session, settings: MeshSettings | None = None):
        self.mesh = MeshClient(session, settings)

    def accepts(self, form: Form, op: str) -> bool:
        return True

    def _target(self, href: str) -> tuple[str, str, str]:
        """(key, parameters, thing) of a zenoh: href."""
        key, _, parameters = href.removeprefix("zenoh:").partition("?")
        parsed = self.mesh.keys.parse(key)
        return key, parameters, parsed.thing if parsed else key

    def _request(self, href: str, payload: bytes | None = None, timeout: float | None = None) -> bytes:
        key, parameters, thing = self._target(href)
        return self.mesh.request(key, payload, timeout, thing=thing, parameters=parameters).payload

    def fetch_td(self, url: str) -> dict[str, Any]:
        """`zenoh:<prefix>/<thing>` (or the TD's own key), or a bare Thing name."""
        key, _, thing = self._target(url if ":" in url else f"zenoh:{self.mesh.keys.td(url)}")
        td = _json(self.mesh.td_bytes(thing))
        if not isinstance(td, dict):
            raise BadGateway(f"{thing} serves no TD")
        return td

    def read(self, form: Form) -> Any:
        return _json(self._request(form.href))

    def write(self, form: Form, value: Any) -> None:
        self._request(form.href, msgspec.json.encode(value))

    def invoke(self, form: Form, input: Any) -> Any:
        """Through `MeshClient.invoke` (short long-poll queries), not one query as long as the action."""
        key = self._target(form.href)[0]
        parsed = self.mesh.keys.parse(key)
        if parsed is None or parsed.kind != "actions":
            raise BadGateway(f"{form.href} is no action's key")
        return self.mesh.invoke(parsed.thing, parsed.name, input)

    def invoke_async(self, form: Form, input: Any) -> ActionStatus:
        return self.mesh.decode_status(self._request(form.href, None if input is NOTHING else msgspec.json.encode(input)))

    def query_action(self, href: str) -> ActionStatus:
        return self.mesh.decode_status(self._request(href))

    def cancel_action(self, href: str) -> ActionStatus | None:
        return self.mesh.decode_status(self._request(href))

    def read_multiple(self, form: Form, names: list[str]) -> dict[str, Any]:
        raise NotFound("the Zenoh binding has no readmultipleproperties form")

    def query_all_actions(self, form: Form) -> dict[str, list[ActionStatus]]:
        return self.mesh.query_all_actions(self._target(form.href)[2])

    def observe(self, form: Form, callback: Callback) -> "ZenohSubscription":
        key, _, _ = self._target(form.href)
        return ZenohSubscription(self.mesh.subscribe_key(key, callback))

    def close(self) -> None:
        """The session is the caller's: it stays open."""


class ZenohSubscription:
    def __init__(self, subscriber: Any):
        self._subscriber = subscriber

    def stop(self) -> None:
        self._subscriber.undeclare()
