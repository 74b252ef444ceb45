"""Replaying a recording: Rerun's own viewer on a `.rrd` file, in a browser or on the desktop.

A headless host has no display for Rerun's desktop viewer, so the default is its web viewer: the
`rerun` command of rerun-sdk serves the file over gRPC, this process serves the viewer's page
(`mesh.recorder.web_viewer`, the same page as the live view's), both on 127.0.0.1 unless asked
otherwise, and a browser opens the URL `url` gives. The recording holds its blueprint, so the
replay opens on the same tabs and views as the live view did.

Rerun's viewer collects usage data unless told not to. Every `rerun` this module starts runs with
`NO_USAGE_DATA` in its environment (`CI` set: Rerun sends nothing from a CI run; it checks no other
switch besides its per-user config file), and the web page may connect to nothing but this host's
ports, so nothing twinmesh starts sends any.
"""
from __future__ import annotations

import os
import socket
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

from mesh.recorder.repair import rerun_cli
from mesh.recorder.web_viewer import ViewerServer, viewer_url

NO_USAGE_DATA = {"CI": "1"}  # Rerun's analytics are off in a CI run (its `rerun analytics disable` is per user)
MAGIC = b"RRF2"  # the first bytes of every .rrd file
MIN_SERVER_MEMORY = 1 << 30  # bytes: the gRPC server holds the whole recording for the page
READY_TIMEOUT = 60.0


class ReplayError(Exception):
    """A replay that cannot start; the message names the problem."""


def rerun_env() -> dict[str, str]:
    """The environment for a `rerun` process twinmesh starts: this one, with Rerun's analytics off."""
    return {**os.environ, **NO_USAGE_DATA}


def check_recording(path: str | Path) -> Path:
    """`path` if it is a readable Rerun recording; else a ReplayError that says what it is instead."""
    path = Path(path)
    if not path.exists():
        raise ReplayError(f"{path}: no such file")
    if path.is_dir():
        raise ReplayError(f"{path} is a folder; give a .rrd file")
    try:
        with path.open("rb") as f:
            head = f.read(len(MAGIC))
    except OSError as e:
        raise ReplayError(f"{path}: cannot be read ({e.strerror})") from None
    if head != MAGIC:
        raise ReplayError(f"{path} is not a Rerun recording (.rrd files start with {MAGIC.decode()})")
    return path


def web_url(host: str, port: int, grpc_port: int) -> str:
    """What a browser opens: the web viewer at host:port, pointed at the file's gRPC stream."""
    return viewer_url("127.0.0.1" if host in ("0.0.0.0", "::", "") else host, port, grpc_port)


def port_free(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        try:
            s.bind((host, port))
        except OSError:
            return False
    return True


@dataclass(frozen=True)
class WebReplay:
    """Serve `path` to a browser: the viewer's page at host:port, the recording at host:grpc_port."""

    path: Path
    host: str = "127.0.0.1"
    port: int = 9090
    grpc_port: int = 9091

    @property
    def url(self) -> str:
        return web_url(self.host, self.port, self.grpc_port)

    def command(self) -> list[str]:
        memory = max(MIN_SERVER_MEMORY, 3 * self.path.stat().st_size) >> 20
        return [rerun_cli(), "--serve-grpc", "--bind", self.host, "--port", str(self.grpc_port),
                "--server-memory-limit", f"{memory}MiB", str(self.path)]

    def check_ports(self) -> None:
        for port, what in ((self.port, "--port"), (self.grpc_port, "--grpc-port")):
            if not port_free(self.host, port):
                raise ReplayError(f"port {port} on {self.host} is taken ({what}); choose another")

    def start(self) -> tuple[subprocess.Popen, ViewerServer]:
        """Start serving; returns once the stream and the page answer (rerun's output is kept for an error)."""
        self.check_ports()
        log = tempfile.TemporaryFile()
        # its own process group: `rerun` is a Python launcher whose child serves; stopping the launcher alone
        # would leave the server running
        proc = subprocess.Popen(self.command(), stdout=log, stderr=subprocess.STDOUT, env=rerun_env(),
                                start_new_session=True)
        if not _wait_port(self.host, self.grpc_port, proc, READY_TIMEOUT):
            stop_group(proc, grace=0)
            log.seek(0)
            said = log.read().decode(errors="replace").strip().splitlines()
            raise ReplayError(f"rerun did not serve {self.path}" + (f": {said[-1][-300:]}" if said else ""))
        try:
            return proc, ViewerServer((self.host, self.port), self.grpc_port)
        except BaseException:  # the page's port taken meanwhile: no rerun is left serving
            stop_group(proc, grace=0)
            raise


def desktop_command(path: Path) -> list[str]:
    """Rerun's desktop viewer on `path`; a ReplayError on a host without a display."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise ReplayError("no display here (DISPLAY is not set): replay in a browser instead, "
                          "without --desktop, and open the URL it prints")
    return [rerun_cli(), str(path)]


def _wait_port(host: str, port: int, proc: subprocess.Popen, timeout: float) -> bool:
    import time

    target = "127.0.0.1" if host in ("0.0.0.0", "") else "::1" if host == "::" else host
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            return False
        try:
            with socket.create_connection((target, port), timeout=0.5):
                return True
        except OSError:
            time.sleep(0.1)
    return False


def stop_group(proc: subprocess.Popen, grace: float = 5.0) -> None:
    """Stop `proc` and every process it started (its own session's group): SIGTERM and up to `grace` seconds
    to end, then SIGKILL for whatever of the group is left (the launcher's server)."""
    import signal

    if grace > 0:
        _signal_group(proc, signal.SIGTERM)
        try:
            proc.wait(timeout=grace)
        except subprocess.TimeoutExpired:
            pass
    _signal_group(proc, signal.SIGKILL)
    proc.wait()


def _signal_group(proc: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(proc.pid, sig)
    except ProcessLookupError:  # the whole group has ended
        pass
