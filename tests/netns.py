"""Hosts for tests: Linux network namespaces on one bridge, each its own network stack (`ip netns`).

`hosts(n)` gives n namespaces, host i at 10.<net>.0.<i+1> on a bridge in the test's own namespace
(which is 10.<net>.0.254, so the test reaches every host). `cut(host)` takes a host's cable out,
`plug(host)` puts it back. Needs root (CAP_NET_ADMIN and CAP_SYS_ADMIN); `unavailable()` says why
not where they cannot be created, for a skip.
"""
from __future__ import annotations

import itertools
import os
import re
import shutil
import signal
import subprocess
import sys
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
_calls = itertools.count()


def _ip(*args: str, ns: str | None = None, check: bool = True) -> subprocess.CompletedProcess:
    cmd = ["ip", *(["netns", "exec", ns, "ip"] if ns else []), *args]
    return subprocess.run(cmd, capture_output=True, text=True, check=check)


def unavailable() -> str | None:
    """Why network namespaces cannot be used here, or None when they can."""
    if sys.platform != "linux" or shutil.which("ip") is None:
        return "needs Linux with iproute2 (`ip`)"
    probe = f"tmprobe{os.getpid()}"
    r = subprocess.run(["ip", "netns", "add", probe], capture_output=True, text=True)
    if r.returncode != 0:
        return f"cannot create a network namespace ({r.stderr.strip() or 'ip netns add failed'}; needs root)"
    subprocess.run(["ip", "netns", "del", probe], capture_output=True)
    return None


@dataclass
class Host:
    name: str       # the namespace
    address: str    # its IPv4 address on the bridge
    veth: str       # its cable's end on the bridge's side
    procs: list[subprocess.Popen] = field(default_factory=list)

    def popen(self, args: list[str], log: Path, env: dict[str, str] | None = None) -> subprocess.Popen:
        """Start `args` inside this host (its own process group, output to `log`)."""
        p = subprocess.Popen(["ip", "netns", "exec", self.name, *args], stdout=open(log, "wb"),
                             stderr=subprocess.STDOUT, cwd=REPO, start_new_session=True,
                             env={**os.environ, "PYTHONUNBUFFERED": "1", **(env or {})})
        self.procs.append(p)
        return p

    def run(self, args: list[str], timeout: float = 60) -> subprocess.CompletedProcess:
        return subprocess.run(["ip", "netns", "exec", self.name, *args], capture_output=True, text=True,
                              timeout=timeout, cwd=REPO)


class Network:
    def __init__(self, hosts: list[Host], bridge: str):
        self.hosts, self.bridge = hosts, bridge

    def cut(self, host: Host) -> None:
        _ip("link", "set", host.veth, "down")

    def plug(self, host: Host) -> None:
        _ip("link", "set", host.veth, "up")


def _sweep() -> None:
    """Remove what test runs that were killed (no `finally`) left behind: their hosts' processes,
    namespaces and bridges. Their names carry the pid of the run that made them."""
    for line in _ip("netns", "list").stdout.splitlines():
        ns = line.split()[0] if line.split() else ""
        m = re.fullmatch(r"tm(\d+)c\dh\d+", ns)
        if m and not _running(int(m.group(1))):
            pids = subprocess.run(["ip", "netns", "pids", ns], capture_output=True, text=True).stdout.split()
            for pid in pids:
                try:
                    os.kill(int(pid), signal.SIGKILL)
                except (ProcessLookupError, ValueError):
                    pass
            _ip("netns", "del", ns, check=False)
    for line in _ip("-o", "link", "show", "type", "bridge").stdout.splitlines():
        m = re.match(r"\d+: (tmbr(\d+)c\d)[:@]", line)
        if m and not _running(int(m.group(2))):
            _ip("link", "del", m.group(1), check=False)


def _running(pid: int) -> bool:
    return pid == os.getpid() or Path(f"/proc/{pid}").exists()


def _free_net(start: int) -> int:
    """A 10.<net>.0.0/24 (net 100..199) that no interface of this namespace has: a bridge on the same
    subnet (another run's) takes the test's packets to its hosts ("No route to host")."""
    taken = set(re.findall(r"inet 10\.(\d+)\.", _ip("-4", "-o", "addr").stdout))
    for i in range(100):
        net = 100 + (start + i) % 100
        if str(net) not in taken:
            return net
    raise RuntimeError("no free 10.x.0.0/24 subnet for test hosts (100..199 all in use)")


@contextmanager
def hosts(n: int, net: int | None = None) -> Iterator[Network]:
    """`n` hosts on one bridge; everything (processes, namespaces, bridge) is removed afterwards."""
    call = next(_calls)  # names of their own: a namespace a failed test left behind for a moment collides with none
    tag = f"{os.getpid()}c{call % 10}"  # at most 7 + 2 digits: names stay within Linux's 15 characters
    _sweep()
    net = net if net is not None else _free_net(os.getpid() + call)
    bridge = f"tmbr{tag}"
    made: list[Host] = []
    try:
        _ip("link", "add", bridge, "type", "bridge")
        _ip("addr", "add", f"10.{net}.0.254/24", "dev", bridge)
        _ip("link", "set", bridge, "up")
        for i in range(n):
            ns, inside, outside = f"tm{tag}h{i}", f"tmi{tag}h{i}", f"tmo{tag}h{i}"
            host = Host(ns, f"10.{net}.0.{i + 1}", outside)
            _ip("netns", "add", ns)
            made.append(host)
            _ip("link", "add", inside, "type", "veth", "peer", "name", outside)
            _ip("link", "set", inside, "netns", ns)
            _ip("link", "set", outside, "master", bridge)
            _ip("link", "set", outside, "up")
            _ip("addr", "add", f"{host.address}/24", "dev", inside, ns=ns)
            _ip("link", "set", inside, "up", ns=ns)
            _ip("link", "set", "lo", "up", ns=ns)
        yield Network(made, bridge)
    finally:
        from tests.labs import stop_process

        for host in made:
            for p in host.procs:  # SIGTERM: a plain program started with SIGINT ignored stops on it too
                stop_process(p, 20, signal.SIGTERM)
        for host in made:
            _ip("netns", "del", host.name, check=False)
        _ip("link", "del", bridge, check=False)
