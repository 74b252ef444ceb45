"""Discovery: who is alive on the mesh, from liveliness tokens (join and leave as they happen)."""
from __future__ import annotations

import threading
from typing import Callable, Literal

from mesh.fabric.drain import Drained
from mesh.fabric.keys import Keys

Listener = Callable[[str], None]
CHANGES_WAITING = 1 << 16  # joins and leaves waiting for the directory's thread before Zenoh waits


class Directory:
    """Tracks the Things alive under a prefix and tells listeners about joins and leaves.

    Listeners run on the directory's own thread, in the order of the joins and leaves (none is
    dropped): they must not block (hand work to a thread or a loop). `tokens="twin"`: only the Things
    whose TD links a twin (`Keys.twin`), for a service with nothing to do for the others.
    """

    def __init__(self, session, keys: Keys, on_join: Listener | None = None, on_leave: Listener | None = None,
                 tokens: Literal["alive", "twin"] = "alive"):
        self.keys = keys
        self._kind = tokens
        self._alive: set[str] = set()
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self._on_join = on_join
        self._on_leave = on_leave
        followed = keys.all_alive() if tokens == "alive" else keys.all_twins()
        self._sub = Drained(lambda handler: session.liveliness().declare_subscriber(followed, handler, history=True),
                            self._samples, CHANGES_WAITING, False, "directory")

    def _samples(self, samples) -> None:
        for sample in samples:
            self._sample(sample)

    def _sample(self, sample) -> None:
        parsed = self.keys.parse(str(sample.key_expr))
        if parsed is None or parsed.kind != self._kind:
            return
        joined = str(sample.kind).endswith("PUT")
        with self._lock:
            if joined == (parsed.thing in self._alive):
                return
            (self._alive.add if joined else self._alive.discard)(parsed.thing)
            self._changed.notify_all()
        listener = self._on_join if joined else self._on_leave
        if listener:
            listener(parsed.thing)

    def alive(self) -> list[str]:
        with self._lock:
            return sorted(self._alive)

    def is_alive(self, thing: str) -> bool:
        with self._lock:
            return thing in self._alive

    def wait_for(self, things: list[str] | set[str], timeout: float) -> bool:
        """Block until all `things` are alive (for CLIs and tests, never in callbacks)."""
        with self._lock:
            return self._changed.wait_for(lambda: set(things) <= self._alive, timeout)

    def close(self) -> None:
        self._sub.undeclare()
