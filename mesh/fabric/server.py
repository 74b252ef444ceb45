"""The Thing runtime: serve one TD's affordances on Zenoh (the exposing side, like node-wot's ExposedThing).

Given a TD and handlers, `ExposedThing` serves the TD, each property (get = read, get with
payload = write), each action and each linked file on its key, publishes property changes and
events, and declares its liveliness token last, so that a Thing is never seen alive before it can
answer. It declares one queryable, `<prefix>/<thing>/**`, and routes each query by its key: a
router's work per declaration grows with the sessions it serves, so a fleet of thousands must not
declare one queryable per affordance. A wildcard query gets one reply per affordance key it
matches, each with its concrete key (reads only). Zenoh callbacks only hand queries to a worker
pool: handlers may block (a motion returns when it is over) without stalling the session.

An action's queryable also serves its asynchronous invocations (`mesh.wot.invocation`), told
apart by the selector's parameters:

| selector | what | reply |
|---|---|---|
| `<prefix>/<thing>/actions/<a>` (payload = input) | invoke, answer when done | the output |
| `...actions/<a>?async` (payload = input) | invoke, answer at once | its ActionStatus |
| `...actions/<a>?id=<id>` | query one invocation | its ActionStatus |
| `...actions/<a>?id=<id>;cancel` | cancel it (waits up to 5 s for it to stop) | its ActionStatus |
| `...actions/<a>?calls` (or `actions/*?calls`) | query all | a list of ActionStatus |

`wait=S` (up to 30 s) on `?async` or `?id=` makes the reply wait until the invocation ended or S
passed (a long poll); `sync` marks a caller that waits for the end anyway (`MeshClient.invoke`): the
invocation is not listed and is forgotten once its end was delivered. Every query is then short,
whatever the action's duration, so no Zenoh query state lives for minutes (it is held until the
query's timeout, not released at the reply). Invoking and cancelling act, so they need the exact
key; querying is a read, wildcards may.
"""
from __future__ import annotations

import logging
import re
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any, Callable

import msgspec

from mesh.fabric.keys import NAME, Keys, check_name, check_slug
from mesh.fabric.session import direct
from mesh.messages.lab import ActionCall
from mesh.messages.relations import TWIN
from mesh.wot.invocation import ID, Invocations
from mesh.wot.payload import decode_json
from mesh.wot.problem import BadInput, NotAllowed, NotFound, Problem
from mesh.wot.thing_description import ThingDescription, decode_td, keep_terms, zenoh_forms
from mesh.wot.validate import SourceSchemas, prepare, validate

log = logging.getLogger(__name__)

Read = Callable[[], Any]
Write = Callable[[Any], object]  # what it returns is ignored
Act = Callable[[Any], Any]
FileSource = Callable[[], bytes]
Route = tuple[str, Callable[..., Any], tuple[Any, ...]]  # (what it changes, its answer, the answer's arguments)

JSON_ENCODING = "application/json"
NO_INPUT = None


QUERY_WORKERS = 64   # per process: queries being answered at once (reads, writes, long polls of actions)
ACTION_WORKERS = 64  # per process: actions running at once (a motion holds one until it is over)
_shared: tuple[ThreadPoolExecutor, ThreadPoolExecutor] | None = None
_shared_lock = threading.Lock()


def shared_pools() -> tuple[ThreadPoolExecutor, ThreadPoolExecutor]:
    """The process's query and action workers, shared by all its Things: threads stay bounded (a fleet
    of 500 Things in a process keeps at most QUERY_WORKERS + ACTION_WORKERS of them, created on
    demand), not 16 per Thing."""
    global _shared
    with _shared_lock:
        if _shared is None:
            _shared = (ThreadPoolExecutor(max_workers=QUERY_WORKERS, thread_name_prefix="twinmesh-query"),
                       ThreadPoolExecutor(max_workers=ACTION_WORKERS, thread_name_prefix="twinmesh-action"))
        return _shared


