"""Publishing a device's moving state: at most `rate` times per wall second while it changes, and at once on `flush()`.

A motion changes a device's state hundreds of times per simulated second; observers want it
smooth but not flooded, and they must see the final value before the action's reply (so `flush()`
runs in the handler, after the motion). Used by the robot Things and the pan-tilt units.
"""
from __future__ import annotations

import logging
import threading
from typing import Any, Callable

from mesh.fabric.server import ExposedThing

log = logging.getLogger(__name__)


class StatePublisher:
    """Publishes the observable properties `read()` returns (name -> value) when they change."""

    def __init__(self, thing: ExposedThing, read: Callable[[], dict[str, Any]], rate: float = 20.0):
        self.thing, self.read, self.period = thing, read, 1.0 / rate
        self._dirty, self._stop = threading.Event(), threading.Event()
        self._lock = threading.Lock()
        self._last: dict[str, Any] = {}
        self._thread = threading.Thread(target=self._loop, name=f"{thing.name}-state", daemon=True)

    def changed(self) -> None:
        """Something moved (any thread, cheap: the stepping thread calls it)."""
        self._dirty.set()

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        self._dirty.set()
        self._thread.join(timeout=2)

    def flush(self) -> None:
        """Publish every value that differs from the last one published, now."""
        with self._lock:
            for name, value in self.read().items():
                if name not in self._last or self._last[name] != value:
                    self.thing.emit_property_change(name, value)
                    self._last[name] = value

    def _loop(self) -> None:
        while not self._stop.is_set():
            if not self._dirty.wait(0.5):
                continue
            self._dirty.clear()
            if self._stop.is_set():
                return
            try:
                self.flush()
            except Exception:  # a closing session
                if self._stop.is_set():
                    return
                log.exception("%s: publishing the state failed", self.thing.name)
            self._stop.wait(self.period)
