"""A remote Thing on the mesh under a name: an ExposedThing serving the remote TD (every term, our forms)
whose handlers forward to the remote Thing, and whose changes and events come from it.

Changes reach the mesh three ways, by what the remote TD offers: an observeproperty form (SSE or
long-poll) is followed; an event's subscribeevent form likewise; every other readable property is
read every `poll` seconds and published when it changed (the real uArm's `location` is observable
only over MQTT). Each observation is kept alive: a remote Thing that stops answering is logged once,
its affordances answer 503 meanwhile, and the bridge subscribes again once it answers."""
from __future__ import annotations

import logging
import threading
from functools import partial
from typing import Any, Callable

from mesh.bridge.remote import RemoteThing
from mesh.fabric.keys import Keys
from mesh.fabric.server import ExposedThing
from mesh.wot.consumed import NOTHING, Callback, Subscription
from mesh.wot.problem import NotAllowed, Problem

log = logging.getLogger(__name__)

RETRY_FIRST, RETRY_MAX = 0.5, 8.0  # s between attempts to subscribe again, doubling


class Feed:
    """One observation of the remote Thing, subscribed again (with back-off) whenever it breaks."""

    def __init__(self, subscribe: Callable[[Callback], Subscription], deliver: Callback, what: str,
                 stopping: threading.Event):
        self._subscribe, self._deliver, self.what = subscribe, deliver, what
        self._stopping = stopping
        self._broken = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"feed {what}", daemon=True)

    def start(self) -> "Feed":
        self._thread.start()
        return self

    def _got(self, value: Any) -> None:
        if isinstance(value, BaseException):
            self._broken.set()
        else:
            self._deliver(value)

    def _run(self) -> None:
        wait = RETRY_FIRST
        while not self._stopping.is_set():
            self._broken.clear()
            try:
                sub = self._subscribe(self._got)
            except Problem:
                self._stopping.wait(wait)
                wait = min(wait * 2, RETRY_MAX)
                continue
            wait = RETRY_FIRST
            while not (self._stopping.is_set() or self._broken.wait(0.5)):
                pass
            sub.stop()
            if not self._stopping.is_set():
                self._stopping.wait(RETRY_FIRST)

    def join(self, timeout: float) -> None:
        if self._thread.is_alive():
            self._thread.join(timeout)


class BridgedThing:
    """`remote` served on the mesh as `name`. `with BridgedThing(...)` exposes it and starts its feeds."""

    def __init__(self, session, name: str, remote: RemoteThing, source_td: dict[str, Any],
                 keys: Keys | None = None, poll: float = 1.0):
        self.name, self.remote, self.poll = name, remote, poll
        self.thing = ExposedThing(session, source_td, name, keys)
        self._stopping = threading.Event()
        self._feeds: list[Feed] = []
        self._polled: list[str] = []
        self._last: dict[str, Any] = {}
        self._answering = True
        self._bind()

    def _bind(self) -> None:
        td, remote = self.remote.td, self.remote
        for prop, p in td.properties.items():
            if remote.can("properties", prop, "readproperty"):
                self.thing.on_read(prop, self._reader(prop))
                if remote.can("properties", prop, "observeproperty"):
                    self._feeds.append(Feed(partial(remote.observe, prop), partial(self._changed, prop),
                                            f"{self.name}/{prop}", self._stopping))
                else:
                    self._polled.append(prop)
            elif not p.writeOnly:
                self.thing.on_read(prop, self._unreadable(prop))
            if remote.can("properties", prop, "writeproperty") and not p.readOnly:
                self.thing.on_write(prop, self._writer(prop))
        for action, a in td.actions.items():
            self.thing.on_action(action, self._invoker(action, a.input is not None))
        for event in td.events:
            if remote.can("events", event, "subscribeevent"):
                self._feeds.append(Feed(partial(remote.subscribe, event), partial(self.thing.emit_event, event),
                                        f"{self.name}/{event}", self._stopping))

    def _invoker(self, action: str, takes_input: bool) -> Callable[[Any], Any]:
        def invoke(value: Any) -> Any:
            return self.remote.invoke(action, value if takes_input else NOTHING)
        return invoke

    def _reader(self, prop: str) -> Callable[[], Any]:
        def read() -> Any:
            value = self.remote.read(prop)
            self._remember(prop, value)
            return value
        return read

    def _unreadable(self, prop: str) -> Callable[[], Any]:
        def read() -> Any:
            raise NotAllowed(f"{self.remote.title} offers no http(s) form to read {prop!r}")
        return read

    def _writer(self, prop: str) -> Callable[[Any], None]:
        def write(value: Any) -> None:
            self.remote.write(prop, value)
            self._changed(prop, value)
        return write

    def _remember(self, prop: str, value: Any) -> None:
        if prop in self._polled:
            self._changed(prop, value)

    def _changed(self, prop: str, value: Any) -> None:
        if self._last.get(prop, NOTHING) != value:
            self._last[prop] = value
            self.thing.emit_property_change(prop, value)

    def _poll(self) -> None:
        while not self._stopping.wait(self.poll):
            for prop in self._polled:
                try:
                    self._changed(prop, self.remote.read(prop))
                    self._answered(True, None)
                except Problem as p:
                    self._answered(False, p)
                    break

    def _answered(self, answering: bool, problem: Problem | None) -> None:
        if answering != self._answering:
            self._answering = answering
            if answering:
                log.warning("%s: %s answers again", self.name, self.remote.host)
            else:
                log.warning("%s: %s", self.name, problem)

    def expose(self) -> "BridgedThing":
        self.thing.expose()
        for feed in self._feeds:
            feed.start()
        if self._polled and self.poll > 0:
            threading.Thread(target=self._poll, name=f"poll {self.name}", daemon=True).start()
        return self

    def destroy(self) -> None:
        self._stopping.set()
        for feed in self._feeds:
            feed.join(6)
        self.thing.destroy()

    def __enter__(self) -> "BridgedThing":
        return self.expose()

    def __exit__(self, *exc: Any) -> None:
        self.destroy()
