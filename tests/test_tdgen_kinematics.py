"""Robot introspection and forward kinematics, checked against pybullet and the UR10's DH model."""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET

import numpy as np
import pybullet as pb
import pytest
from arms import CHAINS, LINK, ROBOTS, level, linkage_urdf, random_q

from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import ROBOTS_DIR, Robot, RobotError


def pybullet_positions(robot: Robot, q: np.ndarray) -> np.ndarray:
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client)
        out = []
        for row in q:
            for index, value in robot.full_joint_values(row).items():
                pb.resetJointState(body, index, value, physicsClientId=client)
            out.append(pb.getLinkState(body, robot.ee_index, computeForwardKinematics=True, physicsClientId=client)[4])
        return np.array(out)
    finally:
        pb.disconnect(client)


@pytest.mark.parametrize("urdf,ee", CHAINS)
def test_fk_matches_pybullet_link_frame(urdf, ee):
    """pybullet reports link states rounded to float32 (asserted here), so agreement is bounded
    by that rounding (~1e-7 m); the double-precision comparison is the Jacobian test below."""
    robot = Robot.load(urdf, ee=ee)
    q = random_q(robot, 100)
    reported = pybullet_positions(robot, q)
    assert np.array_equal(reported.astype(np.float32).astype(float), reported)
    assert np.abs(ForwardKinematics(robot).positions(q) - reported).max() < 2.5e-7


@pytest.mark.parametrize("urdf,ee", CHAINS)
def test_jacobian_matches_pybullet_in_double_precision(urdf, ee):
    """Each column is axis x (ee - joint origin), so this pins the FK chain to < 1e-9 m too."""
    robot = Robot.load(urdf, ee=ee)
    fk = ForwardKinematics(robot)
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client)
        movable = [i for i in range(pb.getNumJoints(body, physicsClientId=client))
                   if pb.getJointInfo(body, i, physicsClientId=client)[2] != pb.JOINT_FIXED]
        for q in random_q(robot, 30, seed=1):
            values = robot.full_joint_values(q)
            for index, value in values.items():
                pb.resetJointState(body, index, value, physicsClientId=client)
            zeros = [0.0] * len(movable)
            lin, _ = pb.calculateJacobian(body, robot.ee_index, [0, 0, 0], [values.get(i, 0.0) for i in movable],
                                          zeros, zeros, physicsClientId=client)
            expected = np.array(lin)[:, [movable.index(j.index) for j in robot.joints]]
            assert np.abs(fk.jacobians(q) - expected).max() < 1e-9
    finally:
        pb.disconnect(client)


def test_passive_and_mimic_joints_follow_the_main_joints(tmp_path):
    robot = Robot.load(linkage_urdf(tmp_path), passive_joints=["j3"], passive=level)
    assert [j.name for j in robot.joints] == ["j1", "j2"]
    assert robot.ee_link == "tool"
    q = random_q(robot, 50)
    fk = ForwardKinematics(robot)
    assert np.abs(fk.positions(q) - pybullet_positions(robot, q)).max() < 2.5e-7
    values = robot.full_joint_values(np.array([0.3, -0.4]))
    assert values[2] == pytest.approx(0.4) and values[3] == pytest.approx(0.5 * -0.4 + 0.1)
    eps = 1e-6
    numeric = np.stack([(fk.positions(q + eps * e) - fk.positions(q - eps * e)) / (2 * eps)
                        for e in np.eye(2)], axis=-1)
    assert np.abs(fk.jacobians(q) - numeric).max() < 1e-8


def ur10_dh(q: np.ndarray) -> np.ndarray:
    """Standard DH forward kinematics of the UR10 (published parameters), one config."""
    d = [0.1273, 0, 0, 0.163941, 0.1157, 0.0922]
    a = [0, -0.612, -0.5723, 0, 0, 0]
    alpha = [math.pi / 2, 0, 0, math.pi / 2, -math.pi / 2, 0]
    t = np.eye(4)
    for th, di, ai, al in zip(q, d, a, alpha):
        ct, st, ca, sa = math.cos(th), math.sin(th), math.cos(al), math.sin(al)
        t = t @ np.array([[ct, -st * ca, st * sa, ai * ct], [st, ct * ca, -ct * sa, ai * st],
                          [0, sa, ca, di], [0, 0, 0, 1]])
    return t[:3, 3]


def test_ur10_urdf_matches_dh_parameters():
    robot = Robot.load("ur10.urdf")
    assert robot.ee_link == "ee_link"
    assert [j.name for j in robot.joints] == ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
                                               "wrist_1_joint", "wrist_2_joint", "wrist_3_joint"]
    q = random_q(robot, 200)
    dh = np.array([ur10_dh(row) for row in q])
    assert np.abs(ForwardKinematics(robot).positions(q) - dh).max() < 1e-9


