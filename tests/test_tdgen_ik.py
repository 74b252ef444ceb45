"""Position IK: round trips on the four arms, limits, seeds, unreachable targets and the CLI."""
from __future__ import annotations

import csv

import numpy as np
import pytest
from arms import ROBOTS, level, linkage_urdf, random_q
from click.testing import CliRunner

from tdgen.cli.ik import ik_command
from tdgen.robot import ik
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot


def within_limits(robot: Robot, q: np.ndarray) -> bool:
    return bool(np.all((q >= robot.lows()) & (q <= robot.highs())))


@pytest.fixture(scope="module", params=ROBOTS)
def fk(request) -> ForwardKinematics:
    return ForwardKinematics(Robot.load(request.param))


def test_batch_round_trip_reaches_every_random_target(fk):
    targets = fk.positions(random_q(fk.robot, 200, seed=7))
    res = ik.solve_many(fk, targets, rng=1)
    assert res.ok.all()
    assert np.linalg.norm(fk.positions(res.q) - targets, axis=1).max() < ik.TOL_M
    assert within_limits(fk.robot, res.q)


def test_single_round_trip_reaches_every_random_target(fk):
    rng = np.random.default_rng(2)
    for target in fk.positions(random_q(fk.robot, 50, seed=8)):
        res = ik.solve(fk, target, rng=rng)
        assert res.ok, f"{fk.robot.name}: {target} missed by {res.error_m} m"
        assert np.linalg.norm(fk.positions(res.q) - target) == pytest.approx(res.error_m, abs=1e-12)
        assert np.allclose(res.reached_m, fk.positions(res.q), atol=1e-12)
        assert within_limits(fk.robot, res.q)


def test_a_near_seed_gives_the_nearby_solution(fk):
    """A target close to the current pose is solved close to it: no jump to another branch."""
    q_now = random_q(fk.robot, 1, seed=3)[0]
    q_true = np.clip(q_now + 0.02, fk.robot.lows(), fk.robot.highs())
    res = ik.solve(fk, fk.positions(q_true), seed=q_now, rng=0)
    assert res.ok
    assert np.abs(res.q - q_now).max() < 0.2


def test_targets_beyond_the_limits_are_never_answered_outside_them():
    """FK of configurations up to 50 % beyond the Panda's (narrow) limits: some are unreachable,
    none may come back outside the limits, and what is reported ok really is within tol."""
    fk = ForwardKinematics(Robot.load("franka_panda/panda.urdf"))
    lo, hi = fk.robot.lows(), fk.robot.highs()
    span = hi - lo
    q = np.random.default_rng(4).uniform(lo - 0.5 * span, hi + 0.5 * span, (100, fk.n))
    targets = fk.positions(q)
    res = ik.solve_many(fk, targets, max_restarts=10, rng=0)
    assert within_limits(fk.robot, res.q)
    assert np.all(np.linalg.norm(fk.positions(res.q[res.ok]) - targets[res.ok], axis=1) <= ik.TOL_M)
    assert res.ok.mean() > 0.5


def test_unreachable_target_reports_the_closest_point_found():
    fk = ForwardKinematics(Robot.load("ur10.urdf"))
    res = ik.solve(fk, [3.0, 0.0, 0.5], rng=0)
    assert not res.ok
    assert res.error_m > 1.5  # reach of a UR10 is ~1.3 m
    assert np.allclose(res.reached_m, fk.positions(res.q)) and within_limits(fk.robot, res.q)


def test_passive_linkage_robot_is_solved(tmp_path):
    fk = ForwardKinematics(Robot.load(linkage_urdf(tmp_path), passive_joints=["j3"], passive=level))
    targets = fk.positions(random_q(fk.robot, 50, seed=5))
    res = ik.solve_many(fk, targets, rng=0)
    assert res.ok.all() and within_limits(fk.robot, res.q)


# --- CLI ---------------------------------------------------------------------------------------
def test_cli_prints_named_joints_and_the_reached_point():
    result = CliRunner().invoke(ik_command, ["ur10.urdf", "500", "-100", "300"])
    assert result.exit_code == 0, result.output
    assert "shoulder_pan_joint" in result.output and "wrist_3_joint" in result.output and "deg" in result.output
    assert "reached (500.000, -100.000, 300.000) mm, error 0.0000" in result.output


def test_cli_refuses_an_unreachable_target_with_the_closest_point():
    result = CliRunner().invoke(ik_command, ["ur10.urdf", "3000", "0", "500"])
    assert result.exit_code == 1
    assert "not reachable by ur10" in result.output and "closest point found" in result.output


