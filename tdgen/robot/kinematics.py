"""Vectorised forward kinematics and Jacobians (positional, and geometric for poses) of a `Robot`'s end effector.

Built once from the URDF chain itself (joint origins xyz/rpy and axes, as the file states them),
so it matches pybullet's link frames without a physics client, and evaluates thousands of
configurations per numpy call: sampling and IK need that, one pybullet call per point does not
scale.

Every movable joint is rewritten as a rotation/translation about its own z axis (a constant
rotation Q with Q z = axis goes before it, Q^T after), so each step only mixes two columns.
Mimic joints and passive joints enter through `Robot.drives()`: a joint value is
multiplier * source + offset, the source being a main joint or a column of `robot.passive(q)`.
"""
from __future__ import annotations

import numpy as np

from tdgen.robot.model import Robot, UrdfJoint


def _rpy_matrix(rpy: tuple[float, float, float]) -> np.ndarray:
    """URDF fixed-axis roll, pitch, yaw: R = Rz(yaw) Ry(pitch) Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array([[cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                     [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                     [-sp, cp * sr, cp * cr]])


def _origin(j: UrdfJoint) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = _rpy_matrix(j.rpy)
    t[:3, 3] = j.xyz
    return t


def _z_to(axis: np.ndarray) -> np.ndarray:
    """A rotation Q with Q @ e_z = axis (unit)."""
    z = axis / np.linalg.norm(axis)
    helper = np.array([1.0, 0.0, 0.0]) if abs(z[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(z, x), z])


class ForwardKinematics:
    """End-effector position (robot base frame, m) and its Jacobian for (N, n) main-joint values."""

    def __init__(self, robot: Robot):
        self.robot = robot
        self.n = len(robot.joints)
        drives = robot.drives()
        n_passive = len(robot.passive_names)
        pre, prismatic, carry = [], [], np.eye(4)
        a_main, a_pass, const = [], [], []
        for j in robot.chain():
            carry = carry @ _origin(j)
            if j.type == "fixed":
                continue
            q_rot = np.eye(4)
            q_rot[:3, :3] = _z_to(np.asarray(j.axis, dtype=float))
            pre.append(carry @ q_rot)
            carry = q_rot.T.copy()
            prismatic.append(j.type == "prismatic")
            d = drives[j.name]
            col_m, col_p = np.zeros(self.n), np.zeros(n_passive)
            if d.kind == "main":
                col_m[d.index] = d.multiplier
            elif d.kind == "passive":
                col_p[d.index] = d.multiplier
            a_main.append(col_m)
            a_pass.append(col_p)
            const.append(d.offset)
        self._rot = [t[:3, :3].copy() for t in pre]
        self._trans = [t[:3, 3].copy() for t in pre]
        self._prismatic = prismatic
        self._post = carry[:3, 3].copy()
        self._post_rot = carry[:3, :3].copy()  # the tip link's orientation after the last joint frame
        self._a_main = np.array(a_main).reshape(len(pre), self.n).T          # (n, m)
        self._a_pass = np.array(a_pass).reshape(len(pre), n_passive).T       # (n_passive, m)
        self._const = np.array(const, dtype=float)
        self._uses_passive = bool(np.any(self._a_pass))

    def _passive(self, q: np.ndarray) -> np.ndarray:
        assert self.robot.passive is not None, "only called when the chain uses passive joints"
        return self.robot.passive(q)

    def _chain_values(self, q: np.ndarray) -> np.ndarray:
        v = q @ self._a_main + self._const
        if self._uses_passive:
            v = v + np.atleast_2d(self._passive(q)) @ self._a_pass
        return v

    def _chain_derivative(self, q: np.ndarray) -> np.ndarray:
        """d(chain joint values)/d(main joints): (N, m, n); passive maps by central differences."""
        d = np.broadcast_to(self._a_main.T, (len(q), *self._a_main.T.shape))
        if not self._uses_passive:
            return d
        eps = 1e-6
        steps = np.eye(self.n) * eps
        plus = np.stack([self._passive(q + s) for s in steps], axis=-1)
        minus = np.stack([self._passive(q - s) for s in steps], axis=-1)
        dp = (plus - minus) / (2 * eps)                                      # (N, n_passive, n)
        return d + np.einsum("pm,Npn->Nmn", self._a_pass, dp)

    def _walk(self, q: np.ndarray, with_axes: bool, with_rotation: bool = False):
        """Positions (N, 3) and, if asked, joint axes and origins (N, m, 3) in the base frame (and,
        `with_rotation`, the tip's orientation (N, 3, 3) as the fourth value)."""
        v = self._chain_values(q)
        n = len(q)
        rot = np.broadcast_to(np.eye(3), (n, 3, 3))
        pos = np.zeros((n, 3))
        axes, origins = [], []
        for k, (r_pre, t_pre) in enumerate(zip(self._rot, self._trans)):
            pos = pos + rot @ t_pre
            rot = rot @ r_pre
            if with_axes:
                axes.append(rot[:, :, 2].copy())
                origins.append(pos)
            if self._prismatic[k]:
                pos = pos + rot[:, :, 2] * v[:, k:k + 1]
            else:
                c, s = np.cos(v[:, k:k + 1]), np.sin(v[:, k:k + 1])
                x, y = rot[:, :, 0].copy(), rot[:, :, 1].copy()  # rot is a fresh product here
                rot[:, :, 0] = c * x + s * y
                rot[:, :, 1] = c * y - s * x
        pos = pos + rot @ self._post
        if with_rotation:
            return pos, axes, origins, rot @ self._post_rot
        return pos, axes, origins

    def positions(self, q: np.ndarray) -> np.ndarray:
        """End-effector positions: (N, n) -> (N, 3), or (n,) -> (3,)."""
        q = np.asarray(q, dtype=float)
        pos, _, _ = self._walk(np.atleast_2d(q), with_axes=False)
        return pos[0] if q.ndim == 1 else pos

    def positions_and_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, n) -> positions (N, 3) and positional Jacobians (N, 3, n), from one pass."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pos, axes, origins = self._walk(q, with_axes=True)
        if not axes:
            return pos, np.zeros((len(q), 3, self.n))
        z = np.stack(axes, axis=-1)                                           # (N, 3, m)
        lever = pos[:, :, None] - np.stack(origins, axis=-1)
        cols = np.where(np.array(self._prismatic), z, np.cross(z, lever, axis=1))
        return pos, cols @ self._chain_derivative(q)

    def poses_and_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, n) -> tip positions (N, 3), orientations (N, 3, 3) and geometric Jacobians (N, 6, n):
        rows 0-2 the position's, rows 3-5 the angular velocity's (base frame), for pose IK."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pos, axes, origins, rot = self._walk(q, with_axes=True, with_rotation=True)
        if not axes:
            return pos, rot, np.zeros((len(q), 6, self.n))
        z = np.stack(axes, axis=-1)                                           # (N, 3, m)
        lever = pos[:, :, None] - np.stack(origins, axis=-1)
        prismatic = np.array(self._prismatic)
        linear = np.where(prismatic, z, np.cross(z, lever, axis=1))
        angular = np.where(prismatic, 0.0, z)
        return pos, rot, np.concatenate([linear, angular], axis=1) @ self._chain_derivative(q)

    def jacobians(self, q: np.ndarray) -> np.ndarray:
        """Positional Jacobians d(ee position)/d(main joints): (N, n) -> (N, 3, n), (n,) -> (3, n)."""
        q = np.asarray(q, dtype=float)
        jac = self.positions_and_jacobians(q)[1]
        return jac[0] if q.ndim == 1 else jac
