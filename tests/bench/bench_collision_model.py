"""The fast collision model beside the exact one, in the same run: agreement, time, the thesis's figures.

    python tests/bench/bench_collision_model.py [--samples 80000] [--million] [--commands]

Per robot and scene: seconds of sampling with each model (the same seed, so the same configurations),
their ratio, the share of samples where both agree, the samples the fast model called free that the
exact test finds colliding (must be 0), and the share it left to the exact test. Then the marginal
cost from 8,000 to N samples (start-up excluded, the issue's measure) against the thesis's 375 s for
the UR10 in its 605-object lab; with --million 1,000,000 samples of the fast model; with --commands
the whole `twinmesh tdgen` command with each model, in table-and-wall and in a room of 610 bodies (and
with both flags, the whole command for 1,000,000 samples).
"""
from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from devices.sim import compensation as c
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import UNSURE, FastCollision, compile_all
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import cluttered_lab, encode_scene, load_scene
from tdgen.sampling import random_configurations, sample_workspace

THESIS_LAB_S, THESIS_SMALL_S = 375.0, 13.7  # UR10 among 605 objects; UR3 beside 2 objects (80,000 samples)


def _timed(robot, scene, n, model, seed=1):
    t = time.perf_counter()
    samples = sample_workspace(robot, scene, n, seed=seed, collision_model=model)
    return time.perf_counter() - t, samples


def _command(args: list[str]) -> float:
    """Seconds of one whole `twinmesh tdgen` run (a fresh process: imports, model, sampling, files)."""
    t = time.perf_counter()
    subprocess.run([sys.executable, "-m", "devices", "tdgen", *args, "--no-progress"], check=True,
                   stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return time.perf_counter() - t


def commands(n: int, million: bool) -> None:
    """The whole command, both models: table-and-wall, and a room of 610 bodies (4 shelves of small boxes
    and tins around the UR10, like the thesis's 605-object lab); with `million`, 1,000,000 samples in
    table-and-wall too (the fast model: the exact one takes half a minute)."""
    with tempfile.TemporaryDirectory() as tmp:
        room = cluttered_lab(shelves=4, levels=6, items_per_level=24)
        (Path(tmp) / "room.json").write_bytes(encode_scene(room))
        print(f"\nwhole `twinmesh tdgen ur10.urdf --samples {n}` (best of 3; the issue asks 1.5 s in table-and-wall, "
              f"2.5 s among 600 boxes)")
        for label, scene in (("table-and-wall", "table-and-wall"), (f"room, {len(room.bodies)} bodies",
                                                                     str(Path(tmp) / "room.json"))):
            row = []
            for model in ("exact", "fast"):
                best = min(_command(["ur10.urdf", "--scene", scene, "--samples", str(n), "--collision-model", model,
                                     "--out", str(Path(tmp) / model)]) for _ in range(3))
                row.append(best)
            print(f"  {label:22} exact {row[0]:6.2f} s   fast {row[1]:6.2f} s   ratio {row[0] / row[1]:5.1f}")
        if million:
            runs = sorted(_command(["ur10.urdf", "--scene", "table-and-wall", "--samples", "1000000",
                                    "--out", str(Path(tmp) / "million")]) for _ in range(5))
            print(f"whole `twinmesh tdgen ur10.urdf --scene table-and-wall --samples 1e6`, fast model (5 runs; the "
                  f"issue asks 3 s): median {runs[2]:.2f} s, best {runs[0]:.2f} s, worst {runs[-1]:.2f} s")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=80_000)
    parser.add_argument("--million", action="store_true", help="also 1,000,000 samples with the fast model")
    parser.add_argument("--commands", action="store_true", help="also the whole tdgen command, both models")
    args = parser.parse_args()
    n = args.samples
    ur10 = Robot.load("ur10.urdf")
    uarm = Robot.load(c.UARM_URDF, ee=c.UARM_EE, passive_joints=c.UARM_PASSIVE_JOINTS, passive=c.uarm_passive)
    cases = [("ur10", ur10, "table-and-wall", None), ("ur10", ur10, "cluttered-lab", None),
             ("uarm", uarm, "iot-platform", "uarm")]
    compile_all()  # a machine's first run compiles the model (or, for few samples, asks the exact test meanwhile)
    print(f"{n} samples per run, load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores\n")
    print(f"{'robot':6} {'scene':16} {'exact s':>8} {'fast s':>8} {'ratio':>6} {'agree':>8} {'free-but-colliding':>19} "
          f"{'left to exact':>14}")
    for name, robot, scene_name, scene_robot in cases:
        scene = load_scene(scene_name, scene_robot)
        sample_workspace(robot, scene, 500, seed=9)  # the compiled loop loaded once, as in any later run
        exact_s, exact = _timed(robot, scene, n, "exact")
        fast_s, fast = _timed(robot, scene, n, "fast")
        world = CollisionWorld(robot, scene)
        unsure = float(np.mean(FastCollision(world).spheres.verdicts(random_configurations(robot, n, 1)) == UNSURE))
        world.close()
        wrong = int(np.sum(~fast.collision & exact.collision))
        print(f"{name:6} {scene_name:16} {exact_s:8.2f} {fast_s:8.2f} {exact_s / fast_s:6.1f} "
              f"{np.mean(fast.collision == exact.collision):8.4%} {wrong:19d} {unsure:14.1%}")

    scene = load_scene("table-and-wall")
    small_s, _ = _timed(ur10, scene, 8_000, "fast")
    big_s, _ = _timed(ur10, scene, n, "fast")
    marginal = (big_s - small_s) * 80_000 / (n - 8_000)
    print(f"\nUR10 table-and-wall, fast model: 8,000 samples {small_s:.3f} s, {n} samples {big_s:.3f} s; marginal "
          f"cost of 80,000 = {marginal:.3f} s: {THESIS_LAB_S / marginal:.0f}x the thesis's lab figure "
          f"({THESIS_LAB_S:.0f} s), {THESIS_SMALL_S / marginal:.0f}x its small scene ({THESIS_SMALL_S} s); "
          "the issue asks 0.375 s (1000x)")
    if args.million:
        million_s, samples = _timed(ur10, scene, 1_000_000, "fast")
        print(f"1,000,000 samples, fast model: {million_s:.2f} s ({1_000_000 / million_s:,.0f} samples/s, "
              f"{int((~samples.collision).sum())} free)")
    if args.commands:
        commands(n, args.million)
    print(f"load average at the end {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
