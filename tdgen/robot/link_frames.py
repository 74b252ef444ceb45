"""Every link's frame, for thousands of configurations at once: what a collision model needs.

`ForwardKinematics` follows one chain to the tip; a collision model needs the whole tree (a
gripper's fingers, a second branch) where the robot stands in its scene. The frames are the
URDF link frames (pybullet's `worldLinkFramePosition`), built from the joints as the file states
them; joints that `Robot.drives()` does not name (a branch nobody moves) stay at 0, as they do in
pybullet's world.
"""
from __future__ import annotations

import numpy as np

from tdgen.robot.kinematics import _origin
from tdgen.robot.model import Robot


def _axis_rotations(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """(N,) angles about one unit axis -> (N, 3, 3) rotations (Rodrigues)."""
    x, y, z = axis
    k = np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])
    s, c = np.sin(angle)[:, None, None], np.cos(angle)[:, None, None]
    return np.eye(3) + s * k + (1.0 - c) * (k @ k)


class LinkFrames:
    """World rotations (N, L, 3, 3) and origins (N, L, 3) of the links, in pybullet's link order
    (index -1, the base, first), for (N, n) main-joint values (SI)."""

    def __init__(self, robot: Robot, base_position, base_quaternion, link_names: list[str]):
        from scipy.spatial.transform import Rotation

        self.robot = robot
        self.names = link_names  # pybullet order: [base, link 0, link 1, ...]
        self._base_rot = Rotation.from_quat(base_quaternion).as_matrix()
        self._base_pos = np.asarray(base_position, dtype=float)
        by_child = {j.child: j for j in robot._urdf_joints.values()}
        index = {name: k for k, name in enumerate(link_names)}
        drives = robot.drives()
        self._steps = []  # (link slot, parent slot, origin 4x4, kind, axis, drive)
        for k, name in enumerate(link_names[1:], start=1):
            j = by_child[name]
            axis = np.asarray(j.axis, dtype=float)
            axis = axis / (np.linalg.norm(axis) or 1.0)
            kind = j.type if j.type in ("revolute", "continuous", "prismatic") else "fixed"
            self._steps.append((k, index[j.parent], _origin(j), kind, axis, drives.get(j.name)))

    def _value(self, drive, q: np.ndarray, passive: np.ndarray | None) -> np.ndarray:
        if drive is None or drive.kind == "const":
            return np.full(len(q), drive.offset if drive is not None else 0.0)
        source = q[:, drive.index] if drive.kind == "main" else passive[:, drive.index]  # type: ignore[index]
        return drive.multiplier * source + drive.offset

    def values(self, q: np.ndarray) -> np.ndarray:
        """(N, L) the value of the joint above each link (0 for the base and fixed joints)."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        passive = np.atleast_2d(self.robot.passive(q)) if self.robot.passive is not None else None
        out = np.zeros((len(q), len(self.names)))
        for k, _, _, kind, _, drive in self._steps:
            if kind != "fixed":
                out[:, k] = self._value(drive, q, passive)
        return out

    def value_maps(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """`values` as a linear map: (main (n, L), passive (p, L), offsets (L,)) with values = q . main +
        passive(q) . passive + offsets."""
        count, n = len(self.names), len(self.robot.joints)
        main, passive, offsets = np.zeros((n, count)), np.zeros((len(self.robot.passive_names), count)), np.zeros(count)
        for k, _, _, kind, _, drive in self._steps:
            if kind == "fixed" or drive is None:
                continue
            if drive.kind == "main":
                main[drive.index, k] = drive.multiplier
            elif drive.kind == "passive":
                passive[drive.index, k] = drive.multiplier
            offsets[k] = drive.offset
        return main, passive, offsets

    def tables(self) -> dict[str, np.ndarray]:
        """The tree as arrays (for compiled code): parent slot, joint origin, kind (0 fixed, 1 turning,
        2 sliding) and axis per link slot, and the base's pose."""
        count = len(self.names)
        parent, kind = np.zeros(count, dtype=np.int64), np.zeros(count, dtype=np.int64)
        origin_r, origin_p, axis = np.tile(np.eye(3), (count, 1, 1)), np.zeros((count, 3)), np.zeros((count, 3))
        for k, up, origin, how, ax, _ in self._steps:
            parent[k], origin_r[k], origin_p[k], axis[k] = up, origin[:3, :3], origin[:3, 3], ax
            kind[k] = {"fixed": 0, "revolute": 1, "continuous": 1, "prismatic": 2}[how]
        return {"parent": parent, "origin_r": origin_r, "origin_p": origin_p, "kind": kind, "axis": axis,
                "base_r": np.asarray(self._base_rot, dtype=float), "base_p": self._base_pos}

    def positions(self, q: np.ndarray, link: str) -> np.ndarray:
        """(N, 3) origins of one link's frame in the robot's base frame (m), in compiled code: the
        sampled points' positions."""
        from tdgen.robot import sphere_kernel

        t = self.tables()
        world = sphere_kernel.tips(self.values(q), t["parent"], t["origin_r"], t["origin_p"], t["kind"], t["axis"],
                                   t["base_r"], t["base_p"], self.names.index(link))
        return self.to_base(world)

    def to_base(self, points: np.ndarray) -> np.ndarray:
        """World points (N, 3) -> the robot's base frame."""
        return (points - self._base_pos) @ self._base_rot

    def frames(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        n = len(q)
        passive = np.atleast_2d(self.robot.passive(q)) if self.robot.passive is not None else None
        rot = np.empty((n, len(self.names), 3, 3))
        pos = np.empty((n, len(self.names), 3))
        rot[:, 0] = self._base_rot
        pos[:, 0] = self._base_pos
        for k, parent, origin, kind, axis, drive in self._steps:
            r_parent, p_parent = rot[:, parent], pos[:, parent]
            r = r_parent @ origin[:3, :3]
            p = p_parent + r_parent @ origin[:3, 3]
            if kind in ("revolute", "continuous"):
                r = r @ _axis_rotations(axis, self._value(drive, q, passive))
            elif kind == "prismatic":
                p = p + (r @ axis) * self._value(drive, q, passive)[:, None]
            rot[:, k], pos[:, k] = r, p
        return rot, pos
