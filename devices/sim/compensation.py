"""Passive joints of the parallelogram arms (uArm Swift Pro, Dobot Magician), set from the main joints.

Both arms drive their second link through a parallelogram, so the motor angles are absolute
(measured against the horizontal or vertical, not against the previous link) and the tool stays
level. Our URDFs (tdgen/robot/models/) model that with two passive joints on the serial chain:
`elbow_passive` undoes the first arm's rotation, so the next main joint is an absolute angle, and
`wrist_passive` undoes that one, so the tool is level. The maps below are exactly what tdgen's
`Robot.load(urdf, ee=..., passive_joints=[...], passive=fn)` takes: (N, n_main) -> (N, n_passive),
columns in the order of the `*_PASSIVE_JOINTS` names.

`KinematicArm` is how the twins use them: a URDF robot whose main joints a device sets and whose
passive joints follow through the map.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Callable, Sequence

import numpy as np
import pybullet as pb

from devices.sim.vec import Vec
from tdgen.robot.model import ROBOTS_DIR

if TYPE_CHECKING:
    from devices.sim.pybullet_world import Pose, World

MODELS = ROBOTS_DIR

UARM_URDF = MODELS / "uarm_swift_pro.urdf"
UARM_MAIN_JOINTS = ("base", "lower_arm", "upper_arm", "hand")
UARM_PASSIVE_JOINTS = ("elbow_passive", "wrist_passive")
UARM_EE = "tcp"

DOBOT_URDF = MODELS / "dobot_magician.urdf"
DOBOT_MAIN_JOINTS = ("j1_base", "j2_rear_arm", "j3_forearm", "j4_end")
DOBOT_PASSIVE_JOINTS = ("elbow_passive", "wrist_passive")
DOBOT_EE = "tcp"


def _level(q: np.ndarray, first: int, second: int) -> np.ndarray:
    q = np.atleast_2d(np.asarray(q, dtype=float))
    return np.stack([-q[:, first], -q[:, second]], axis=1)


def uarm_passive(q: np.ndarray) -> np.ndarray:
    """(N, 4) main [base, lower_arm, upper_arm, hand] -> (N, 2) [elbow_passive, wrist_passive]."""
    return _level(q, 1, 2)


def dobot_passive(q: np.ndarray) -> np.ndarray:
    """(N, 4) main [j1_base, j2_rear_arm, j3_forearm, j4_end] -> (N, 2) [elbow_passive, wrist_passive]."""
    return _level(q, 1, 2)


class KinematicArm:
    """A fixed-base URDF robot moved by setting joint values (no dynamics, no collisions).

    Main joints are set by the device, passive joints follow through the compensation map; all
    links are taken out of collision so a teleported link never kicks a cube (held cubes hang on
    a constraint instead). Motors are off and `hold()` puts every joint back after each physics
    step (gravity and a held cube's weight would otherwise bend the arm). `q` is replaced, never
    mutated, so other threads may read it.
    """

    def __init__(self, client: int, urdf: str, base_pos: Vec, base_orn: Vec,
                 main: Sequence[str], passive: Sequence[str] = (),
                 compensation: Callable[[np.ndarray], np.ndarray] | None = None, world: World | None = None):
        self.client = client
        self.body = pb.loadURDF(urdf, list(base_pos), list(base_orn), useFixedBase=True, physicsClientId=client)
        n = pb.getNumJoints(self.body, physicsClientId=client)
        infos = [pb.getJointInfo(self.body, i, physicsClientId=client) for i in range(n)]
        self.joint_index = {info[1].decode(): i for i, info in enumerate(infos)}
        self.link_index = {info[12].decode(): i for i, info in enumerate(infos)}
        self.main, self.passive = list(main), list(passive)
        self._compensation = compensation
        self._main_idx = [self.joint_index[j] for j in self.main]
        self._passive_idx = [self.joint_index[j] for j in self.passive]
        self._movable = [i for i, info in enumerate(infos) if info[2] != pb.JOINT_FIXED]
        for link in range(-1, n):
            pb.setCollisionFilterGroupMask(self.body, link, 0, 0, physicsClientId=client)
        pb.setJointMotorControlArray(self.body, self._movable, pb.VELOCITY_CONTROL,
                                     forces=[0.0] * len(self._movable), physicsClientId=client)
        self.q = np.zeros(len(self.main))
        self.extra: dict[str, float] = {}
        self._hold_joints: list[int] = []
        self._hold_values: list[list[float]] = []
        if world is not None:
            world.add_post_step(self.hold, physics=True)  # only gravity bends it

    def apply(self, q: Vec) -> None:
        """Set the main joints (and the passive ones from them). Stepping thread."""
        q = np.asarray(q, dtype=float).copy()
        self.q = q
        self._update_targets()
        self.hold()

    def set_joint(self, name: str, value: float) -> None:
        """A joint outside the main chain (a finger). Stepping thread."""
        self.extra = {**self.extra, name: float(value)}
        self._update_targets()
        self.hold()

    def hold(self, dt: float = 0.0) -> None:
        """Every joint back to its commanded value, at rest. Stepping thread. One call for the whole arm:
        pybullet updates the body's links once per call, and this runs after every physics step."""
        if self._hold_joints:
            pb.resetJointStatesMultiDof(self.body, self._hold_joints, self._hold_values, physicsClientId=self.client)

    def _update_targets(self) -> None:
        targets = list(zip(self._main_idx, map(float, self.q)))
        if self._compensation is not None:
            targets += zip(self._passive_idx, map(float, self._compensation(self.q[None])[0]))
        targets += [(self.joint_index[n], v) for n, v in self.extra.items()]
        self._hold_joints = [i for i, _ in targets]
        self._hold_values = [[v] for _, v in targets]

    def link_pose(self, link: str) -> Pose:
        st = pb.getLinkState(self.body, self.link_index[link], computeForwardKinematics=True,
                             physicsClientId=self.client)
        return tuple(st[4]), tuple(st[5])

    def joint_values(self) -> dict[str, float]:
        """Main, passive and extra joint values by name (what a recorder animates)."""
        out = dict(zip(self.main, map(float, self.q)))
        if self._compensation is not None:
            out.update(zip(self.passive, map(float, self._compensation(self.q[None])[0])))
        out.update(self.extra)
        return out
