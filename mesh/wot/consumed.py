"""Consuming any Thing from its TD (the WoT Scripting API's ConsumedThing, in Python), protocol-neutral.

A `Consumer` holds one `ProtocolClient` per URI scheme (node-wot's servient: `mesh.http.http_client`
speaks http and https, `mesh.fabric.mesh_client.ZenohClient` zenoh) and gives a `ConsumedThing` for a
TD. For each operation the Thing takes the first form of the affordance whose `op` matches and
that a client accepts: node-wot's rule, so a TD's first form is what both clients use. Inputs and
written values are checked against the TD before they leave (400 without a round trip); errors
come back as `mesh.wot.problem.Problem`s whatever the protocol, so callers catch one thing.
"""
from __future__ import annotations

import queue
import re
import threading
import time
from typing import Any, Callable, Iterable, Protocol

import msgspec

from mesh.wot.invocation import FINISHED, ActionStatus
from mesh.wot.problem import BadInput, NotFound, Problem, TimedOut
from mesh.wot.thing_description import Form, ThingDescription, decode_td
from mesh.wot.validate import validate

NOTHING: Any = type("Nothing", (), {"__repr__": lambda self: "NOTHING"})()  # no input, unlike a JSON null
Callback = Callable[[Any], None]


class Subscription(Protocol):
    def stop(self) -> None:
        """End the observation or subscription; the callback is not called after it returns."""


class ProtocolClient(Protocol):
    """One binding's client side (node-wot's `ProtocolClient`): performs a form."""

    schemes: tuple[str, ...]

    def accepts(self, form: Form, op: str) -> bool:
        """Whether this client can perform `op` with `form` (an SSE form, say, but not a long-poll one)."""

    def fetch_td(self, url: str) -> dict[str, Any]: ...

    def read(self, form: Form) -> Any: ...

    def write(self, form: Form, value: Any) -> None: ...

    def invoke(self, form: Form, input: Any) -> Any:
        """Perform an invokeaction form; `input` is NOTHING for an action without input."""

    def invoke_async(self, form: Form, input: Any) -> ActionStatus: ...

    def query_action(self, href: str) -> ActionStatus: ...

    def cancel_action(self, href: str) -> ActionStatus | None:
        """The status once it stopped, or None when the Thing only said it did (HTTP 204)."""

    def read_multiple(self, form: Form, names: list[str]) -> dict[str, Any]: ...

    def query_all_actions(self, form: Form) -> dict[str, list[ActionStatus]]: ...

    def observe(self, form: Form, callback: Callback) -> Subscription:
        """Call `callback(value)` for each change or event; registered when this returns."""

    def close(self) -> None: ...


class NothingArrived(TimedOut, queue.Empty):
    """`Inbox.get` found nothing in time: a Problem like every consumer error, and still the
    `queue.Empty` that callers of a queue catch."""

    title = "Nothing arrived in time"


class Inbox:
    """A callback that queues what it is given: `get(timeout)` the next value (`NothingArrived` after
    `timeout` s), raising a Problem a broken stream reported instead of a value.

    An observation brings changes only: a property that already has the awaited value sends nothing,
    so read it after observing starts and wait only when it differs."""

    def __init__(self) -> None:
        self.queue: queue.Queue = queue.Queue()

    def __call__(self, value: Any) -> None:
        self.queue.put(value)

    def get(self, timeout: float) -> Any:
        try:
            item = self.queue.get(timeout=timeout)
        except queue.Empty:
            raise NothingArrived(f"no change or event arrived within {timeout:g} s (an observation brings changes "
                                 "only: a property that already had its value sends none; read it first)") from None
        if isinstance(item, BaseException):
            raise item
        return item


def ops(form: Form) -> list[str]:
    return form.ops()


def scheme(href: str) -> str:
    return href.split(":", 1)[0].lower()


