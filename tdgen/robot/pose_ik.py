"""Pose inverse kinematics: the tip at a position and in an orientation, damped least squares with restarts.

The position-only solver's method (`tdgen.robot.ik`) on the 6-D error: the position error (m)
and the rotation vector from the tip's orientation to the target's (rad, base frame), the latter
weighed by `LENGTH` (m per rad) so that neither dominates the step. Rows run in parallel from
random seeds (and the caller's seed); a row that stalls restarts; the search ends at the first
row within both tolerances (0.01 mm and 0.01 deg by default), which two nearly undamped steps then
polish. Joint limits hold throughout. `accept` lets a caller refuse a solution (one that collides)
and keep searching.
"""
from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.spatial.transform import Rotation

from tdgen.robot.kinematics import ForwardKinematics

TOL_M = 1e-5                   # 0.01 mm
TOL_RAD = math.radians(0.01)   # 0.01 deg
LENGTH = 0.1                   # m per rad in the step's error norm
_MU0, _MU_MIN, _MU_MAX = 1e-3, 1e-12, 1e4
_PARALLEL, _STALL_EVERY, _STALL_RATIO = 8, 8, 0.5


@dataclass(frozen=True)
class PoseIKResult:
    q: np.ndarray              # (n,) main joint values, SI, within the limits
    position_m: np.ndarray     # (3,) the tip where q puts it
    rotation: np.ndarray       # (3, 3) its orientation
    error_m: float
    error_rad: float
    ok: bool                   # within both tolerances (and accepted)


def rotation_of(orientation: ArrayLike) -> np.ndarray:
    """A 3x3 matrix from a quaternion (x, y, z, w), roll/pitch/yaw in degrees (fixed axes), or a matrix."""
    a = np.asarray(orientation, dtype=float)
    if a.shape == (3, 3):
        return a
    if a.shape == (4,):
        return Rotation.from_quat(a).as_matrix()
    if a.shape == (3,):
        return Rotation.from_euler("xyz", a, degrees=True).as_matrix()
    raise ValueError(f"an orientation is a quaternion (4), roll/pitch/yaw (3) or a 3x3 matrix, not shape {a.shape}")


def _errors(pos: np.ndarray, rot: np.ndarray, target_p: np.ndarray, target_r: np.ndarray) -> np.ndarray:
    """(N, 6): position error (m) and rotation vector (rad) from each tip to the target, base frame."""
    rotvec = Rotation.from_matrix(target_r[None] @ rot.transpose(0, 2, 1)).as_rotvec()
    return np.concatenate([target_p[None] - pos, rotvec], axis=1)


def _step(jac: np.ndarray, err: np.ndarray, mu: np.ndarray) -> np.ndarray:
    a = jac @ jac.transpose(0, 2, 1) + mu[:, None, None] * np.eye(6)
    return (jac.transpose(0, 2, 1) @ np.linalg.solve(a, err[:, :, None]))[:, :, 0]


