"""A mesh process's life: a stop event set by SIGINT/SIGTERM, and its name in `ps`.

Every long-running part (router, adapter, recorder, a device) runs `target(settings, stop, ...)` and
returns when `stop` is set; whoever starts it (a terminal, the lab's supervisor) installs the handlers.
"""
from __future__ import annotations

import signal
import threading


class StopEvent(threading.Event):
    """An Event whose untimed wait wakes up every 0.2 s.

    Signals often land on one of Zenoh's native threads; Python runs its handler only when the
    main thread next wakes, so a main thread blocked forever in `wait()` would never see Ctrl-C.
    """

    def wait(self, timeout: float | None = None) -> bool:
        if timeout is not None:
            return super().wait(timeout)
        while not super().wait(0.2):
            pass
        return True


def install_stop_handlers() -> StopEvent:
    """A stop event set by SIGINT and SIGTERM (call from the main thread)."""
    stop = StopEvent()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    return stop


def set_title(role: str) -> None:
    """Name this process in `ps`/`top` as `twinmesh: <role>` (instead of `python -c from multiprocessing...`)."""
    from setproctitle import setproctitle

    setproctitle(f"twinmesh: {role}")