class Invocation:
    """An asynchronous invocation: ask how it is going, wait for its end, or cancel it."""

    def __init__(self, thing: "ConsumedThing", status: ActionStatus, client: ProtocolClient, query: str,
                 cancel: str | None):
        self.thing, self.status, self._client, self._query, self._cancel = thing, status, client, query, cancel

    @property
    def id(self) -> str:
        return self.status.id

    def query(self) -> ActionStatus:
        self.status = self._client.query_action(self._query)
        return self.status

    def wait(self, timeout: float | None = None, poll: float = 0.05) -> Any:
        """The output once it completed; its problem raised if it failed or was cancelled."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while self.status.status not in FINISHED:
            if deadline is not None and time.monotonic() > deadline:
                raise TimedOut(f"{self.status.action} ({self.id}) still {self.status.status} after {timeout:g} s")
            time.sleep(poll)
            poll = min(poll * 1.5, 0.5)
            self.query()
        if self.status.status != "completed":
            raise _problem_of(self.status)
        return self.status.output

    def cancel(self) -> ActionStatus:
        """Stop it where it is; its final status (409 Conflict if it had already ended)."""
        if self._cancel is None:
            raise NotFound(f"{self.thing.title}: {self.status.action} has no cancelaction form")
        status = self._client.cancel_action(self._cancel)
        self.status = status if status is not None else self._client.query_action(self._query)
        return self.status


def _problem_of(status: ActionStatus) -> Problem:
    """The problem a failed or cancelled invocation ended with, as the class its status maps to."""
    if not status.error:
        return Problem(f"{status.action} ended {status.status}")
    return Problem.from_json(msgspec.json.encode(status.error))


class ConsumedThing:
    """A Thing as its TD describes it, driven through the consumer's protocol clients."""

    def __init__(self, td: dict[str, Any], clients: Iterable[ProtocolClient]):
        self.source = td
        self.td: ThingDescription = decode_td(td)
        self.title = self.td.title
        self._clients = list(clients)
        self._owned: Consumer | None = None

    def owns(self, consumer: "Consumer") -> None:
        """Close `consumer` (its clients) with this Thing: for a Thing consumed on its own."""
        self._owned = consumer

    def close(self) -> None:
        if self._owned is not None:
            self._owned.close()

    def __enter__(self) -> "ConsumedThing":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # --- properties ----------------------------------------------------------------------------------
    def read_property(self, name: str) -> Any:
        client, form = self._form("properties", name, "readproperty")
        return client.read(form)

    def write_property(self, name: str, value: Any) -> None:
        client, form = self._form("properties", name, "writeproperty")
        validate(value, self.td.properties[name], path=name)
        client.write(form, value)

    def read_multiple_properties(self, names: Iterable[str]) -> dict[str, Any]:
        """Through the Thing's readmultipleproperties form where it has one, else one read each."""
        names = list(names)
        for name in names:
            self._affordance("properties", name)
        found = self._thing_form("readmultipleproperties")
        if found is None:
            return {n: self.read_property(n) for n in names}
        values = found[0].read_multiple(found[1], names)
        return {n: values[n] for n in names if n in values}

    def read_all_properties(self) -> dict[str, Any]:
        readable = [n for n, p in self.td.properties.items() if not p.writeOnly]
        return self.read_multiple_properties(readable)

    def observe_property(self, name: str, callback: Callback) -> Subscription:
        client, form = self._form("properties", name, "observeproperty")
        return client.observe(form, callback)

    # --- actions ------------------------------------------------------------------------------------
    def invoke_action(self, name: str, input: Any = NOTHING) -> Any:
        """Invoke through the first invokeaction form (synchronous on twinmesh: the answer is the output)."""
        client, form = self._form("actions", name, "invokeaction")
        return client.invoke(form, self._input(name, input))

    def invoke_action_async(self, name: str, input: Any = NOTHING) -> Invocation:
        """Start the action through its asynchronous form; the Invocation queries and cancels it."""
        affordance = self._affordance("actions", name)
        value = self._input(name, input)
        for client, form in self._candidates(affordance.forms, "invokeaction"):
            if _asynchronous(form):
                status = client.invoke_async(form, value)
                query = self._status_href(affordance.forms, "queryaction", status, client)
                cancel = self._status_href(affordance.forms, "cancelaction", status, client)
                if query is None:
                    raise NotFound(f"{self.title}: {name} has an asynchronous form but no queryaction form")
                return Invocation(self, status, client, query, cancel)
        raise NotFound(f"{self.title}: {name} cannot be invoked asynchronously (no such form)")

    def query_all_actions(self) -> dict[str, list[ActionStatus]]:
        found = self._thing_form("queryallactions")
        if found is None:
            raise NotFound(f"{self.title} offers no queryallactions form")
        return found[0].query_all_actions(found[1])

    # --- events ---------------------------------------------------------------------------------------
    def subscribe_event(self, name: str, callback: Callback) -> Subscription:
        client, form = self._form("events", name, "subscribeevent")
        return client.observe(form, callback)

    # --- forms ----------------------------------------------------------------------------------------
    def _affordance(self, kind: str, name: str) -> Any:
        found = self.td.affordance(kind, name)  # type: ignore[arg-type]
        if found is None:
            raise NotFound(self.td.no_such(self.title, kind, name))  # type: ignore[arg-type]
        return found

    def _candidates(self, forms: list[Form], op: str):
        for form in forms:
            if op in ops(form):
                for client in self._clients:
                    if scheme(form.href) in client.schemes and client.accepts(form, op):
                        yield client, form
                        break

    def _form(self, kind: str, name: str, op: str) -> tuple[ProtocolClient, Form]:
        affordance = self._affordance(kind, name)
        for found in self._candidates(affordance.forms, op):
            return found
        have = sorted({scheme(f.href) for f in affordance.forms if op in ops(f)})
        raise NotFound(f"{self.title}: {name} has no {op} form this consumer can use"
                       + (f" (it offers {', '.join(have)})" if have else ""))

    def _thing_form(self, op: str) -> tuple[ProtocolClient, Form] | None:
        return next(self._candidates(self.td.forms or [], op), None)

    def _status_href(self, forms: list[Form], op: str, status: ActionStatus, client: ProtocolClient) -> str | None:
        if op == "queryaction" and status.href and scheme(status.href) in client.schemes:
            return status.href  # the Thing said where (HTTP: the Location)
        for form in forms:
            if op in ops(form) and scheme(form.href) in client.schemes:
                return re.sub(r"\{id\}", status.id, form.href)
        return None

    def _input(self, name: str, input: Any) -> Any:
        action = self._affordance("actions", name)
        if action.input is not None:
            if input is NOTHING:
                raise BadInput(f"{self.title}: {name} needs an input")
            validate(input, action.input, path="input")
        return input


