"""Run a lab as separate processes (spawned, never forked), restart what crashes, stop them all cleanly.

Each process runs `target(settings, stop, **kwargs)`; SIGINT/SIGTERM set `stop`, the target
closes its sessions and returns. The supervisor forwards Ctrl-C/SIGTERM, waits, then escalates
(terminate, kill) so that no process is left behind. A process that ends on its own while the lab
runs is started again, after a pause that doubles with each crash (`RESTART_BACKOFF`), while the
others keep serving; one that crashes `MAX_CRASHES` times within `CRASH_WINDOW` seconds stops the
lab. A restarted world starts from its scene's initial state.
"""
from __future__ import annotations

import logging
import multiprocessing as mp
import os
import pickle
import signal
import threading
import time
from dataclasses import dataclass, field
from multiprocessing.process import BaseProcess
from typing import Any, Callable

import msgspec

from mesh.backoff import pause_after
from mesh.fabric.settings import MeshSettings
from mesh.process import StopEvent, install_stop_handlers, run_quietly, set_title

log = logging.getLogger(__name__)


SAME_CTRL_C = 1.0  # s a child's exit may precede the lab's own stop signal and still be part of it
RESTART_BACKOFF = (0.5, 8.0)  # s before a crashed process starts again: first pause, longest pause
MAX_CRASHES, CRASH_WINDOW = 5, 60.0  # this many crashes of one process within this many seconds stop the lab


Entry = Callable[..., None]  # entry(settings, stop, **kwargs): a module-level function (spawn pickles it by name)


@dataclass(frozen=True)
class ProcessSpec:
    """One process of a lab: a name and the function it runs (devices.lab.entries) with keyword arguments.

    `role` is what `ps` shows after `twinmesh: ` (default: the name), e.g. `world iot-lab`."""

    name: str
    target: Entry
    kwargs: dict[str, Any] = field(default_factory=dict)
    role: str = ""


def die_with_parent(parent: int, grace: float | None = None) -> None:
    """Ask Linux to send SIGTERM to this process when its parent dies, however it dies (`kill -9`
    included): no orphan keeps the lab's ports after `up` is gone. Elsewhere a no-op. A process still
    there `grace` s after (default ORPHAN_GRACE) ends itself."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGTERM, 0, 0, 0)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        return
    if os.getppid() != parent:  # it died before we asked
        os.kill(os.getpid(), signal.SIGTERM)
    threading.Thread(target=_orphan_watchdog, args=(parent, ORPHAN_GRACE if grace is None else grace),
                     name="orphan-watchdog", daemon=True).start()


ORPHAN_GRACE = 1.5  # s an orphaned process has to stop cleanly (sessions, a recording's footer) before it is ended


def _orphan_watchdog(parent: int, grace: float) -> None:
    """The SIGTERM above asks for a clean stop; if the process is still there `grace` seconds after its
    parent died (a session close that hangs), it ends itself: no orphan holds a port for long."""
    while os.getppid() == parent:
        time.sleep(0.25)
    time.sleep(grace)
    os._exit(1)


def follows_its_starter() -> bool:
    """Whether a lab started now should end with the process that started it: not when that is the
    service manager (PID 1: systemd, a container's init) or when hang-ups are ignored (`nohup`)."""
    return os.getppid() != 1 and signal.getsignal(signal.SIGHUP) is not signal.SIG_IGN


def _child(spec: ProcessSpec, settings_json: bytes, log_level: int, parent: int) -> None:
    die_with_parent(parent)
    set_title(spec.role or spec.name)
    logging.basicConfig(level=log_level, format=f"%(asctime)s {spec.name} %(levelname)s %(message)s")
    stop = install_stop_handlers()
    settings = msgspec.json.decode(settings_json, type=MeshSettings)
    spec.target(settings, stop, **spec.kwargs)


class Supervisor:
    """Starts specs in order, watches them, and stops them all on request or on a signal."""

    def __init__(self, settings: MeshSettings, specs: list[ProcessSpec], grace: float = 5.0):
        self.settings = settings
        self.specs = specs
        self.grace = grace
        self.procs: dict[str, BaseProcess] = {}
        self.crashes: dict[str, list[float]] = {}  # per process, when it crashed (monotonic)
        self._ctx = mp.get_context("spawn")
        self.stop = StopEvent()

    def start(self) -> None:
        """Spawn every process; from here on SIGINT/SIGTERM set `self.stop` (call from the main thread)."""
        self.stop = install_stop_handlers()
        for spec in self.specs:
            self._spawn(spec)

    def _spawn(self, spec: ProcessSpec) -> None:
        payload = msgspec.json.encode(self.settings)
        level = logging.getLogger().getEffectiveLevel()
        args = (spec, payload, level, os.getpid())
        p = self._ctx.Process(target=run_quietly, args=(pickle.dumps((_child, args)),), name=spec.name, daemon=False)
        p.start()
        self.procs[spec.name] = p

    def dead(self) -> str | None:
        """A sentence naming a process that exited on its own, or None while all run."""
        for name, p in self.procs.items():
            if not p.is_alive():
                return f"process {name} exited (code {p.exitcode})"
        return None

    def run_until_stopped(self) -> int:
        """Block until a signal, restarting children that exit on their own, then stop all. Returns
        an exit code: 1 when a child kept crashing."""
        failed = ""
        due: dict[str, float] = {}  # crashed processes -> when they start again
        while not self.stop.wait(0.2):
            dead = [n for n, p in self.procs.items() if not p.is_alive() and n not in due]
            if dead and self.stop.wait(SAME_CTRL_C):  # a terminal's Ctrl-C reaches the children too, and
                break                                # one may end before our own handler has run
            now = time.monotonic()
            for name in dead:
                crashes = [t for t in self.crashes.get(name, []) if now - t < CRASH_WINDOW] + [now]
                self.crashes[name] = crashes
                code = self.procs[name].exitcode
                if len(crashes) >= MAX_CRASHES:
                    failed = name
                    log.error("process %s exited (code %s), its %d%s crash within %.0f s; stopping the lab",
                              name, code, len(crashes), _ordinal(len(crashes)), CRASH_WINDOW)
                    break
                pause = pause_after(len(crashes), *RESTART_BACKOFF)
                log.error("process %s exited (code %s); starting it again in %.1f s (crash %d of %d allowed "
                          "within %.0f s)", name, code, pause, len(crashes), MAX_CRASHES - 1, CRASH_WINDOW)
                due[name] = now + pause
            if failed:
                break
            for name, when in list(due.items()):
                if time.monotonic() >= when:
                    del due[name]
                    self._spawn(next(s for s in self.specs if s.name == name))
                    log.warning("process %s started again", name)
        self.shutdown()
        return 1 if failed else 0

    def shutdown(self) -> None:
        for p in self.procs.values():
            if p.is_alive():
                p.terminate()  # SIGTERM: the child sets its stop event and closes its sessions
        deadline = time.monotonic() + self.grace
        for p in self.procs.values():
            p.join(max(0.0, deadline - time.monotonic()))
        for p in self.procs.values():
            if p.is_alive():
                log.warning("process %s did not stop in %.0f s; killing it", p.name, self.grace)
                p.kill()
                p.join()


def _ordinal(n: int) -> str:
    return {1: "st", 2: "nd", 3: "rd"}.get(n if n < 20 else n % 10, "th")
