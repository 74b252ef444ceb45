"""Real labs for tests: `twinmesh up` (or any twinmesh command) as a subprocess on free loopback ports.

Every process is started in its own process group and stopped with SIGINT, like a user's Ctrl-C;
`Lab.stop()` reports whether anything had to be killed, so tests can assert a clean shutdown.
"""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import httpx

from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings

REPO = Path(__file__).resolve().parents[1]
# the Things of the `iot-platform` scene (the real lab's devices' twins and the world)
PLATFORM_THINGS = frozenset({"dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2",
                             "color-sensor", "uarm", "world"})


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _hangups_reach_children() -> None:
    """Labs die with whoever started them (`up`'s own rule), unless hang-ups are ignored, as under `nohup`:
    then `up` takes itself for detached on purpose and outlives a killed test run. A handler here (which
    does nothing) is reset to the default in every child, so the labs of a test run follow it anyway."""
    if signal.getsignal(signal.SIGHUP) is signal.SIG_IGN:
        try:
            signal.signal(signal.SIGHUP, lambda signum, frame: None)
        except ValueError:  # not the main thread: nothing to change from here
            pass


def twinmesh_cmd(endpoint: str, *args: str) -> list[str]:
    return [sys.executable, "-m", "devices", "--connect", endpoint, *args]


@dataclass
class Lab:
    """A running `twinmesh up`: its Zenoh endpoint, HTTP base URL and process."""

    endpoint: str
    http: str | None
    proc: subprocess.Popen
    log: Path
    extra: list[subprocess.Popen] = field(default_factory=list)
    tmp: Path | None = None  # where a test keeps the lab's logs and its robots'
    options: tuple[str, ...] = ()  # global options every command of this lab takes (`--secrets DIR`)

    def cli(self, *args: str, timeout: float = 60, check: bool = False) -> subprocess.CompletedProcess:
        """Run a one-shot `twinmesh` command against this lab."""
        return subprocess.run(twinmesh_cmd(self.endpoint, *self.options, *args), capture_output=True, text=True,
                              timeout=timeout, check=check, cwd=REPO)

    def cli_args(self, *args: str) -> list[str]:
        """The command line of a `twinmesh` command against this lab (to start it yourself)."""
        return twinmesh_cmd(self.endpoint, *self.options, *args)

    def spawn(self, *args: str, log: Path | None = None) -> subprocess.Popen:
        """Start another long-running twinmesh process (a device, a recorder) on this lab's mesh."""
        out = open(log, "wb") if log else subprocess.DEVNULL
        _hangups_reach_children()
        p = subprocess.Popen(twinmesh_cmd(self.endpoint, *self.options, *args), stdout=out, stderr=subprocess.STDOUT,
                             cwd=REPO, start_new_session=True)
        self.extra.append(p)
        return p

    def wait_ready(self, limit: float = 1200.0) -> None:
        """`twinmesh wait`, what a user's script does, for as long as the lab runs and says what it still
        waits for: no fixed time (a busy machine only makes it slower); `limit` is a last resort."""
        deadline = time.monotonic() + limit
        while True:
            try:
                ready = self.cli("wait", "--timeout", "20", timeout=120)
                said = ready.stderr
                if ready.returncode == 0:
                    return
            except subprocess.TimeoutExpired:  # `wait` itself slow to start on a loaded machine: ask again
                said = "`twinmesh wait` did not answer within 120 s"
            if self.proc.poll() is not None or time.monotonic() > deadline:
                why = "the lab exited" if self.proc.poll() is not None else f"not ready after {limit:.0f} s"
                raise AssertionError(f"{why}: {said}\n--- lab log ---\n{self.log.read_text()[-4000:]}")

    def wait_things(self, names: set[str], timeout: float = 120.0) -> list[str]:
        """Poll `twinmesh things` until all `names` are listed (start-up of spawned processes)."""
        deadline = time.monotonic() + timeout
        listed: list[str] = []
        while time.monotonic() < deadline:
            r = self.cli("things", timeout=15)
            listed = r.stdout.split()
            if names <= set(listed):
                return listed
            time.sleep(0.2)
        raise AssertionError(f"things {sorted(names - set(listed))} not listed within {timeout} s; "
                             f"listed {listed}\n--- lab log ---\n{self.log.read_text()[-4000:]}")

    def wait_http(self, path: str = "/things", timeout: float = 120.0) -> None:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                if httpx.get(self.http + path, timeout=2).status_code < 500:
                    return
            except httpx.HTTPError:
                pass
            time.sleep(0.2)
        raise AssertionError(f"adapter not serving {path} within {timeout} s\n{self.log.read_text()[-4000:]}")

    def stop_extra(self, timeout: float = 30.0) -> bool:
        """Ctrl-C what was started on this lab's mesh (`spawn`), not the lab: a shared lab is handed back
        as it was lent. True when every one exited on its own."""
        clean = True
        while self.extra:
            clean &= stop_process(self.extra.pop(), timeout)
        return clean

    def stop(self, timeout: float = 30.0) -> bool:
        """Ctrl-C everything; True when every process exited on its own."""
        clean = True
        for p in [*self.extra, self.proc]:
            clean &= stop_process(p, timeout)
        return clean


