"""The test hosts themselves: a run killed mid-test (no `finally`) left its bridge behind, on a subnet
a later run then chose too; the later run's requests to its hosts failed with "No route to host",
which the 4-host test read as devices missing from the adapter (a CI failure of session 9)."""
from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest

from tests import netns

WHY_NOT = netns.unavailable()
pytestmark = [pytest.mark.lab, pytest.mark.skipif(WHY_NOT is not None, reason=f"network namespaces: {WHY_NOT}")]


def _dead_pid() -> int:
    return next(p for p in range(3_999_999, 3_000_000, -1) if not Path(f"/proc/{p}").exists())


def _ip(*args: str) -> None:
    subprocess.run(["ip", *args], check=True, capture_output=True)


def test_hosts_avoid_a_subnet_in_use_and_remove_what_killed_runs_left(tmp_path):
    dead = _dead_pid()
    stale_bridge, stale_ns, busy = f"tmbr{dead}c0", f"tm{dead}c0h0", f"tmbusy{dead % 10000}"
    first = netns._free_net(0)
    _ip("link", "add", stale_bridge, "type", "bridge")
    _ip("addr", "add", f"10.{first}.0.254/24", "dev", stale_bridge)
    _ip("netns", "add", stale_ns)
    second = netns._free_net(0)  # first is taken now
    _ip("link", "add", busy, "type", "bridge")  # someone else's bridge: not ours to remove
    _ip("addr", "add", f"10.{second}.0.254/24", "dev", busy)
    try:
        with netns.hosts(2) as net:
            links = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True).stdout
            assert stale_bridge not in links and busy in links
            assert stale_ns not in subprocess.run(["ip", "netns", "list"], capture_output=True, text=True).stdout
            host = net.hosts[1]
            assert not host.address.startswith(f"10.{second}.")
            host.popen([sys.executable, "-m", "http.server", "8000", "--bind", host.address], tmp_path / "http.log")
            deadline, status = time.monotonic() + 30, None
            while status is None and time.monotonic() < deadline:
                try:
                    status = httpx.get(f"http://{host.address}:8000/", timeout=2).status_code
                except httpx.HTTPError:
                    time.sleep(0.2)
            assert status == 200, "the test could not reach its own host"
    finally:
        subprocess.run(["ip", "link", "del", busy], capture_output=True)
        subprocess.run(["ip", "link", "del", stale_bridge], capture_output=True)
        subprocess.run(["ip", "netns", "del", stale_ns], capture_output=True)
