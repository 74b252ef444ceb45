"""Hosts for tests: Linux network namespaces on one bridge, each its own network stack (`ip netns`).

`hosts(n)` gives n namespaces, host i at 10.<net>.0.<i+1> on a bridge in the test's own namespace
(which is 10.<net>.0.254, so the test reaches every host). `cut(host)` takes a host's cable out,
`plug(host)` puts it back. Needs root (CAP_NET_ADMIN and CAP_SYS_ADMIN); `unavailable()` says why
not where they cannot be created, for a skip.
"""
from __future__ import annotations

import itertools
import os
import shutil
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


@contextmanager
def hosts(n: int, net: int | None = None) -> Iterator[Network]:
    """`n` hosts on one bridge; everything (processes, namespaces, bridge) is removed afterwards."""
    call = next(_calls)  # names of their own: a namespace a failed test left behind for a moment collides with none
    tag = f"{os.getpid() % 100000}c{call % 10}"
    net = net if net is not None else 100 + (os.getpid() + call) % 100
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
            for p in host.procs:
                stop_process(p, 20)
        for host in made:
            _ip("netns", "del", host.name, check=False)
        _ip("link", "del", bridge, check=False)
