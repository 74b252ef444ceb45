"""The thesis's uArm evaluation, reproduced: the platform's arms generated where they stand.

    python tests/bench/bench_platform_arms.py [--samples 80000] [--grid 10]

For the uArm (real frame, the shipped calibration) and the Dobot (twin frame), each in the
`iot-platform` scene at its own place: the generated TD's Cartesian bounds beside the thesis's
virtual uArm TD and the real uArm TD's safe box, then every point of a grid (default 10 mm) over
that safe box: inside the workspace hull, reached by IK within 0.01 mm, and collision-free there.
"""
from __future__ import annotations

import argparse
import tempfile
import time

import numpy as np

from tdgen.generate import generate
from tdgen.robot import ik
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import ROBOTS_DIR, Robot
from tdgen.robot.surroundings import load_scene
from tdgen.robot.workspace_check import Workspace

THESIS_UARM = {"x": (-35.9, 373.5), "y": (-363.0, 363.3), "z": (-30.0, 175.5)}  # the thesis's virtual uArm TD
SAFE_BOX = {"x": (120.0, 200.0), "y": (-200.0, 200.0), "z": (52.0, 100.0)}      # the real uArm TD's goTo box
ARMS = {"uarm": ("uarm_swift_pro.urdf", "real"), "dobot": ("dobot_magician.urdf", "twin")}


def grid(step: float) -> np.ndarray:
    axes = [np.arange(lo, hi + 1e-9, step) for lo, hi in SAFE_BOX.values()]
    return np.array(np.meshgrid(*axes, indexing="ij")).reshape(3, -1).T


def evaluate(name: str, samples: int, step: float) -> None:
    urdf, frame = ARMS[name]
    robot = Robot.load(urdf)
    scene = load_scene("iot-platform", name)
    calibration = ROBOTS_DIR / "uarm-calibration.csv" if frame == "real" else None
    with tempfile.TemporaryDirectory() as out:
        t = time.perf_counter()
        result = generate(robot, scene, samples, seed=0, out_dir=out, calibration=calibration, frame=frame)
        seconds = time.perf_counter() - t
        workspace = Workspace.load(out)
    print(f"\n{name}: {robot.describe_chain()}; {samples} samples in {seconds:.1f} s, "
          f"{result.collision_free} collision-free, hull {result.volume_mm3 / 1e9:.4f} m^3 ({frame} frame)")
    print(f"{'axis':>4}  {'generated (mm)':>20}  {'thesis virtual uArm':>20}  {'real TD safe box':>18}")
    for i, axis in enumerate("xyz"):
        print(f"{axis:>4}  {result.low_mm[i]:9.1f}..{result.high_mm[i]:<9.1f}  "
              f"{THESIS_UARM[axis][0]:9.1f}..{THESIS_UARM[axis][1]:<9.1f}  "
              f"{SAFE_BOX[axis][0]:7.1f}..{SAFE_BOX[axis][1]:<7.1f}")
    points = grid(step)
    inside = np.array([workspace.check(p).inside for p in points])
    fk = ForwardKinematics(robot)
    solved = ik.solve_many(fk, points / 1000.0, rng=0)  # twin = real for the shipped pairs (identity map)
    reached = np.linalg.norm(fk.positions(solved.q) * 1000.0 - points, axis=1) <= 0.01
    world = CollisionWorld(robot, scene)
    try:
        free = ~world.colliding(solved.q)
    finally:
        world.close()
    ok = reached & free
    print(f"grid {step:g} mm over the safe box: {len(points)} points, {int(inside.sum())} inside the hull, "
          f"{int(reached.sum())} reached by IK within 0.01 mm, {int(ok.sum())} reached collision-free "
          f"({ok.mean():.1%})")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--samples", type=int, default=80_000)
    parser.add_argument("--grid", type=float, default=10.0, help="grid step in mm")
    args = parser.parse_args()
    for name in ARMS:
        evaluate(name, args.samples, args.grid)


if __name__ == "__main__":
    main()
