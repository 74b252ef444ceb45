"""Cube workflow benchmark: wall and simulated time of the whole workflow, CPU and memory of the lab.

Starts `twinmesh up iot-platform --speed max` (then `--speed 1`) on free ports and, for each:
- idle: CPU (% of one core, user+system, summed over the supervisor and all its processes) and
  resident memory (RSS per process and summed; shared pages count once per process) over a few s;
- the workflow over Zenoh (`devices.apps.cube_workflow.cube_workflow`, a `mesh.consumer` on a session; at speed max also
  over the HTTP adapter with a consumer given its base URL): wall time, simulated time (the world Thing's
  `simTime` before and after), and the lab's CPU and peak RSS meanwhile.

    python tests/bench/bench_workflow.py [--idle 5] [--runs-max 2] [--no-speed-1]

The benchmark client runs on the same machine (its own CPU is not counted): figures are for
comparison on one machine. Speed 1 takes about a minute (the workflow is ~46 simulated seconds).
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, test helpers

from labs import PLATFORM_THINGS as THINGS  # noqa: E402
from labs import mesh_client, start_lab  # noqa: E402


def lab_processes(pid: int) -> dict[str, psutil.Process]:
    """The supervisor and its children by the role each shows in `ps` (`twinmesh: <role>`); the
    multiprocessing resource tracker, which has no role, is left out."""
    sup = psutil.Process(pid)
    roles = {}
    for p in sup.children():
        title = " ".join(p.cmdline())
        if title.startswith("twinmesh: "):
            roles[title.removeprefix("twinmesh: ")] = p
    return {"supervisor": sup, **roles}


class Meter:
    """CPU seconds and peak RSS of a set of processes between start() and stop()."""

    def __init__(self, procs: dict[str, psutil.Process], period: float = 0.2):
        self.procs, self.period = procs, period
        self.peak: dict[str, int] = {}
        self._stop = threading.Event()

    def _cpu(self) -> dict[str, float]:
        return {n: sum(p.cpu_times()[:2]) for n, p in self.procs.items()}

    def _sample(self) -> None:
        while True:
            for n, p in self.procs.items():
                self.peak[n] = max(self.peak.get(n, 0), p.memory_info().rss)
            if self._stop.wait(self.period):
                return

    def __enter__(self) -> "Meter":
        self.cpu0, self.t0 = self._cpu(), time.perf_counter()
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.wall = time.perf_counter() - self.t0
        self.cpu = {n: v - self.cpu0[n] for n, v in self._cpu().items()}
        self._stop.set()
        self._thread.join()

    def report(self, what: str) -> None:
        total = sum(self.cpu.values())
        print(f"  {what}: CPU {100 * total / self.wall:5.1f} % of a core over {self.wall:.1f} s "
              f"(" + ", ".join(f"{n} {100 * c / self.wall:.1f}" for n, c in self.cpu.items()) + "); "
              f"RSS peak {sum(self.peak.values()) / 2**20:.0f} MiB ("
              + ", ".join(f"{n} {m / 2**20:.0f}" for n, m in self.peak.items()) + ")")


@contextmanager
def lab_at(speed: str, tmp: Path):
    lab = start_lab(tmp, "iot-platform", http=True, things=THINGS, extra_args=("--speed", speed))
    try:
        yield lab
    finally:
        lab.stop()


def one_run(lab, client, consumer, label: str) -> None:
    from devices.apps.cube_workflow import cube_workflow

    client.invoke("world", "reset")
    sim0 = client.read("world", "simTime")
    with Meter(lab_processes(lab.proc.pid)) as meter:
        run = cube_workflow(consumer, sensor_timeout=300)
    sim = client.read("world", "simTime") - sim0
    print(f"  workflow {label}: {run.seconds:.2f} s wall, {sim:.1f} s simulated "
          f"(x{sim / run.seconds:.1f}), cube {run.color_name} {run.color}")
    meter.report(f"lab during the workflow {label}")


def bench(speed: str, runs: int, idle: float, http: bool, tmp: Path) -> None:
    import mesh

    print(f"twinmesh up iot-platform --speed {speed}")
    with lab_at(speed, tmp) as lab, mesh_client(lab.endpoint) as client:
        time.sleep(2.0)  # let start-up settle (cubes land, sessions connect)
        procs = lab_processes(lab.proc.pid)
        with Meter(procs) as meter:
            time.sleep(idle)
        meter.report("idle")
        for i in range(runs):
            with mesh.consumer(session=client.session, settings=client.settings) as things:
                one_run(lab, client, things, f"over Zenoh #{i + 1}")
        if http:
            with mesh.consumer(base=lab.http) as things:
                one_run(lab, client, things, "over HTTP")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--idle", type=float, default=5.0, help="seconds of idle measurement")
    ap.add_argument("--runs-max", type=int, default=2, help="Zenoh runs at speed max")
    ap.add_argument("--no-speed-1", action="store_true", help="skip the (about one minute) speed-1 run")
    args = ap.parse_args()
    print(f"{psutil.cpu_count()} CPUs, load average {', '.join(f'{v:.1f}' for v in psutil.getloadavg())}")
    with tempfile.TemporaryDirectory() as tmp:
        bench("max", args.runs_max, args.idle, http=True, tmp=Path(tmp))
        if not args.no_speed_1:
            bench("1", 1, args.idle, http=False, tmp=Path(tmp))


if __name__ == "__main__":
    main()
