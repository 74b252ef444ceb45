"""Any TD as a virtual Thing on the mesh: served from its TD alone, before its hardware or model exists.

Interface-level simulation, as Eclipse Thingweb's shadow-thing does it: every value the Thing gives
(a property read, an action's output, an event's data) is built from the affordance's own data
schema and is valid by it (`mesh.wot.schema_values`); initial values are the schema's `const`,
`default`, `enum` or `examples` where given. Every schema is prepared before the Thing is exposed
(`prepare`, also run by the CLI before anything starts): a TD with a schema no value can be given
for is refused at start, naming its JSON pointer, and no read, answer or event fails afterwards.
Writable properties keep what was written (checked first, as for every Thing) and publish the
change; read-only numeric properties may drift within their bounds (`drift`) so that dashboards
see life; every event fires every `events_every` s with valid data; an action checks its input and
answers a valid output, or nothing when the TD declares none. The served TD is the original, forms
aside (`mesh.fabric.server.ExposedThing` keeps every term); names that are no key chunk are escaped
on the wire (`mesh.wot.names`).
"""
from __future__ import annotations

import logging
import threading
import zlib
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Any, Callable

from mesh.fabric.keys import Keys
from mesh.fabric.server import ExposedThing
from mesh.wot.schema_values import NoValue, SchemaValues

log = logging.getLogger(__name__)

DRIFT_EVERY = 1.0  # s between drifts of the read-only numeric properties


@dataclass(frozen=True)
class VirtualSpec:
    """What to serve: the name on the mesh, where the TD came from, and the TD."""

    name: str
    source: str
    td: dict[str, Any]


def schema_of(affordance: dict[str, Any]) -> dict[str, Any]:
    """The data schema of a property affordance (the affordance itself, forms aside)."""
    return {k: v for k, v in affordance.items() if k != "forms"}


class VirtualThing:
    """One TD served with values from its schemas. `with VirtualThing(...)` exposes it and starts its life."""

    def __init__(self, session, spec: VirtualSpec, keys: Keys | None = None, seed: int | None = None,
                 drift: bool = False, events_every: float = 5.0):
        self.name, self.spec = spec.name, spec
        self.values = SchemaValues(None if seed is None else seed ^ zlib.crc32(spec.name.encode()))
        self.thing = ExposedThing(session, spec.td, spec.name, keys)
        self.drift, self.events_every = drift, events_every
        self._read_only: dict[str, Any] = {}
        self._lock = threading.Lock()
        self._stopping = threading.Event()
        self._threads: list[threading.Thread] = []
        self._bind()

    def _where(self, *path: str) -> str:
        return where(self.spec, *path)

    def _bind(self) -> None:
        td = self.spec.td
        for schema, path in schemas_of(td):
            self.values.prepare(schema, where(self.spec, *path))
        for prop, p in (td.get("properties") or {}).items():
            initial = self.values.initial(schema_of(p), self._where("properties", prop))
            if p.get("readOnly"):
                self._read_only[prop] = initial
                self.thing.on_read(prop, self._reader(prop))
            else:
                self.thing.state(prop, initial)
        for action, a in (td.get("actions") or {}).items():
            self.thing.on_action(action, self._answer(action, a.get("output")))

    def _reader(self, prop: str) -> Callable[[], Any]:
        def read() -> Any:
            with self._lock:
                return self._read_only[prop]
        return read

    def _answer(self, action: str, output: Any) -> Callable[[Any], Any]:
        def act(_input: Any) -> Any:
            if not isinstance(output, dict):
                return None
            with self._lock:
                return self.values.value(output, self._where("actions", action, "output"))
        return act

    # --- life -------------------------------------------------------------------------------------------
    def _drift(self) -> None:
        props = self.spec.td.get("properties") or {}
        while not self._stopping.wait(DRIFT_EVERY):
            for prop in self._read_only:
                with self._lock:
                    old = self._read_only[prop]
                    new = self.values.drift(schema_of(props[prop]), old)
                    self._read_only[prop] = new
                if new != old:
                    self.thing.emit_property_change(prop, new)

    def _fire(self) -> None:
        events = self.spec.td.get("events") or {}
        while not self._stopping.wait(self.events_every):
            for event, e in events.items():
                data = e.get("data")
                try:
                    with self._lock:
                        value = self.values.value(data, self._where("events", event, "data")) \
                            if isinstance(data, dict) else None
                except NoValue as problem:
                    log.warning("%s", problem)
                    continue
                try:
                    self.thing.emit_event(event, value)
                except Exception:  # one lost firing; the Thing's other events and later firings go on
                    log.exception("%s: event %s not emitted", self.name, event)

    def expose(self) -> "VirtualThing":
        self.thing.expose()
        if self.drift and self._read_only:
            self._threads.append(threading.Thread(target=self._drift, name=f"drift {self.name}", daemon=True))
        if self.events_every > 0 and self.spec.td.get("events"):
            self._threads.append(threading.Thread(target=self._fire, name=f"events {self.name}", daemon=True))
        for t in self._threads:
            t.start()
        return self

    def destroy(self) -> None:
        self._stopping.set()
        for t in self._threads:
            t.join(timeout=5)
        self.thing.destroy()

    def __enter__(self) -> "VirtualThing":
        return self.expose()

    def __exit__(self, *exc: Any) -> None:
        self.destroy()


def schemas_of(td: dict[str, Any]) -> list[tuple[Any, tuple[str, ...]]]:
    """Every schema a virtual Thing gives values of, with its path in the TD: properties, action
    outputs, event data."""
    out: list[tuple[Any, tuple[str, ...]]] = []
    for kind, key in (("properties", None), ("actions", "output"), ("events", "data")):
        for name, a in (td.get(kind) or {}).items():
            if not isinstance(a, dict):
                continue
            schema = schema_of(a) if key is None else a.get(key)
            if isinstance(schema, (dict, bool)) and (key is None or key in a):
                out.append((schema, (kind, name) if key is None else (kind, name, key)))
    return out


def where(spec: VirtualSpec, *path: str) -> str:
    """`NAME (SOURCE): /json/pointer` of a schema in the Thing's TD."""
    pointer = "".join("/" + p.replace("~", "~0").replace("/", "~1") for p in path)
    return f"{spec.name} ({spec.source}): {pointer}"


def prepare(specs: list[VirtualSpec], seed: int | None = None) -> None:
    """Prepare every schema of every Thing before anything starts: a schema no value can be given for
    is NoValue naming the Thing, the JSON pointer and why, and none of them starts. The values are
    prepared from the schemas alone (not the seed), so the process that serves them finds the same."""
    values = SchemaValues(seed)
    for spec in specs:
        for schema, path in schemas_of(spec.td):
            values.prepare(schema, where(spec, *path))


def run(settings: Any, stop: threading.Event, specs: list[VirtualSpec], seed: int | None = None,
        drift: bool = False, events_every: float = 5.0, ready: Callable[[], None] | None = None) -> None:
    """Serve the virtual Things, each on its own session, until `stop` is set."""
    from mesh.fabric.session import open_session

    with ExitStack() as stack:
        for spec in specs:
            session = stack.enter_context(open_session(settings, thing=spec.name))
            stack.enter_context(VirtualThing(session, spec, settings.keys, seed, drift, events_every))
            log.info("virtual %s (%s) from %s", spec.name, spec.td.get("title"), spec.source)
        if ready is not None:
            ready()
        stop.wait()