class SharedLab:
    """A lab that modules borrow in turn (conftest's session labs): started on first use, stopped by `close`
    once no module will borrow it again (the last module of its unit of work is done) or with the session.
    An idle lab with a physics world still steps it in real time, a tenth of a core or more."""

    def __init__(self, start: Callable[[], Lab], name: str):
        self._start, self.name = start, name
        self.lab: Lab | None = None

    def get(self) -> Lab:
        if self.lab is None:
            self.lab = self._start()
        return self.lab

    def close(self) -> None:
        lab, self.lab = self.lab, None
        if lab is not None:
            assert lab.stop(), f"{self.name} did not stop cleanly on Ctrl-C"


def interrupt(p: subprocess.Popen, log: Path, hang: float = 10.0) -> None:
    """Ctrl-C a process and assert that it ended on its own with exit code 0 (`hang` only
    detects a hang; it is no timing goal: those live in tests/bench)."""
    os.killpg(p.pid, signal.SIGINT)
    try:
        p.wait(hang)
    finally:
        stopped_alone = stop_process(p)
    assert stopped_alone and p.returncode == 0, f"exit {p.returncode} after Ctrl-C\n{log.read_text()[-3000:]}"


def stop_process(p: subprocess.Popen, timeout: float = 15.0, sig: int = signal.SIGINT) -> bool:
    """Stop `p`'s process group with `sig` (Ctrl-C) and wait; True if it stopped by itself within `timeout`,
    else its threads' stacks go to its log and the group is killed. Only processes that handle `sig`
    themselves stop on SIGINT wherever the tests run: a run started in the background by a script (`cmd &`)
    hands its children SIGINT ignored, and a process that takes Python's or node's default keeps it ignored."""
    if p.poll() is not None:
        return True
    os.killpg(p.pid, sig)
    try:
        p.wait(timeout)
        return True
    except subprocess.TimeoutExpired:
        os.kill(p.pid, signal.SIGUSR1)  # its threads' stacks to its log: where it is stuck
        time.sleep(2.0)
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        return False


def start_lab(tmp: Path, scene: str | None = "lights", http: bool = True, things: set[str] | None = None,
              extra_args: tuple[str, ...] = (), view: bool = False, options: tuple[str, ...] = ()) -> Lab:
    """Start `twinmesh up SCENE` (None: `twinmesh up`, the default scene) on free ports and wait until it serves.
    The live 3D view only when asked (`view`: on a free port; its URL is in the lab's ready line). A port found
    free can be taken by another process before the lab binds it: then the lab starts again on other ports."""
    for attempt in range(3):
        try:
            return _start_lab(tmp, scene, http, things, extra_args, view, options)
        except Exception:
            log = tmp / f"lab-{scene or 'default'}.log"
            taken = log.exists() and "address already in use" in log.read_text(errors="replace").lower()
            if not taken or attempt == 2:
                raise
    raise AssertionError("unreachable")


def _start_lab(tmp: Path, scene: str | None, http: bool, things: set[str] | None, extra_args: tuple[str, ...],
               view: bool, options: tuple[str, ...]) -> Lab:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    port = free_port()
    args = ["up", *([scene] if scene else []), *extra_args] + (["--http", f"127.0.0.1:{port}"] if http else ["--no-http"])
    args += ["--view", f"127.0.0.1:{free_port()}"] if view else ["--no-view"]
    log = tmp / f"lab-{scene or 'default'}.log"
    _hangups_reach_children()
    proc = subprocess.Popen(twinmesh_cmd(endpoint, *options, *args), stdout=open(log, "wb"), stderr=subprocess.STDOUT,
                            cwd=REPO, start_new_session=True, env={**os.environ, "PYTHONUNBUFFERED": "1"})
    lab = Lab(endpoint, f"http://127.0.0.1:{port}" if http else None, proc, log, options=options)
    try:
        lab.wait_ready()
        if things:
            lab.wait_things(things)
        if http:
            lab.wait_http()
    except BaseException:
        lab.stop()
        raise
    return lab


def start_robot_lab(tmp: Path) -> Lab:
    """`twinmesh up lights` with the adapter and a fresh tdgen cache in `tmp`: a lab for robots to join
    (`lab.tmp` is `tmp`, for their logs)."""
    lab = start_lab(tmp, "lights", http=True, things={"light-left", "light-right", "tdgen"},
                    extra_args=("--tdgen-cache", str(tmp / "cache")))
    lab.tmp = tmp
    return lab


def spawn_up(endpoint: str, log: Path, *args: str) -> subprocess.Popen:
    """`twinmesh up ARGS` on `endpoint` in its own process group, output to `log` (no waiting); the live 3D
    view on a free port unless ARGS say otherwise."""
    if "--view" not in args and "--no-view" not in args:
        args = (*args, "--view", f"127.0.0.1:{free_port()}")
    _hangups_reach_children()
    return subprocess.Popen(twinmesh_cmd(endpoint, "up", *args), stdout=open(log, "wb"), stderr=subprocess.STDOUT,
                            cwd=REPO, start_new_session=True)


def wait_ready(endpoint: str, timeout: float = 60) -> subprocess.CompletedProcess:
    """`twinmesh wait` against `endpoint`, as a user's script does after `twinmesh up &`."""
    return subprocess.run(twinmesh_cmd(endpoint, "wait", "--timeout", str(timeout)), capture_output=True, text=True,
                          timeout=timeout + 30, cwd=REPO)


@contextmanager
def mesh_client(endpoint: str) -> Iterator[MeshClient]:
    """A client-mode Zenoh consumer of the lab at `endpoint`, for tests that talk to Things directly."""
    settings = MeshSettings(mode="client", connect=(endpoint,))
    with open_session(settings) as session:
        yield MeshClient(session, settings)