def solve_pose(fk: ForwardKinematics, position_m: ArrayLike, orientation: ArrayLike, seed: ArrayLike | None = None,
               tol_m: float = TOL_M, tol_rad: float = TOL_RAD, max_restarts: int = 200,
               rng: np.random.Generator | int | None = None,
               accept: Callable[[np.ndarray], bool] | None = None) -> PoseIKResult:
    """Joint values putting the tip at `position_m` (base frame, m) in `orientation` (see `rotation_of`).

    Returns the closest configuration found, ok=False, when none is within both tolerances (or
    accepted) after `max_restarts` random seeds.
    """
    target_p, target_r = np.asarray(position_m, dtype=float).reshape(3), rotation_of(orientation)
    rng = np.random.default_rng(rng)
    lo, hi, n = fk.robot.lows(), fk.robot.highs(), fk.n
    scale = np.array([1.0, 1.0, 1.0, LENGTH, LENGTH, LENGTH])
    q = rng.uniform(lo, hi, (_PARALLEL, n))
    if seed is not None:
        q[0] = np.clip(np.asarray(seed, dtype=float), lo, hi)
    pos, rot, jac = fk.poses_and_jacobians(q)
    mu, it, mark = np.full(_PARALLEL, _MU0), np.zeros(_PARALLEL, dtype=int), np.full(_PARALLEL, np.inf)
    best = (np.inf, q[0], np.inf, np.inf)
    restarts = max_restarts
    while True:
        e = _errors(pos, rot, target_p, target_r)
        e_m, e_rad = np.linalg.norm(e[:, :3], axis=1), np.linalg.norm(e[:, 3:], axis=1)
        weighted = np.linalg.norm(e * scale, axis=1)
        k = int(np.argmin(weighted))
        if weighted[k] < best[0]:
            best = (float(weighted[k]), q[k].copy(), float(e_m[k]), float(e_rad[k]))
        done = (e_m <= tol_m) & (e_rad <= tol_rad)
        for row in np.flatnonzero(done):
            polished = _polish(fk, q[row], target_p, target_r)
            if accept is None or accept(polished):
                return _result(fk, polished, target_p, target_r, tol_m, tol_rad)
            mark[row], mu[row] = 0.0, _MU_MAX  # refused: restart this row
        check = (it > 0) & (it % _STALL_EVERY == 0)
        stalled = (check & (weighted > _STALL_RATIO * mark)) | (mu >= _MU_MAX)
        mark = np.where(check, weighted, mark)
        for row in np.flatnonzero(stalled):
            if restarts <= 0:
                continue
            restarts -= 1
            q[row] = rng.uniform(lo, hi)
            mu[row], it[row], mark[row] = _MU0, 0, np.inf
        if restarts <= 0 and stalled.all():
            break
        fresh = np.flatnonzero(stalled)
        if len(fresh):
            pos[fresh], rot[fresh], jac[fresh] = fk.poses_and_jacobians(q[fresh])
            e[fresh] = _errors(pos[fresh], rot[fresh], target_p, target_r)
        dq = _step(jac * scale[None, :, None], e * scale, mu)
        q_new = np.clip(q + dq, lo, hi)
        pos_new, rot_new, jac_new = fk.poses_and_jacobians(q_new)
        better = np.linalg.norm(_errors(pos_new, rot_new, target_p, target_r) * scale, axis=1) < \
            np.linalg.norm(e * scale, axis=1)
        q = np.where(better[:, None], q_new, q)
        pos = np.where(better[:, None], pos_new, pos)
        rot = np.where(better[:, None, None], rot_new, rot)
        jac = np.where(better[:, None, None], jac_new, jac)
        mu = np.where(better, np.maximum(mu / 3, _MU_MIN), mu * 4)
        it += 1
    result = _result(fk, best[1], target_p, target_r, tol_m, tol_rad)
    return PoseIKResult(result.q, result.position_m, result.rotation, result.error_m, result.error_rad, False)


def _polish(fk: ForwardKinematics, q: np.ndarray, target_p: np.ndarray, target_r: np.ndarray,
            steps: int = 2) -> np.ndarray:
    scale = np.array([1.0, 1.0, 1.0, LENGTH, LENGTH, LENGTH])
    lo, hi = fk.robot.lows(), fk.robot.highs()
    q = q[None].copy()
    for _ in range(steps):
        pos, rot, jac = fk.poses_and_jacobians(q)
        e = _errors(pos, rot, target_p, target_r)
        q_new = np.clip(q + _step(jac * scale[None, :, None], e * scale, np.full(1, 1e-9)), lo, hi)
        p2, r2, _ = fk.poses_and_jacobians(q_new)
        if np.linalg.norm(_errors(p2, r2, target_p, target_r) * scale) < np.linalg.norm(e * scale):
            q = q_new
    return q[0]


def _result(fk: ForwardKinematics, q: np.ndarray, target_p: np.ndarray, target_r: np.ndarray,
            tol_m: float, tol_rad: float) -> PoseIKResult:
    pos, rot, _ = fk.poses_and_jacobians(q[None])
    e = _errors(pos, rot, target_p, target_r)[0]
    e_m, e_rad = float(np.linalg.norm(e[:3])), float(np.linalg.norm(e[3:]))
    return PoseIKResult(q, pos[0], rot[0], e_m, e_rad, e_m <= tol_m and e_rad <= tol_rad)