def _asynchronous(form: Form) -> bool:
    """The invokeaction form that answers at once with a status: 201 by its response, or `?async`."""
    return (form.response or {}).get("htv:statusCodeValue") == 201 or re.search(r"[?;&]async\b", form.href) is not None


class Consumer:
    """The protocol clients of one program, and the Things it consumes through them.

    `thing(name)` resolves a name with `resolve` (a Thing URL on an adapter, or a mesh name) and
    keeps the ConsumedThing; `close()` closes the clients it was given."""

    def __init__(self, clients: Iterable[ProtocolClient], resolve: Callable[[str], str] | None = None):
        self.clients = list(clients)
        self._resolve = resolve or (lambda name: name)
        self._things: dict[str, ConsumedThing] = {}
        self._lock = threading.Lock()

    def consume(self, td: dict[str, Any] | str) -> ConsumedThing:
        """A TD as a dict, or where to fetch it: a URL a client speaks."""
        if isinstance(td, str):
            for client in self.clients:
                if scheme(td) in client.schemes:
                    td = client.fetch_td(td)
                    break
            else:
                raise NotFound(f"no client for {td!r} (this consumer speaks "
                               f"{', '.join(s for c in self.clients for s in c.schemes)})")
        return ConsumedThing(td, self.clients)

    def thing(self, name: str) -> ConsumedThing:
        with self._lock:
            found = self._things.get(name)
        if found is None:
            found = self.consume(self._resolve(name))
            with self._lock:
                self._things[name] = found
        return found

    def close(self) -> None:
        for client in self.clients:
            client.close()

    def __enter__(self) -> "Consumer":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()
