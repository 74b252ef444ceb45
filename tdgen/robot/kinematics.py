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

import time

import numpy as np

from tdgen.robot.cores import compile_in_background, compiled, njit  # numba, its compiled code in the user's cache
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


@njit(cache=True)
def _chain(v, rots, trans, prismatic, post, pos, axes, linear, rot):
    """The walk down the chain for rows of joint values v (N, m), compiled: a numpy walk costs a fixed overhead per
    call whatever N, which a few rows (an IK's) pay on every iteration. Fills the tip's position pos (N, 3),
    each joint's z axis and its effect on the tip's position (N, m, 3: z x (tip - origin) turning, z
    sliding) and the last joint frame's orientation rot (N, 3, 3). Plain loops: they compile in a second,
    matrix products would take several (a robot process pays that once per machine)."""
    r, t = np.empty((3, 3)), np.empty((3, 3))
    p = np.empty(3)
    for s in range(v.shape[0]):
        for a in range(3):
            p[a] = 0.0
            for b in range(3):
                r[a, b] = 1.0 if a == b else 0.0
        for k in range(v.shape[1]):
            for a in range(3):
                p[a] += r[a, 0] * trans[k, 0] + r[a, 1] * trans[k, 1] + r[a, 2] * trans[k, 2]
            for a in range(3):
                for b in range(3):
                    t[a, b] = r[a, 0] * rots[k, 0, b] + r[a, 1] * rots[k, 1, b] + r[a, 2] * rots[k, 2, b]
            for a in range(3):
                axes[s, k, a] = t[a, 2]
                linear[s, k, a] = p[a]  # the joint's origin, until the tip is known
            if prismatic[k]:
                for a in range(3):
                    p[a] += t[a, 2] * v[s, k]
                    r[a, 0], r[a, 1], r[a, 2] = t[a, 0], t[a, 1], t[a, 2]
            else:
                c, sn = np.cos(v[s, k]), np.sin(v[s, k])
                for a in range(3):
                    r[a, 0] = c * t[a, 0] + sn * t[a, 1]
                    r[a, 1] = c * t[a, 1] - sn * t[a, 0]
                    r[a, 2] = t[a, 2]
        for a in range(3):
            pos[s, a] = p[a] + r[a, 0] * post[0] + r[a, 1] * post[1] + r[a, 2] * post[2]
            for b in range(3):
                rot[s, a, b] = r[a, b]
        for k in range(v.shape[1]):
            if prismatic[k]:
                for a in range(3):
                    linear[s, k, a] = axes[s, k, a]
            else:
                lx, ly, lz = pos[s, 0] - linear[s, k, 0], pos[s, 1] - linear[s, k, 1], pos[s, 2] - linear[s, k, 2]
                x, y, z = axes[s, k, 0], axes[s, k, 1], axes[s, k, 2]
                linear[s, k, 0] = y * lz - z * ly
                linear[s, k, 1] = z * lx - x * lz
                linear[s, k, 2] = x * ly - y * lx


_LOOK_EVERY = 1.0  # s between looks for the compiled code (`_chain_code`)
_compiled_at = [0.0, 0.0]  # [when it was found on disk (0: not yet), when last looked for]


def _chain_code():
    """`_chain`, compiled where the machine has our compiled code (`cores.compiled`); until then its Python
    function, run as it is written (the same steps, slower), while the code compiles in a process of its
    own (`cores.compile_in_background`): a first start compiles nothing in a process that serves."""
    if _compiled_at[0]:
        return _chain
    now = time.monotonic()
    if now - _compiled_at[1] >= _LOOK_EVERY:
        _compiled_at[1] = now
        if compiled():
            _compiled_at[0] = now
            return _chain
        compile_in_background()
    return _chain.py_func


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
        self._rots = np.array([t[:3, :3] for t in pre], dtype=float).reshape(len(pre), 3, 3)
        self._translations = np.array([t[:3, 3] for t in pre], dtype=float).reshape(len(pre), 3)
        self._sliding = np.array(prismatic, dtype=np.bool_)
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

    def _walk(self, q: np.ndarray, with_rotation: bool = False):
        """Positions (N, 3), joint axes and their effects on the position (N, m, 3) in the base frame (and,
        `with_rotation`, the tip's orientation (N, 3, 3) as the fourth value)."""
        v = np.ascontiguousarray(self._chain_values(q), dtype=float)
        n, m = len(q), len(self._rots)
        pos, rot = np.empty((n, 3)), np.empty((n, 3, 3))
        axes, linear = np.empty((n, m, 3)), np.empty((n, m, 3))
        _chain_code()(v, self._rots, self._translations, self._sliding, self._post, pos, axes, linear, rot)
        if with_rotation:
            return pos, axes, linear, rot @ self._post_rot
        return pos, axes, linear

    def positions(self, q: np.ndarray) -> np.ndarray:
        """End-effector positions: (N, n) -> (N, 3), or (n,) -> (3,)."""
        q = np.asarray(q, dtype=float)
        pos, _, _ = self._walk(np.atleast_2d(q))
        return pos[0] if q.ndim == 1 else pos

    def positions_and_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(N, n) -> positions (N, 3) and positional Jacobians (N, 3, n), from one pass."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pos, _, linear = self._walk(q)
        return pos, linear.transpose(0, 2, 1) @ self._chain_derivative(q)

    def poses_and_jacobians(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(N, n) -> tip positions (N, 3), orientations (N, 3, 3) and geometric Jacobians (N, 6, n):
        rows 0-2 the position's, rows 3-5 the angular velocity's (base frame), for pose IK."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        pos, axes, linear, rot = self._walk(q, with_rotation=True)
        angular = np.where(self._sliding[None, :, None], 0.0, axes)
        return pos, rot, np.concatenate([linear, angular], axis=2).transpose(0, 2, 1) @ self._chain_derivative(q)

    def jacobians(self, q: np.ndarray) -> np.ndarray:
        """Positional Jacobians d(ee position)/d(main joints): (N, n) -> (N, 3, n), (n,) -> (3, n)."""
        q = np.asarray(q, dtype=float)
        jac = self.positions_and_jacobians(q)[1]
        return jac[0] if q.ndim == 1 else jac