def test_ur10_links_have_inertials_and_non_adjacent_ones_do_not_touch_at_home():
    robot = Robot.load("ur10.urdf")
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client, flags=pb.URDF_USE_SELF_COLLISION)
        n = pb.getNumJoints(body, physicsClientId=client)
        parent = {i: pb.getJointInfo(body, i, physicsClientId=client)[16] for i in range(n)}
        pb.performCollisionDetection(physicsClientId=client)
        for a in range(-1, n):
            for b in range(a + 1, n):
                if parent[b] == a:
                    continue
                close = pb.getClosestPoints(body, body, 0.005, a, b, physicsClientId=client)
                assert not close, f"links {a} and {b} are within 5 mm at q = 0"
    finally:
        pb.disconnect(client)
    links = ET.parse(robot.urdf_path).getroot().findall("link")
    assert all(float(link.find("inertial/mass").get("value")) > 0 for link in links)


@pytest.mark.parametrize("urdf", ROBOTS)
def test_info_limits_are_the_urdf_limits_in_deg_and_mm(urdf):
    robot = Robot.load(urdf)
    path = robot.urdf_path
    assert path.is_file() and (urdf != "ur10.urdf" or path.parent == ROBOTS_DIR)
    xml = {j.get("name"): j for j in ET.parse(path).getroot().findall("joint")}
    info = robot.info()
    assert info["jointAmount"] == len(info["jointNames"]) == len(robot.joints)
    for name, kind, low, high in zip(info["jointNames"], info["jointTypes"], info["jointLimitLows"],
                                     info["jointLimitHighs"]):
        limit = xml[name].find("limit")
        assert kind == xml[name].get("type") == "revolute"
        assert low == pytest.approx(math.degrees(float(limit.get("lower"))), abs=1e-9)
        assert high == pytest.approx(math.degrees(float(limit.get("upper"))), abs=1e-9)


def test_panda_main_joints_are_the_arm_and_fingers_need_an_explicit_ee():
    arm = Robot.load("franka_panda/panda.urdf")
    assert arm.ee_link == "panda_grasptarget"
    assert [j.name for j in arm.joints] == [f"panda_joint{i}" for i in range(1, 8)]
    finger = Robot.load("franka_panda/panda.urdf", ee="panda_leftfinger")
    assert finger.joints[-1].name == "panda_finger_joint1" and finger.joints[-1].type == "prismatic"
    assert finger.info()["jointLimitHighs"][-1] == pytest.approx(40.0)  # 0.04 m in mm
    assert finger.joints[-1].max_velocity == pytest.approx(0.2)


def test_units_and_continuous_joints(tmp_path):
    robot = Robot.load(linkage_urdf(tmp_path), ee="side")
    assert [(j.name, j.type) for j in robot.joints] == [("j1", "revolute"), ("spin", "continuous")]
    assert robot.joints[1].lower == -math.pi and robot.joints[1].upper == math.pi
    assert robot.info()["jointLimitHighs"] == pytest.approx([math.degrees(2), 180.0])
    assert robot.joints[0].max_velocity == 2.0
    finger = Robot.load("franka_panda/panda.urdf", ee="panda_leftfinger")
    q = random_q(finger, 5)
    user = finger.to_user_units(q)
    assert user[:, -1] == pytest.approx(q[:, -1] * 1000) and user[:, 0] == pytest.approx(np.degrees(q[:, 0]))
    assert finger.from_user_units(user) == pytest.approx(q)
    assert finger.to_user_units(q[0]).shape == (8,)


def test_load_into_places_the_base():
    robot = Robot.load("ur10.urdf")
    q = random_q(robot, 1)[0]
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client, base_position=(1.0, 2.0, 0.5), base_yaw=math.pi / 2)
        for index, value in robot.full_joint_values(q).items():
            pb.resetJointState(body, index, value, physicsClientId=client)
        world = pb.getLinkState(body, robot.ee_index, computeForwardKinematics=True, physicsClientId=client)[4]
    finally:
        pb.disconnect(client)
    x, y, z = ForwardKinematics(robot).positions(q)
    assert np.allclose(world, (1.0 - y, 2.0 + x, 0.5 + z), atol=2.5e-7)


def test_bad_urdfs_raise_clear_robot_errors(tmp_path):
    with pytest.raises(RobotError, match="nowhere.urdf: URDF file not found"):
        Robot.load(tmp_path / "nowhere.urdf")
    broken = tmp_path / "broken.urdf"
    broken.write_text("<robot name='x'><link name='a'></robot>")
    with pytest.raises(RobotError, match="broken.urdf: broken XML"):
        Robot.load(broken)
    rigid = tmp_path / "rigid.urdf"
    rigid.write_text(f"<robot name='rigid'>{LINK.format('a')}{LINK.format('b')}"
                     "<joint name='f' type='fixed'><parent link='a'/><child link='b'/></joint></robot>")
    with pytest.raises(RobotError, match="rigid.urdf: no actuated joint"):
        Robot.load(rigid)
    with pytest.raises(RobotError, match="ur10.urdf: no link named 'tool0'.*wrist_3_link"):
        Robot.load("ur10.urdf", ee="tool0")
    with pytest.raises(RobotError, match="linkage.urdf: passive joints \\['j3'\\] need a passive map"):
        Robot.load(linkage_urdf(tmp_path), passive_joints=["j3"])
