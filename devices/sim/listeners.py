"""Who wants to hear of a device's changes: a thread-safe list of callbacks with unsubscribe."""
from __future__ import annotations

import threading
from typing import Callable, Generic, TypeVar

T = TypeVar("T")


class Listeners(Generic[T]):
    def __init__(self) -> None:
        self._callbacks: list[Callable[[T], None]] = []
        self._lock = threading.Lock()

    def add(self, callback: Callable[[T], None]) -> Callable[[], None]:
        """Keep `callback`; returns the function that drops it again."""
        with self._lock:
            self._callbacks.append(callback)

        def unsubscribe() -> None:
            with self._lock:
                if callback in self._callbacks:
                    self._callbacks.remove(callback)
        return unsubscribe

    def now(self) -> list[Callable[[T], None]]:
        """The callbacks at this moment (call them outside any lock)."""
        with self._lock:
            return list(self._callbacks)
