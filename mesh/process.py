"""A mesh process's life: a stop event set by SIGINT/SIGTERM, and its name in `ps`.

Every long-running part (router, adapter, recorder, a device) runs `target(settings, stop, ...)` and
returns when `stop` is set; whoever starts it (a terminal, the lab's supervisor) installs the handlers.
"""
from __future__ import annotations

import faulthandler
import importlib.abc
import importlib.machinery
import logging
import os
import signal
import sys
import threading
from contextlib import contextmanager
from typing import Any, Iterator, NoReturn


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


def install_stop_handlers(signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> StopEvent:
    """A stop event set by `signals`, SIGINT and SIGTERM unless told (call from the main thread); set here
    also where the process was started with SIGINT ignored (a script's `cmd &`). SIGUSR1 prints where every
    thread of the process is to stderr: for a process that does not stop (`kill -USR1 PID`).

    The handler itself only writes a byte to a pipe; a watcher thread sets the event. A handler runs
    in the main thread between two bytecodes, possibly while that thread holds the event's own lock
    (inside `stop.wait()`), and setting the event there would wait for that lock forever."""
    signal.signal(signal.SIGUSR1, _dump_threads)
    stop = StopEvent()
    read_end, write_end = os.pipe()
    os.set_blocking(write_end, False)

    def watch() -> None:
        os.read(read_end, 1)
        stop.set()

    def handle(*_: Any) -> None:
        try:
            os.write(write_end, b"!")
        except BlockingIOError:  # the pipe is full of earlier signals: the watcher has its byte
            pass

    threading.Thread(target=watch, name="stop-signal", daemon=True).start()
    for sig in signals:
        signal.signal(sig, handle)
    return stop


def _dump_threads(*_: Any) -> None:
    """Every thread's stack to stderr. From a Python-level handler, with the GIL held: faulthandler's own
    handler reads the other threads' frames while they run, and a dump in a fresh clone's test run
    stopped half-way through a thread that was busy in Python code."""
    faulthandler.dump_traceback(file=sys.stderr, all_threads=True)


def set_title(role: str) -> None:
    """Name this process in `ps`/`top` as `twinmesh: <role>` (instead of `python -c from multiprocessing...`)."""
    from setproctitle import setproctitle

    setproctitle(f"twinmesh: {role}")


# --- pybullet's import banner -------------------------------------------------------------------


@contextmanager
def _descriptor_silenced(fd: int) -> Iterator[None]:
    saved = os.dup(fd)
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, fd)
        yield
    finally:
        os.dup2(saved, fd)
        os.close(saved)
        os.close(devnull)


class _SilentLoader(importlib.abc.Loader):
    def __init__(self, loader: Any):
        self.loader = loader

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> Any:
        with _descriptor_silenced(2):
            return self.loader.create_module(spec)

    def exec_module(self, module: Any) -> None:
        with _descriptor_silenced(2):
            self.loader.exec_module(module)


class _QuietImports(importlib.abc.MetaPathFinder):
    NAMES = frozenset({"pybullet"})

    def find_spec(self, name: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if name not in self.NAMES or os.environ.get(SHOW_NATIVE) == "1":
            return None
        for finder in sys.meta_path:
            if finder is self or not hasattr(finder, "find_spec"):
                continue
            spec = finder.find_spec(name, path, target)
            if spec is not None:
                if spec.loader is not None:
                    spec.loader = _SilentLoader(spec.loader)
                return spec
        return None


SHOW_NATIVE = "TWINMESH_SHOW_NATIVE_OUTPUT"  # "1" (`twinmesh -v`, inherited by every child): let pybullet speak


def end_now(code: int = 0) -> NoReturn:
    """End this process at once, its Zenoh sessions unclosed: the OS closes every link together, and each
    other end sees its socket close at once, which ends the session there as a close would (its
    liveliness tokens and declarations go). For the processes that hold thousands of links (a
    router, a fleet's devices): closing them one by one costs a router O(N) per link (Zenoh's link
    bookkeeping walks every transport), so a lab of 10,000 did not stop within seconds."""
    logging.shutdown()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except (OSError, ValueError):
            pass
    os._exit(code)


def run_quietly(payload: bytes) -> None:
    """A spawned child's start: pybullet quiet first, then `fn(*args)` from `payload` (pickled `(fn, args)`).
    Pickled as bytes, the arguments are unpickled only now: unpickled by spawn itself, before any code of
    ours runs, they would import pybullet loudly (a Robot, a scene, a real device's guard)."""
    import pickle

    quiet_pybullet_import()
    fn, args = pickle.loads(payload)
    fn(*args)


def quiet_pybullet_import() -> None:
    """pybullet prints its build time to stderr when it loads: not when twinmesh loads it (unless the
    environment says SHOW_NATIVE=1, as `twinmesh -v` does for itself and its children)."""
    if "pybullet" not in sys.modules and not any(isinstance(f, _QuietImports) for f in sys.meta_path):
        sys.meta_path.insert(0, _QuietImports())
