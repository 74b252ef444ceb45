"""Faults: how long a lab takes to recover from a killed part or a cut cable, and what failed meanwhile.

One `twinmesh up lights --record` lab; each part in turn (tdgen, recorder, adapter, lights, router)
is killed with SIGKILL while a client reads `light-left`'s lightState over HTTP every 50 ms.
Printed per part: when the supervisor's new process was there, when reads succeeded again and
the lab listed every Thing again, and the reads that failed meanwhile. The baseline is what a
crash cost before the supervisor restarted parts: the whole lab stopped, and a user started it
again (`twinmesh up lights` until ready). With network namespaces (root), also a host's cable cut
and plugged back (tests/netns.py): when the other host's adapter answered 503, and when it served
the host's Thing again.

    python tests/bench/bench_faults.py
"""
from __future__ import annotations

import os
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests.labs, tests.netns

from tests.labs import start_lab  # noqa: E402

PARTS = ("tdgen", "recorder", "adapter", "lights", "router")
EVERY = 0.05
THINGS = {"tdgen", "light-left", "light-right"}


class Reader:
    """Reads light-left's state every EVERY seconds; counts what failed and when reads last failed."""

    def __init__(self, base: str):
        self.base, self.ok, self.failed = base, 0, 0
        self.last_failure = 0.0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self) -> "Reader":
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _run(self) -> None:
        with httpx.Client(timeout=2) as c:
            while not self._stop.wait(EVERY):
                try:
                    good = c.get(f"{self.base}/light-left/properties/lightState").status_code == 200
                except httpx.HTTPError:
                    good = False
                if good:
                    self.ok += 1
                else:
                    self.failed += 1
                    self.last_failure = time.monotonic()


def _child(lab, title: str, not_pid: int | None = None) -> psutil.Process:
    while True:
        for c in psutil.Process(lab.proc.pid).children():
            try:
                if c.pid != not_pid and c.status() != psutil.STATUS_ZOMBIE and \
                        " ".join(c.cmdline()).startswith(f"twinmesh: {title}"):
                    return c
            except psutil.Error:
                continue
        time.sleep(0.02)


def _listed(lab) -> bool:
    return THINGS <= set(lab.cli("things").stdout.split())


def kill_each(tmp: Path) -> list[tuple[str, float, float, float, int, int]]:
    lab = start_lab(tmp, "lights", things=THINGS, extra_args=("--record", str(tmp / "lab.rrd")))
    rows = []
    try:
        for title in PARTS:
            time.sleep(3)  # out of the previous restart's backoff window's way
            victim = _child(lab, title)
            with Reader(lab.http) as reader:
                time.sleep(1)
                before_failed = reader.failed
                t0 = time.monotonic()
                os.kill(victim.pid, signal.SIGKILL)
                _child(lab, title, not_pid=victim.pid)
                respawned = time.monotonic() - t0
                while not _listed(lab):
                    time.sleep(0.05)
                listed = time.monotonic() - t0
                time.sleep(2)
                served = max(0.0, reader.last_failure - t0) if reader.failed > before_failed else 0.0
                rows.append((title, respawned, served, listed, reader.failed - before_failed,
                             reader.ok + reader.failed))
    finally:
        lab.stop()
    return rows


def whole_restart(tmp: Path) -> float:
    """The baseline: a user starting the whole lab again after it stopped (until `twinmesh wait` says ready)."""
    t0 = time.monotonic()
    lab = start_lab(tmp, "lights", things=THINGS)
    took = time.monotonic() - t0
    lab.stop()
    return took


def cut_cable(tmp: Path) -> tuple[float, float] | str:
    from tests import netns

    why = netns.unavailable()
    if why:
        return f"skipped: {why}"
    py = [sys.executable, "-m", "twinmesh"]
    with netns.hosts(2) as net:
        a, b = net.hosts
        endpoint, base = f"tcp/{a.address}:7447", f"http://{a.address}:8080"
        log_a, log_b = tmp / "a.log", tmp / "b.log"
        a.popen([*py, "--connect", endpoint, "up", "fleet", "--fleet", "5", "--http", f"{a.address}:8080",
                 "--no-view"], log_a)
        while "ready" not in log_a.read_text():
            time.sleep(0.2)
        b.popen([*py, "up", "lights", "--join", endpoint], log_b)
        while "ready" not in log_b.read_text():
            time.sleep(0.2)

        def status() -> int:
            try:
                return httpx.get(f"{base}/light-left/properties/lightState", timeout=10).status_code
            except httpx.HTTPError:
                return 0
        while status() != 200:
            time.sleep(0.1)
        net.cut(b)
        t0 = time.monotonic()
        while status() != 503:
            time.sleep(0.02)
        gone = time.monotonic() - t0
        net.plug(b)
        t1 = time.monotonic()
        while status() != 200:
            time.sleep(0.02)
        return gone, time.monotonic() - t1


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("baseline", "parts", "cable"):
            (Path(tmp) / name).mkdir()
        baseline = whole_restart(Path(tmp) / "baseline")
        rows = kill_each(Path(tmp) / "parts")
        cable = cut_cable(Path(tmp) / "cable")
    print(f"\nSIGKILL of each part of `twinmesh up lights --record`, reads of light-left every {EVERY * 1000:.0f} ms:\n")
    print("| killed part | new process after | reads fail until | all Things listed after | failed reads | "
          "reads | vs. whole-lab restart (baseline) |\n|---|---|---|---|---|---|---|")
    for title, respawned, served, listed, failed, total in rows:
        print(f"| {title} | {respawned:.2f} s | {served:.2f} s | {listed:.2f} s | {failed} | {total} | "
              f"{listed / baseline:.2f}x of {baseline:.1f} s |")
    print(f"\nbaseline: before the supervisor restarted parts, any crash stopped the lab; starting `twinmesh up "
          f"lights` again took {baseline:.1f} s until ready, and every read failed meanwhile "
          f"(~{baseline / EVERY:.0f} at this rate).")
    if isinstance(cable, str):
        print(f"\ncut cable: {cable}")
    else:
        print(f"\ncut cable between two hosts (network namespaces): the lab's adapter answered 503 for the other "
              f"host's light {cable[0]:.2f} s after the cut, and served it again {cable[1]:.2f} s after the cable "
              "was plugged back (the joining router's lease: 1.5 s).")


if __name__ == "__main__":
    main()
