"""A registry without a mesh, for the adapter's routes under Starlette's TestClient.

`mesh.http.app.create_app(registry)` takes the registry it serves as a parameter; this one holds
its Things in memory and keeps the real registry's contract that the routes rely on: 404 for an
unknown Thing, 503 (with the same wording) for one that left or while the adapter shuts down, a
device's refusal (any `Problem` a handler raises) passed through unchanged, changes fanned out by
the real `Observers`. What it does not do is Zenoh: that part is the lab tests'.
"""
from __future__ import annotations

import time
import uuid
from collections.abc import Callable
from contextlib import AbstractContextManager
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any

import msgspec

from mesh.fabric.mesh_client import Reply
from mesh.fabric.settings import MeshSettings
from mesh.http.gateway import DIRECTORY
from mesh.http.observers import Change, Feed, Observers
from mesh.http.problems import unavailable
from mesh.wot.invocation import ActionStatus
from mesh.wot.problem import Conflict, NotFound
from mesh.wot.thing_description import ThingDescription, decode_td, thing_id
from mesh.wot.validate import SourceSchemas


def _now() -> str:
    return datetime.now(timezone.utc).isoformat(timespec="milliseconds").replace("+00:00", "Z")


@dataclass
class FakeThing:
    """A Thing as a device would serve it: its TD, its property values, action handlers, files."""

    td: ThingDescription
    schemas: SourceSchemas
    values: dict[str, Any] = field(default_factory=dict)
    actions: dict[str, Callable[[Any], Any]] = field(default_factory=dict)
    readers: dict[str, Callable[[], Any]] = field(default_factory=dict)
    files: dict[str, tuple[bytes, str]] = field(default_factory=dict)
    invocations: dict[str, ActionStatus] = field(default_factory=dict)
    alive: bool = True


class FakeRegistry:
    """The part of `mesh.http.gateway.Registry` the routes use, over in-memory Things."""

    def __init__(self) -> None:
        self.settings = MeshSettings()
        self.keys = self.settings.keys
        self.observers = Observers(16)
        self.things: dict[str, FakeThing] = {}
        self.closing = False
        self.started = self.closed = False
        self.writes: list[tuple[str, str, Any]] = []  # what reached the "device", in order
        self.cache: dict[tuple[str, str], bytes] = {}  # what `cached` answers (the fast path)

    # --- set-up by the tests
    def add(self, td: dict[str, Any], **kwargs: Any) -> FakeThing:
        td.setdefault("id", thing_id(td["title"]))
        thing = FakeThing(decode_td(td), SourceSchemas(td), **kwargs)
        self.things[td["title"]] = thing
        return thing

    def publish(self, thing: str, kind: str, name: str, value: Any) -> None:
        """A property change or an event, as the mesh would deliver it (call on the app's loop)."""
        self.observers.publish(thing, kind, Change(name, msgspec.json.encode(value), time.time()))

    def leave(self, thing: str) -> None:
        self.things[thing].alive = False
        self.observers.thing_left(thing)

    # --- lifecycle (the app's lifespan)
    async def start(self) -> None:
        self.started = True

    def begin_shutdown(self) -> None:
        self.closing = True
        self.observers.close_all()

    async def close(self) -> None:
        self.closed = True

    # --- what the routes call
    def _entry(self, thing: str) -> FakeThing:
        if self.closing:
            raise unavailable("the adapter is shutting down", retry_after=1)
        found = self.things.get(thing)
        if found is None:
            raise NotFound(f"no Thing {thing!r} on the mesh")
        if not found.alive:
            raise unavailable(f"{thing} has left the mesh")
        return found

    def names(self) -> list[str]:
        return sorted(n for n, t in self.things.items() if t.alive)

    def known_tds(self) -> dict[str, ThingDescription]:
        return {n: t.td for n, t in sorted(self.things.items())}

    async def td(self, thing: str) -> ThingDescription:
        return self._entry(thing).td

    def schemas(self, thing: str) -> SourceSchemas:
        return self._entry(thing).schemas

    def render(self, thing: str, base: str, make: Callable[[ThingDescription, dict | None], bytes]) -> bytes:
        return make(self._entry(thing).td, None)

    def cached(self, thing: str, prop: str) -> bytes | None:
        return self.cache.get((thing, prop))

    async def read(self, thing: str, prop: str) -> bytes:
        entry = self._entry(thing)
        if prop in entry.readers:
            return msgspec.json.encode(entry.readers[prop]())
        return msgspec.json.encode(entry.values.get(prop))

    async def write(self, thing: str, prop: str, payload: bytes) -> None:
        entry = self._entry(thing)
        value = msgspec.json.decode(payload)
        if prop in entry.actions:  # a device-side check (a refusal), keyed by the property's name
            entry.actions[prop](value)
        self.writes.append((thing, prop, value))
        entry.values[prop] = value

    async def invoke(self, thing: str, action: str, payload: bytes | None) -> bytes:
        entry = self._entry(thing)
        out = entry.actions[action](None if payload is None else msgspec.json.decode(payload))
        return b"" if out is None else msgspec.json.encode(out)

    async def invoke_async(self, thing: str, action: str, payload: bytes | None) -> ActionStatus:
        entry = self._entry(thing)
        status = ActionStatus(uuid.uuid4().hex, action, "running", _now(), timeStarted=_now())
        entry.invocations[status.id] = status
        return status

    async def query_action(self, thing: str, action: str, id: str) -> ActionStatus:
        found = self._entry(thing).invocations.get(id)
        if found is None or found.action != action:
            raise NotFound(f"{action!r} of {thing} has no invocation {id!r}")
        return found

    async def cancel_action(self, thing: str, action: str, id: str) -> ActionStatus:
        status = await self.query_action(thing, action, id)
        if status.status != "running":
            raise Conflict(f"invocation {id} has already ended ({status.status})", extra={"status": status.status})
        done = msgspec.structs.replace(status, status="cancelled", timeEnded=_now())
        self.things[thing].invocations[id] = done
        return done

    async def query_all_actions(self, thing: str) -> dict[str, list[ActionStatus]]:
        found: dict[str, list[ActionStatus]] = {}
        for status in self._entry(thing).invocations.values():
            found.setdefault(status.action, []).append(status)
        return found

    async def file(self, thing: str, name: str) -> Reply:
        entry = self._entry(thing)
        if name not in entry.files:
            raise NotFound(f"{thing} has no file {name!r}")
        payload, encoding = entry.files[name]
        return Reply(payload, encoding)

    def watch(self, thing: str, kind: str, names: list[str]) -> AbstractContextManager[Feed]:
        self._entry(thing)
        return self.observers.watch(thing, kind, names)


__all__ = ["DIRECTORY", "FakeRegistry", "FakeThing"]