def test_cli_solves_a_csv_of_targets(tmp_path):
    fk = ForwardKinematics(Robot.load("kuka_iiwa/model.urdf"))
    targets = fk.positions(random_q(fk.robot, 20, seed=6)) * 1000
    src, out = tmp_path / "targets.csv", tmp_path / "solutions.csv"
    src.write_text("x,y,z\n" + "\n".join(",".join(f"{v:.4f}" for v in t) for t in targets) + "\n\n")
    result = CliRunner().invoke(ik_command, ["kuka_iiwa/model.urdf", "--targets", str(src), "--out", str(out)])
    assert result.exit_code == 0, result.output
    assert "solved 20/20 (100.00%)" in result.output and "median" in result.output
    rows = list(csv.DictReader(out.open()))
    assert list(rows[0])[:7] == ["x", "y", "z", "reached_x", "reached_y", "reached_z", "error_mm"]
    assert list(rows[0])[7:] == [j.name for j in fk.robot.joints]
    for row, target in zip(rows, targets):
        q = fk.robot.from_user_units(np.array([float(row[j.name]) for j in fk.robot.joints]))
        assert np.linalg.norm(fk.positions(q) * 1000 - target) < 0.0101  # joints printed to 1e-6 deg


@pytest.mark.parametrize("args,message", [
    (["missing.urdf", "1", "2", "3"], "missing.urdf: URDF file not found"),
    (["ur10.urdf", "--ee", "tool0", "1", "2", "3"], "no link named 'tool0'"),
    (["ur10.urdf", "--seed", "1,2", "1", "2", "3"], "ur10 has 6 main joints, got 2"),
])
def test_cli_errors_are_messages_not_tracebacks(args, message):
    result = CliRunner().invoke(ik_command, args)
    assert result.exit_code == 2 and message in result.output
    assert isinstance(result.exception, SystemExit)


def test_cli_names_the_bad_csv_line(tmp_path):
    src = tmp_path / "targets.csv"
    src.write_text("100,200,300\n100,abc,300\n")
    result = CliRunner().invoke(ik_command, ["ur10.urdf", "--targets", str(src)])
    assert result.exit_code == 2
    assert "targets.csv line 2: expected x,y,z in mm, got '100,abc,300'" in result.output


def _pybullet_pose(robot: Robot, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The tip's position (m) and quaternion by pybullet's own forward kinematics (the independent check)."""
    import pybullet as pb

    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client)
        for index, value in robot.full_joint_values(q).items():
            pb.resetJointState(body, index, value, physicsClientId=client)
        state = pb.getLinkState(body, robot.ee_index, computeForwardKinematics=True, physicsClientId=client)
        return np.array(state[4]), np.array(state[5])
    finally:
        pb.disconnect(client)


def test_pose_targets_are_reached_within_a_hundredth_of_a_mm_and_of_a_degree(fk):
    """Random reachable poses (FK of random configurations, orientation as roll/pitch/yaw): pose IK
    finds configurations pybullet agrees put the tip there within 0.01 mm and 0.01 deg."""
    from scipy.spatial.transform import Rotation

    from tdgen.robot.pose_ik import solve_pose

    robot = fk.robot
    rng = np.random.default_rng(11)
    for q_true in rng.uniform(robot.lows(), robot.highs(), (12, fk.n)):
        position, quaternion = _pybullet_pose(robot, q_true)
        rpy = Rotation.from_quat(quaternion).as_euler("xyz", degrees=True)
        result = solve_pose(fk, position, rpy, rng=0)
        assert result.ok and within_limits(robot, result.q), (robot.name, result.error_m, result.error_rad)
        reached, orientation = _pybullet_pose(robot, result.q)
        assert np.linalg.norm(reached - position) * 1000 <= 0.01
        angle = (Rotation.from_quat(orientation) * Rotation.from_quat(quaternion).inv()).magnitude()
        assert np.degrees(angle) <= 0.01 + 1e-6  # pybullet's float orientation


def test_a_pose_a_four_joint_arm_cannot_take_is_refused_by_the_cli_with_how_far_it_is():
    result = CliRunner().invoke(ik_command, ["uarm_swift_pro.urdf", "200", "0", "100", "--rpy", "0", "45", "0"])
    assert result.exit_code == 1 and "not reachable" in result.output and "45.000 deg away" in result.output
    ok = CliRunner().invoke(ik_command, ["ur10.urdf", "600", "200", "400", "--rpy", "180", "0", "90"])
    assert ok.exit_code == 0 and "error 0.000000 mm and 0.000000 deg" in ok.output, ok.output
