"""Arms for the kinematics and IK tests: the four shipped and bundled URDFs, a small linkage with a
passive and a mimic joint, random configurations."""
from __future__ import annotations

import numpy as np

from tdgen.robot.model import Robot

ROBOTS = ["franka_panda/panda.urdf", "kuka_iiwa/model.urdf", "xarm/xarm6_robot.urdf", "ur10.urdf"]
# (urdf, ee): the four arms, plus the Panda to its left finger (a prismatic joint on the chain)
CHAINS = [(u, None) for u in ROBOTS] + [("franka_panda/panda.urdf", "panda_leftfinger")]

LINK = ('<link name="{0}"><inertial><mass value="1"/>'
        '<inertia ixx="0.01" ixy="0" ixz="0" iyy="0.01" iyz="0" izz="0.01"/></inertial></link>')
JOINT = ('<joint name="{0}" type="{1}"><parent link="{2}"/><child link="{3}"/><origin xyz="{4}" rpy="{5}"/>'
         '<axis xyz="{6}"/><limit lower="-2" upper="2" effort="1" velocity="{7}"/>{8}</joint>')


def linkage_urdf(tmp_path) -> str:
    """A small arm with a passive joint (j3 = -j2, as a parallelogram keeps a tool level) and a
    mimic joint (j4 = 0.5 j2 + 0.1), odd axes and rpy, and a continuous wrist off the chain."""
    links = "".join(LINK.format(n) for n in ["base", "l1", "l2", "l3", "l4", "tool", "side"])
    joints = [
        JOINT.format("j1", "revolute", "base", "l1", "0 0 0.1", "0 0 0.3", "0 0 1", 2, ""),
        JOINT.format("j2", "revolute", "l1", "l2", "0.02 0 0.2", "0.1 0.2 0", "0 1 0", 0, ""),
        JOINT.format("j3", "revolute", "l2", "l3", "0.3 0 0", "0 0 0", "0 0.6 0.8", 1, ""),
        JOINT.format("j4", "prismatic", "l3", "l4", "0.25 0 0", "0.5 0 0", "1 0 0", 1,
                     '<mimic joint="j2" multiplier="0.5" offset="0.1"/>'),
        JOINT.format("tool_joint", "fixed", "l4", "tool", "0.05 0.01 0", "0 0 0", "1 0 0", 1, ""),
        JOINT.format("spin", "continuous", "l1", "side", "0 0.1 0", "0 0 0", "0 0 1", 1, ""),
    ]
    path = tmp_path / "linkage.urdf"
    path.write_text(f'<?xml version="1.0"?><robot name="linkage">{links}{"".join(joints)}</robot>')
    return str(path)


def level(q: np.ndarray) -> np.ndarray:
    return -q[:, [1]]


def random_q(robot: Robot, n: int, seed: int = 0) -> np.ndarray:
    return np.random.default_rng(seed).uniform(robot.lows(), robot.highs(), (n, len(robot.joints)))
