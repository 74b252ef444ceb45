"""The consuming side: read, write, invoke, observe and subscribe by affordance name over Zenoh.

Used by the CLI, the HTTP adapter, the recorder and the workflows. Error replies come back as the
same `Problem` the device raised; no reply at all becomes 503 when the Thing is gone from the
mesh and 504 when it is alive but did not answer in time.
"""
from __future__ import annotations

import re
import time
from dataclasses import dataclass
from typing import Any, Callable

import msgspec

from twinmesh.fabric.keys import Keys
from twinmesh.fabric.settings import MeshSettings
from twinmesh.wot.invocation import ID, ActionStatus
from twinmesh.wot.payload import JSON_ERRORS
from twinmesh.wot.problem import BadGateway, NotFound, Problem, TimedOut, Unavailable
from twinmesh.wot.td import AffordanceKind, ThingDescription, decode_td

NOTHING = object()  # "no input" for invoke, distinct from a JSON null input


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
        self.keys: Keys = self.settings.keys

    # --- discovery ---------------------------------------------------------------------
    def things(self, timeout: float = 2.0) -> list[str]:
        """Names of the Things alive now."""
        names = set()
        for r in self.session.liveliness().get(self.keys.all_alive(), timeout=timeout):
            if r.ok is not None:
                parsed = self.keys.parse(str(r.ok.key_expr))
                if parsed and parsed.kind == "alive":
                    names.add(parsed.thing)
        return sorted(names)

    def is_alive(self, thing: str, timeout: float = 1.0) -> bool:
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
        payload = None if input is NOTHING else msgspec.json.encode(input)
        timeout = self.settings.action_timeout if timeout is None else timeout
        return _json(self.request(self.keys.action(thing, action), payload, timeout, thing=thing,
                                  what=("actions", action)).payload)

    # --- asynchronous actions (twinmesh.fabric.server's selectors) ---------------------------------------
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
        return self._subscribe(self.keys.property(thing, prop), callback)

    def subscribe(self, thing: str, event: str, callback: Callable[[Any], None]):
        return self._subscribe(self.keys.event(thing, event), callback)

    def _subscribe(self, key: str, callback: Callable[[Any], None]):
        return self.session.declare_subscriber(key, lambda s: callback(_json(s.payload.to_bytes())))


def _json(payload: bytes) -> Any:
    if not payload:
        return None
    try:
        return msgspec.json.decode(payload)
    except JSON_ERRORS:
        raise BadGateway(f"a peer replied with invalid JSON: {payload[:100]!r}") from None