class ExposedThing:
    """One Thing on the mesh. Register handlers, then `expose()`; `destroy()` (or `with`) undeclares."""

    def __init__(self, session, td: ThingDescription | dict[str, Any], name: str, keys: Keys | None = None):
        """`td` as a model, or as the JSON document itself: then every term of it is served, also those
        the model does not hold (an extension vocabulary's, say). Queries and actions run on the
        process's shared workers (`shared_pools`)."""
        self.session = session
        self.name = check_slug(name)
        self.keys = keys or Keys()
        self._source = td if isinstance(td, dict) else None
        self.td = decode_td(td) if isinstance(td, dict) else td
        self._schemas = SourceSchemas(self._source)  # inputs checked against the whole schema the document states
        self._reads: dict[str, Read] = {}
        self._writes: dict[str, Write] = {}
        self._actions: dict[str, Act] = {}
        self._files: dict[str, tuple[FileSource, str]] = {}
        self._file_lookup: Callable[[str], tuple[bytes, str]] | None = None
        self._values: dict[str, Any] = {}
        self._lock = threading.Lock()
        # actions run on the second pool (synchronous calls are carried as asynchronous ones: MeshClient.invoke)
        self._pool, self._runner = shared_pools()
        self.invocations = Invocations(self._runner)
        self._declared: list[Any] = []
        self._routes: dict[str, Route] = {}
        self._route_keys: list[tuple[Any, str]] = []
        self._publishers: dict[str, Any] = {}
        self._td_json = b""
        self._exposed = False
        self._twin_token: Any = None

    # --- handlers -------------------------------------------------------------------------
    def on_read(self, prop: str, fn: Read) -> "ExposedThing":
        self._need("properties", prop)
        self._reads[prop] = fn
        return self

    def on_write(self, prop: str, fn: Write) -> "ExposedThing":
        self._need("properties", prop)
        self._writes[prop] = fn
        return self

    def on_action(self, action: str, fn: Act) -> "ExposedThing":
        self._need("actions", action)
        self._actions[action] = fn
        return self

    def wrap_action(self, action: str, wrap: Callable[[Act], Act]) -> "ExposedThing":
        """Replace the action's handler by `wrap(handler)` (a guard in front of a device's own handler)."""
        self._actions[action] = wrap(self._actions[action])
        return self

    def wrap_write(self, prop: str, wrap: Callable[[Write], Write]) -> "ExposedThing":
        self._writes[prop] = wrap(self._writes[prop])
        return self

    def on_file(self, name: str, source: FileSource, content_type: str) -> "ExposedThing":
        self._files[check_name(name)] = (source, content_type)
        return self

    def on_any_file(self, lookup: Callable[[str], tuple[bytes, str]]) -> "ExposedThing":
        """Serve every file name through one lookup, `name -> (bytes, content type)` (any
        `files/<name>` key), for Things whose files come and go (the tdgen service); raise NotFound for unknown
        names. Use instead of `on_file`, not with it."""
        self._file_lookup = lookup
        return self

    def state(self, prop: str, initial: Any) -> "ExposedThing":
        """Back a property by a stored value: reads return it, writes store it and publish the change."""
        self._need("properties", prop)
        self._values[prop] = initial
        self._reads[prop] = lambda: self.value(prop)
        self._writes[prop] = lambda v: self.set_value(prop, v)
        return self

    def value(self, prop: str) -> Any:
        with self._lock:
            return self._values[prop]

    def set_value(self, prop: str, value: Any) -> bool:
        """Store a state-backed property; publish it if it changed. Returns whether it changed."""
        with self._lock:
            changed = self._values.get(prop, object()) != value
            self._values[prop] = value
        if changed:
            self.emit_property_change(prop, value)
        return changed

    # --- publications -------------------------------------------------------------------
    def emit_property_change(self, prop: str, value: Any) -> None:
        self._publish(self.keys.property(self.name, prop), value)

    def emit_event(self, event: str, data: Any = None) -> None:
        self._need("events", event)
        self._publish(self.keys.event(self.name, event), data)

    def _truthful(self, td: ThingDescription) -> ThingDescription:
        """The TD as the handlers serve it: a property nobody writes is `readOnly` (its forms then offer
        no writeproperty), one nobody reads `writeOnly`, so a TD never offers what no handler does."""
        props = {}
        for name, p in td.properties.items():
            read_only = True if name not in self._writes else p.readOnly
            write_only = True if name not in self._reads else p.writeOnly
            props[name] = msgspec.structs.replace(p, readOnly=read_only, writeOnly=write_only)
        return msgspec.structs.replace(td, properties=props)

    def update_td(self, td: ThingDescription) -> None:
        """Replace the TD (e.g. a regenerated robot TD) and tell observers of `<thing>/td`."""
        td = self._truthful(td)
        self.td = td
        self._td_json = self._served_td()
        if self._exposed:
            self._mark_twin()
            self.session.put(self.keys.td(self.name), self._td_json, encoding=JSON_ENCODING)

    def _mark_twin(self) -> None:
        """Hold the twin token (`Keys.twin`) while the TD links a twin: the services that work on twins
        follow these tokens, not every Thing's TD."""
        links = any(link.rel == TWIN for link in self.td.links)
        if links and self._twin_token is None:
            self._twin_token = self.session.liveliness().declare_token(self.keys.twin(self.name))
        elif not links and self._twin_token is not None:
            self._twin_token.undeclare()
            self._twin_token = None

    def _served_td(self) -> bytes:
        served = zenoh_forms(self.td, self.keys.prefix, self.name)
        return msgspec.json.encode(keep_terms(self._source, served.to_dict())) if self._source else served.to_json()

    def _publish(self, key: str, value: Any) -> None:
        if not self._exposed:
            return
        pub = self._publishers.get(key)
        if pub is None:
            pub = self._publishers[key] = self.session.declare_publisher(key, encoding=JSON_ENCODING)
        pub.put(msgspec.json.encode(value))

    # --- lifecycle ----------------------------------------------------------------------
    def expose(self) -> "ExposedThing":
        missing = [p for p in self.td.properties if p not in self._reads and not self.td.properties[p].writeOnly]
        missing += [a for a in self.td.actions if a not in self._actions]
        if missing:
            raise ValueError(f"{self.name}: no handler for {', '.join(missing)}")
        self.td = self._truthful(self.td)
        self._td_json = self._served_td()
        prepare(self.td)
        import zenoh

        k = self.keys
        routes: dict[str, Route] = {k.td(self.name): ("", self._answer_td, ())}
        routes.update({k.property(self.name, p): ("with-payload", self._answer_property, (p,))
                       for p in self.td.properties})
        routes.update({k.action(self.name, a): ("action", self._answer_action, (a,)) for a in self.td.actions})
        routes.update({k.file(self.name, f): ("", self._answer_file, (f,)) for f in self._files})
        self._routes = routes
        self._route_keys = [(zenoh.KeyExpr(key), key) for key in routes]
        self._declared.append(self.session.declare_queryable(f"{k.alive(self.name)}/**", direct(self._route)))
        self._exposed = True
        self._declared.append(self.session.liveliness().declare_token(k.alive(self.name)))
        self._mark_twin()
        return self

    def destroy(self) -> None:
        self._exposed = False
        if self._twin_token is not None:
            self._declared.append(self._twin_token)
            self._twin_token = None
        for d in reversed(self._declared):
            try:
                d.undeclare()
            except Exception:  # the session may already be closing
                pass
        self._declared.clear()
        for pub in self._publishers.values():
            try:
                pub.undeclare()
            except Exception:
                pass
        self._publishers.clear()
        self.invocations.cancel_all()

    def __enter__(self) -> "ExposedThing":
        return self.expose()

    def __exit__(self, *exc) -> None:
        self.destroy()

    # --- query handling -----------------------------------------------------------------------
    def _route(self, query) -> None:  # runs on a Zenoh thread: never block here
        """The key's route (`acts` says when a query changes something: "with-payload", writes;
        "action", all but status queries; only a query on exactly that key may); a wildcard query
        gets every route it matches; a file name through `on_any_file`'s lookup; else no reply."""
        asked = str(query.key_expr)
        route = self._routes.get(asked)
        if route is not None:
            self._pool.submit(self._serve, query, [(asked, route)])
            return
        if "*" in asked or "$" in asked:
            matched = [(key, self._routes[key]) for expr, key in self._route_keys if query.key_expr.intersects(expr)]
            if matched:
                self._pool.submit(self._serve, query, matched)
                return
        else:
            parsed = self.keys.parse(asked)
            lookup = self._file_lookup
            if lookup is not None and parsed is not None and parsed.thing == self.name and parsed.kind == "files" \
                    and NAME.match(parsed.name):
                name = parsed.name
                self._pool.submit(self._serve, query, [(asked, ("", lambda _payload: lookup(name), ()))])
                return
        query.drop()  # nothing of this Thing's: no reply

    def _serve(self, query, routes: list[tuple[str, Route]]) -> None:  # a worker thread
        try:
            for key, (acts, answer, args) in routes:
                if not self._exposed:  # destroyed while the query waited for a worker: no reply
                    return
                self._answer(query, key, acts, answer, args)
        finally:
            query.drop()

    def _answer(self, query, key: str, acts: str, answer, args) -> None:
        try:
            payload = query.payload.to_bytes() if query.payload is not None else None
            asked = str(query.key_expr)
            params = dict(query.parameters) if acts == "action" else {}
            reads = acts == "action" and ("calls" in params or "id" in params and "cancel" not in params)
            if asked != key and (acts == "action" and not reads or acts == "with-payload" and payload is not None):
                raise BadInput(f"{key}: writes and actions run only for a query on their exact key, not on "
                               f"{asked}")
            out = answer(payload, *args, params) if acts == "action" else answer(payload, *args)
            out, encoding = out if isinstance(out, tuple) else (out, JSON_ENCODING)
            query.reply(key, out if out is not None else b"", encoding=encoding)  # the concrete key answers
        except Problem as p:
            query.reply_err(p.to_json(), encoding="application/problem+json")
        except Exception as e:  # a device bug must still answer, not time out
            log.exception("%s: handler failed", self.name)
            query.reply_err(Problem(f"{type(e).__name__}: {e}").to_json(), encoding="application/problem+json")

    def _answer_td(self, payload: bytes | None) -> bytes:
        return self._td_json

    def _answer_property(self, payload: bytes | None, prop: str) -> bytes | None:
        aff = self.td.properties[prop]
        if payload is None:
            if aff.writeOnly or prop not in self._reads:
                raise NotAllowed(f"property {prop!r} of {self.name} is not readable")
            return msgspec.json.encode(self._reads[prop]())
        if aff.readOnly or prop not in self._writes:
            raise NotAllowed(f"property {prop!r} of {self.name} is read-only")
        value = decode_json(payload, f"the value for {prop!r}")
        validate(value, self._schemas.of(aff, "properties", prop), path=prop)
        self._writes[prop](value)
        return None

    def _answer_action(self, payload: bytes | None, action: str, params: dict[str, str]) -> bytes | None:
        if "calls" in params:
            return msgspec.json.encode(self.invocations.all(action))
        if "id" in params:
            id = params["id"]
            if not re.fullmatch(ID, id) or self.invocations.get(id).action != action:
                raise NotFound(f"{action!r} of {self.name} has no invocation {id!r}")
            if "cancel" in params:
                return msgspec.json.encode(self.invocations.cancel(id))
            return msgspec.json.encode(self.invocations.wait(id, _wait(params)))
        value = self._checked_input(action, payload)
        if "async" in params:
            started = self.invocations.start(action, lambda: self._perform(action, value), hidden="sync" in params)
            wait = _wait(params)
            return msgspec.json.encode(self.invocations.wait(started.id, wait) if wait > 0 else started)
        out = self._perform(action, value)
        return None if out is None else msgspec.json.encode(out)

    def _checked_input(self, action: str, payload: bytes | None) -> Any:
        """The action's input from the payload, valid by the TD (BadInput otherwise)."""
        aff = self.td.actions[action]
        value = None
        if aff.input is None and payload is not None and payload.strip() not in (b"", b"null"):
            raise BadInput(f"action {action!r} takes no input; send none (or null)")
        if aff.input is not None:
            if not payload:
                raise BadInput(f"action {action!r} needs an input")
            value = decode_json(payload, f"the input of {action!r}")
            validate(value, self._schemas.of(aff.input, "actions", action, "input"), path="input")
        return value

    def _perform(self, action: str, value: Any) -> Any:
        """Run the handler; the call goes out on the action's key (for recorders) either way."""
        started = time.monotonic()
        try:
            out = self._actions[action](value)
        except Problem as p:
            self._publish_call(action, ActionCall(input=value, error=str(p), status=p.status,
                                                  seconds=time.monotonic() - started))
            raise
        self._publish_call(action, ActionCall(input=value, output=out, seconds=time.monotonic() - started))
        return out

    def _publish_call(self, action: str, call: "ActionCall") -> None:
        """Tell observers of the mesh (the recorder) that an action ran: a put on the action's key."""
        self._publish(self.keys.action(self.name, action), call)

    def _answer_file(self, payload: bytes | None, name: str) -> tuple[bytes, str]:
        source, content_type = self._files.get(name, (None, ""))
        if source is None:
            raise NotFound(f"{self.name} has no file {name!r}")
        return source(), content_type

    def _need(self, kind: str, name: str) -> None:
        if name not in getattr(self.td, kind):
            raise ValueError(f"{self.name}: the TD has no {kind[:-1] if kind != 'properties' else 'property'} {name!r}")


MAX_WAIT = 30.0  # s a status query may wait for the end


def _wait(params: dict[str, str]) -> float:
    raw = params.get("wait", "0")
    try:
        seconds = float(raw)
    except ValueError:
        raise BadInput(f"wait must be a number of seconds, not {raw!r}") from None
    if not 0 <= seconds <= MAX_WAIT:  # also refuses nan and inf
        raise BadInput(f"wait must be within 0..{MAX_WAIT:g} s, not {raw!r}")
    return seconds
