"""IK benchmark: tdgen.robot.ik against one pybullet calculateInverseKinematics call, per robot.

Targets are the FK of random in-limit configurations, so all are reachable. Prints, per robot,
the share solved within 0.01 mm, the largest error, the median and p99 time per target of
`ik.solve` (one target at a time) and of `ik.solve_many` (all at once, time per target), and the
same run's pybullet baseline: one calculateInverseKinematics call from q = 0 per target.

    python tests/bench/bench_ik.py [--targets N] [--seed S]
"""
from __future__ import annotations

import argparse
import time

import numpy as np
import pybullet as pb

from tdgen.robot import ik
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot

ROBOTS = ["franka_panda/panda.urdf", "kuka_iiwa/model.urdf", "xarm/xarm6_robot.urdf", "ur10.urdf"]


def ours(fk: ForwardKinematics, targets: np.ndarray, rng: np.random.Generator) -> dict:
    lo, hi = fk.robot.lows(), fk.robot.highs()
    times, errors, inside = [], [], True
    for t in targets:
        t0 = time.perf_counter()
        res = ik.solve(fk, t, rng=rng)
        times.append(time.perf_counter() - t0)
        errors.append(np.linalg.norm(fk.positions(res.q) - t))  # re-checked, not taken from res
        inside &= bool(np.all((res.q >= lo) & (res.q <= hi)))
    t0 = time.perf_counter()
    batch = ik.solve_many(fk, targets, rng=rng)
    batch_time = (time.perf_counter() - t0) / len(targets)
    errors = np.array(errors)
    inside &= bool(np.all((batch.q >= lo) & (batch.q <= hi)))
    return {"solved": np.mean(errors <= ik.TOL_M), "max": errors.max(), "median": np.median(times),
            "p99": np.percentile(times, 99), "inside": inside,
            "batch_solved": batch.ok.mean(), "batch_time": batch_time}


def pybullet_baseline(robot: Robot, targets: np.ndarray) -> dict:
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client)
        movable = [i for i in range(pb.getNumJoints(body, physicsClientId=client))
                   if pb.getJointInfo(body, i, physicsClientId=client)[2] != pb.JOINT_FIXED]
        columns = [movable.index(j.index) for j in robot.joints]
        home = np.clip(np.zeros(len(robot.joints)), robot.lows(), robot.highs())
        times, errors = [], []
        for t in targets:
            for i, v in robot.full_joint_values(home).items():
                pb.resetJointState(body, i, v, physicsClientId=client)
            t0 = time.perf_counter()
            sol = pb.calculateInverseKinematics(body, robot.ee_index, t.tolist(), physicsClientId=client)
            times.append(time.perf_counter() - t0)
            for i, v in robot.full_joint_values(np.asarray(sol)[columns]).items():
                pb.resetJointState(body, i, v, physicsClientId=client)
            reached = pb.getLinkState(body, robot.ee_index, computeForwardKinematics=True, physicsClientId=client)[4]
            errors.append(np.linalg.norm(np.asarray(reached) - t))
    finally:
        pb.disconnect(client)
    errors = np.array(errors)
    return {"1mm": np.mean(errors <= 1e-3), "0.01mm": np.mean(errors <= 1e-5), "median": np.median(times)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--targets", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()
    print(f"{args.targets} reachable random targets per robot; times per target\n")
    print(f"{'robot':10} | {'ours ≤0.01mm':>12} {'max err mm':>10} {'median ms':>9} {'p99 ms':>7} "
          f"{'batch ms':>8} {'batch ok':>8} | {'pybullet ≤1mm':>13} {'≤0.01mm':>7} {'median ms':>9} | "
          f"{'time ours/pb':>12}")
    for urdf in ROBOTS:
        robot = Robot.load(urdf)
        fk = ForwardKinematics(robot)
        rng = np.random.default_rng(args.seed)
        targets = fk.positions(rng.uniform(robot.lows(), robot.highs(), (args.targets, len(robot.joints))))
        a, b = ours(fk, targets, rng), pybullet_baseline(robot, targets)
        print(f"{robot.name:10} | {a['solved']:12.2%} {a['max'] * 1e3:10.2e} {a['median'] * 1e3:9.2f} "
              f"{a['p99'] * 1e3:7.2f} {a['batch_time'] * 1e3:8.3f} {a['batch_solved']:8.2%} | "
              f"{b['1mm']:13.2%} {b['0.01mm']:7.2%} "
              f"{b['median'] * 1e3:9.3f} | {a['median'] / b['median']:11.1f}x")
        if not a["inside"]:
            print(f"  !! {robot.name}: a solution outside the joint limits")


if __name__ == "__main__":
    main()
