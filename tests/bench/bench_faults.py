"""Faults: how long a lab takes to recover from a killed part or a cut cable, and what failed meanwhile.

One `twinmesh up lights --record` lab; each part in turn (tdgen, recorder, adapter, lights, router)
is killed with SIGKILL while a client reads `light-left`'s lightState over HTTP every 50 ms.
Printed per part: when the supervisor's new process was there, when reads succeeded again and
the lab listed every Thing again, and the reads that failed meanwhile. The baseline is what a
crash cost before the supervisor restarted parts: the whole lab stopped, and a user started it
again (`twinmesh up lights` until ready). With network namespaces (root), also a host's cable cut
and plugged back (tests/netns.py): when the other host's adapter answered 503, when it served the
host's Thing again, and whether the lab's own Things kept answering meanwhile; beside it the same cut
with Zenoh's default 2 receive threads in the routers (the baseline).

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


ZENOH_DEFAULT_RUNTIME = "(rx: (worker_threads: 2))"  # Zenoh's own: the baseline of the cable cut
AFTER_CUT = 15.0  # s of reads of the lab's own light after the cut: the dead links are seen and closed


def cut_cable(tmp: Path, runtime: str | None = None) -> dict[str, float] | str:
    """Host B (`up lights --join` and a robot joined directly) cut off from the lab on A, and plugged
    back: when A's adapter answered 503 for B's light and served it again, and how A's own light-1
    answered meanwhile. `runtime`: the routers' ZENOH_RUNTIME (None: the project's own)."""
    from tests import netns

    why = netns.unavailable()
    if why:
        return f"skipped: {why}"
    py = [sys.executable, "-m", "devices"]
    env = {"ZENOH_RUNTIME": runtime} if runtime else {}
    with netns.hosts(2) as net:
        a, b = net.hosts
        endpoint, base = f"tcp/{a.address}:7447", f"http://{a.address}:8080"
        log_a, log_b, log_r = tmp / "a.log", tmp / "b.log", tmp / "robot.log"
        a.popen([*py, "--connect", endpoint, "up", "fleet", "--fleet", "5", "--http", f"{a.address}:8080",
                 "--no-view"], log_a, env)
        while "ready" not in log_a.read_text():
            time.sleep(0.2)
        b.popen([*py, "up", "lights", "--join", endpoint], log_b, env)
        b.popen([*py, "robot", "ur10.urdf", "--name", "ur10", "--samples", "300", "--join", endpoint], log_r)

        def status(thing: str = "light-left", prop: str = "lightState") -> int:
            try:
                return httpx.get(f"{base}/{thing}/properties/{prop}", timeout=10).status_code
            except httpx.HTTPError:
                return 0
        while status() != 200 or status("ur10", "getJointposition") != 200:
            time.sleep(0.2)
        net.cut(b)
        t0, gone, own, slowest = time.monotonic(), None, [], 0.0
        while time.monotonic() - t0 < AFTER_CUT:
            t = time.monotonic()
            own.append(status("light-1"))
            slowest = max(slowest, time.monotonic() - t)
            if gone is None and status() == 503:
                gone = time.monotonic() - t0
            time.sleep(EVERY)
        net.plug(b)
        t1 = time.monotonic()
        while status() != 200:
            time.sleep(0.02)
        return {"gone": gone if gone is not None else float("nan"), "back": time.monotonic() - t1,
                "reads": len(own), "failed": sum(1 for c in own if c != 200), "slowest": slowest}


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        for name in ("baseline", "parts", "cable"):
            (Path(tmp) / name).mkdir()
        baseline = whole_restart(Path(tmp) / "baseline")
        rows = kill_each(Path(tmp) / "parts")
        cable = cut_cable(Path(tmp) / "cable")
        (Path(tmp) / "cable-baseline").mkdir()
        cable_baseline = cut_cable(Path(tmp) / "cable-baseline", ZENOH_DEFAULT_RUNTIME)
    print(f"\nSIGKILL of each part of `twinmesh up lights --record`, reads of light-left every {EVERY * 1000:.0f} ms:\n")
    print("| killed part | new process after | reads fail until | all Things listed after | failed reads | "
          "reads | vs. whole-lab restart (baseline) |\n|---|---|---|---|---|---|---|")
    for title, respawned, served, listed, failed, total in rows:
        print(f"| {title} | {respawned:.2f} s | {served:.2f} s | {listed:.2f} s | {failed} | {total} | "
              f"{listed / baseline:.2f}x of {baseline:.1f} s |")
    print(f"\nbaseline: before the supervisor restarted parts, any crash stopped the lab; starting `twinmesh up "
          f"lights` again took {baseline:.1f} s until ready, and every read failed meanwhile "
          f"(~{baseline / EVERY:.0f} at this rate).")
    if isinstance(cable, str) or isinstance(cable_baseline, str):
        print(f"\ncut cable: {cable if isinstance(cable, str) else cable_baseline}")
    else:
        print(f"\ncut cable between two hosts (network namespaces; B: `up lights --join` and `robot --join`): "
              f"reads of B's light-left and of A's own light-1 over A's adapter, {AFTER_CUT:.0f} s after the cut:\n")
        print("| routers' receive threads | B's light: 503 after | served again after plug | A's light-1 reads | "
              "failed | slowest read |\n|---|---|---|---|---|---|")
        for label, c in (("16 (twinmesh)", cable), ("2 (Zenoh's default, baseline)", cable_baseline)):
            print(f"| {label} | {c['gone']:.2f} s | {c['back']:.2f} s | {c['reads']:.0f} | {c['failed']:.0f} | "
                  f"{c['slowest'] * 1000:.0f} ms |")
        print("\nA dead link's socket is closed with a 10 s linger on one of the router's receive threads "
              "(zenoh#1101): with 2, both of B's links can hold both and the lab's router stalls.")


if __name__ == "__main__":
    main()
