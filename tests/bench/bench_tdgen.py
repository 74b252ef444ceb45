"""tdgen benchmark: sampling throughput with collision checking, hull time, hull volume convergence.

    python tests/bench/bench_tdgen.py [--samples 80000] [--reference-samples 1000000] [--robot ur10.urdf]

Figures, for the robot in `table-and-wall` (3 bodies) and in `cluttered-lab` (78 bodies):
- samples per second with collision checking on one core and on two (spawn pool), and the ratio;
- the whole `generate()` run for the default N on all cores (sampling, hull, files);
- the hull time and the hull volume of N samples against a large reference run (the ratio says
  how much of the workspace the default N misses: a hull of fewer points is always smaller).
The thesis figures (375 s for 80 000 UR10 samples in a 605-object scene, 13.7 s for a UR3 in a
2-object scene) are printed beside ours; they are for other hardware and another implementation.
"""
from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time

from tdgen.generate import generate
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import load_scene
from tdgen.robot.workspace import convex_hull
from tdgen.sampling import sample_workspace

THESIS = {"cluttered-lab": ("UR10, 605 objects", 375.0), "table-and-wall": ("UR3, 2 objects", 13.7)}


def _cpu() -> float:
    """CPU seconds of this process and its finished children (the pool's workers)."""
    children = resource.getrusage(resource.RUSAGE_CHILDREN)
    return time.process_time() + children.ru_utime + children.ru_stime


def throughput(robot: Robot, scene_name: str, n: int, workers: int) -> tuple[float, float]:
    """(samples per wall-clock second, samples per CPU second)."""
    scene = load_scene(scene_name)
    t, cpu = time.perf_counter(), _cpu()
    sample_workspace(robot, scene, n, seed=1, workers=workers)
    return n / (time.perf_counter() - t), n / (_cpu() - cpu)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--robot", default="ur10.urdf")
    parser.add_argument("--samples", type=int, default=80_000)
    parser.add_argument("--reference-samples", type=int, default=1_000_000)
    args = parser.parse_args()
    robot = Robot.load(args.robot)
    n = args.samples

    print(f"robot {robot.name}, {n} samples per run, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("samples/s: wall clock (per CPU second, which other load on the machine does not change)\n")
    print(f"{'scene':16} {'bodies':>6} {'1 core /s':>16} {'2 cores /s':>16} {'ratio':>6} "
          f"{'generate s':>11} {'thesis':>22}")
    for scene_name in ("table-and-wall", "cluttered-lab"):
        one, one_cpu = throughput(robot, scene_name, n, workers=1)
        two, two_cpu = throughput(robot, scene_name, n, workers=2)
        with tempfile.TemporaryDirectory() as out:
            result = generate(robot, scene_name, n, seed=1, out_dir=out, workers=2)
        label, seconds = THESIS[scene_name]
        print(f"{scene_name:16} {len(load_scene(scene_name).bodies):>6} {f'{one:.0f} ({one_cpu:.0f})':>16} "
              f"{f'{two:.0f} ({two_cpu:.0f})':>16} {two / one:>6.2f} {result.timings['total']:>11.2f} "
              f"{f'{seconds} s ({label})':>22}")
        steps = ", ".join(f"{k} {v:.2f} s" for k, v in result.timings.items())
        print(f"{'':16} generate steps: {steps}")

    scene = load_scene("table-and-wall")
    t = time.perf_counter()
    reference = sample_workspace(robot, scene, args.reference_samples, seed=2, workers=2)
    ref_time = time.perf_counter() - t
    t = time.perf_counter()
    ref_hull = convex_hull(reference.free)
    ref_hull_time = time.perf_counter() - t
    default = sample_workspace(robot, scene, n, seed=3, workers=2)
    t = time.perf_counter()
    hull = convex_hull(default.free)
    hull_time = time.perf_counter() - t
    print(f"\nhull volume, table-and-wall: {n} samples {hull.volume / 1e9:.4f} m^3 "
          f"({len(default.free)} free points, hull {hull_time * 1000:.0f} ms)")
    print(f"  reference {args.reference_samples} samples {ref_hull.volume / 1e9:.4f} m^3 "
          f"({len(reference.free)} free points, sampling {ref_time:.1f} s, hull {ref_hull_time * 1000:.0f} ms)")
    print(f"  ratio {hull.volume / ref_hull.volume:.4f}")
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
