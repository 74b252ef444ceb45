"""Workspace sampling: random joint configurations, their end-effector positions and collisions.

Configurations are drawn uniformly within the joint limits (random, not a grid: no aliasing, and
any N works). The end-effector positions come from the vectorised `ForwardKinematics` (it agrees
with pybullet's link frames to well under a micrometre, see the tests), the collision flags from
pybullet worlds in worker processes (spawn context; each worker owns one DIRECT client holding the
scene and the robot). All random numbers are drawn up front from one seeded generator and chunks
come back in order, so a seed gives the same points whatever the number of workers.

What counts as a collision (penetration deeper than `CONTACT_TOLERANCE`):
- the robot with itself, except pairs of links that are rigidly joined or joined by one joint
  ("adjacent"; joints no configuration moves, such as a Panda's finger, count as rigid) and pairs
  in contact both at the home pose (q = 0 clipped to the limits) and at mid-range: meshes that
  overlap by design (a Panda's hand and link 6), not poses that happen to fold the arm;
- the robot with a scene body, except the links rigidly fixed to the base: a robot bolted onto a
  table touches it in every configuration, which says nothing about the configuration.

Positions are in the robot's base frame, in mm, wherever the scene puts the robot.
"""
from __future__ import annotations

import math
import multiprocessing
import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from tdgen.kinematics import ForwardKinematics
from tdgen.robot import Robot
from tdgen.scene import Scene, build_into

CONTACT_TOLERANCE = 1e-4  # m: contacts shallower than this are touching, not colliding
CHUNK = 1000


@dataclass(frozen=True)
class Samples:
    q: np.ndarray           # (N, n) main-joint values, SI (rad, m)
    positions: np.ndarray   # (N, 3) end-effector positions, robot base frame, mm
    collision: np.ndarray   # (N,) bool

    @property
    def free(self) -> np.ndarray:
        """Positions of the collision-free samples (mm)."""
        return self.positions[~self.collision]


class CollisionWorld:
    """One pybullet DIRECT client with the scene and the robot: answers "does q collide?"."""

    def __init__(self, robot: Robot, scene: Scene):
        import pybullet as pb

        self._pb = pb
        self.robot = robot
        self.client = pb.connect(pb.DIRECT)
        try:
            build_into(scene, self.client)
            self.body = robot.load_into(self.client, scene.robot.position, math.radians(scene.robot.yaw),
                                        flags=pb.URDF_USE_SELF_COLLISION)
        except Exception:
            pb.disconnect(self.client)
            raise
        names = {pb.getJointInfo(self.body, i, physicsClientId=self.client)[1].decode(): i
                 for i in range(pb.getNumJoints(self.body, physicsClientId=self.client))}
        self._indices = [names[n] for n in robot.joint_values(np.zeros((1, len(robot.joints))))]
        group = self._rigid_groups()
        self._fixed_to_base = {link for link, g in group.items() if g == group[-1]}
        self._excluded = self._adjacent_pairs(group)
        self._excluded |= self._touching_by_design()

    def close(self) -> None:
        self._pb.disconnect(self.client)

    def _values(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values -> (N, m) values of every driven pybullet joint."""
        return np.column_stack(list(self.robot.joint_values(q).values()))

    def _set(self, values: np.ndarray) -> None:
        for index, value in zip(self._indices, values):
            self._pb.resetJointState(self.body, index, value, physicsClientId=self.client)

    def _rigid_groups(self) -> dict[int, int]:
        """link index -> group: links joined by fixed (or never moved) joints share a group."""
        pb, moving = self._pb, set(self._indices)
        group = {-1: -1}
        for i in range(pb.getNumJoints(self.body, physicsClientId=self.client)):  # parents come first
            parent = pb.getJointInfo(self.body, i, physicsClientId=self.client)[16]
            group[i] = i if i in moving else group[parent]
        return group

    def _adjacent_pairs(self, group: dict[int, int]) -> set[tuple[int, int]]:
        """Link pairs in one rigid group or in two groups joined by one joint."""
        pb = self._pb
        joined = {(g, g) for g in group.values()}
        for i in self._indices:
            parent = pb.getJointInfo(self.body, i, physicsClientId=self.client)[16]
            joined |= {(group[i], group[parent]), (group[parent], group[i])}
        return {(a, b) for a in group for b in group if (group[a], group[b]) in joined}

    def _touching_by_design(self) -> set[tuple[int, int]]:
        """Self-contact pairs at both the home pose (q = 0 within the limits) and mid-range."""
        lows, highs = self.robot.lows(), self.robot.highs()
        pairs = []
        for q in (np.clip(np.zeros(len(lows)), lows, highs), (lows + highs) / 2):
            self._set(self._values(q[None])[0])
            pairs.append({p for (a, b), other in self._contacts() if other == self.body for p in ((a, b), (b, a))})
        return pairs[0] & pairs[1]

    def _contacts(self) -> list[tuple[tuple[int, int], int]]:
        """((robot link, other link), other body) for every penetrating contact of the robot."""
        pb = self._pb
        pb.performCollisionDetection(physicsClientId=self.client)
        found = []
        for c in pb.getContactPoints(bodyA=self.body, physicsClientId=self.client):
            if c[8] < -CONTACT_TOLERANCE:
                if c[1] == self.body:
                    found.append(((c[3], c[4]), c[2]))
                else:
                    found.append(((c[4], c[3]), c[1]))
        return found

    def _colliding(self) -> bool:
        for (link, other_link), other in self._contacts():
            if other == self.body:
                if (link, other_link) not in self._excluded:
                    return True
            elif link not in self._fixed_to_base:
                return True
        return False

    def colliding(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values (SI) -> (N,) bool: collides with itself or the scene."""
        values = self._values(np.atleast_2d(q))
        out = np.empty(len(values), dtype=bool)
        for k, row in enumerate(values):
            self._set(row)
            out[k] = self._colliding()
        return out


_world: CollisionWorld | Exception | None = None  # the worker process's own world, or why it has none


def _init_worker(robot: Robot, scene: Scene) -> None:
    global _world
    try:
        _world = CollisionWorld(robot, scene)
    except Exception as exc:  # noqa: BLE001 - a raising initializer makes the pool respawn workers forever
        _world = exc


def _check_chunk(q: np.ndarray) -> np.ndarray:
    if isinstance(_world, Exception):
        raise _world
    assert _world is not None, "worker not initialised"
    return _world.colliding(q)


def random_configurations(robot: Robot, n: int, seed: int | None) -> np.ndarray:
    """(n, dof) joint values drawn uniformly within the limits (SI)."""
    return np.random.default_rng(seed).uniform(robot.lows(), robot.highs(), size=(n, len(robot.joints)))


def default_workers() -> int:
    return os.cpu_count() or 1


def sample_workspace(robot: Robot, scene: Scene, n: int, seed: int | None = 0, workers: int | None = None,
                     progress: bool = False) -> Samples:
    """Draw n configurations and find their end-effector positions and collisions.

    `workers=1` checks in this process (no start-up cost: small runs, tests); more use a spawn pool,
    which pickles the robot: its passive map, if any, must be a module-level function.
    The progress bar goes to stderr and only shows when asked and stderr is a terminal.
    """
    if n < 1:
        raise ValueError("need at least one sample")
    q = random_configurations(robot, n, seed)
    positions = np.round(ForwardKinematics(robot).positions(q) * 1000.0, 3)
    chunks = [q[i:i + CHUNK] for i in range(0, n, CHUNK)]
    workers = max(1, min(workers or default_workers(), len(chunks)))
    bar = tqdm(total=n, unit="samples", file=sys.stderr, disable=not (progress and sys.stderr.isatty()))
    flags = []
    with bar:
        if workers == 1:
            world = CollisionWorld(robot, scene)
            try:
                for chunk in chunks:
                    flags.append(world.colliding(chunk))
                    bar.update(len(chunk))
            finally:
                world.close()
        else:
            ctx = multiprocessing.get_context("spawn")
            with ctx.Pool(workers, initializer=_init_worker, initargs=(robot, scene)) as pool:
                for chunk, result in zip(chunks, pool.imap(_check_chunk, chunks)):
                    flags.append(result)
                    bar.update(len(chunk))
    return Samples(q=q, positions=positions, collision=np.concatenate(flags))


def write_points_csv(path: Path, robot: Robot, samples: Samples) -> None:
    """points.csv: `x,y,z,collision,<joint names>`; mm, 0/1, then deg or mm per joint."""
    joints = robot.to_user_units(samples.q)
    header = ",".join(["x", "y", "z", "collision", *(j.name for j in robot.joints)])
    table = np.column_stack([samples.positions, samples.collision.astype(int), joints])
    fmt = ["%.3f"] * 3 + ["%d"] + ["%.6f"] * joints.shape[1]
    np.savetxt(path, table, fmt=fmt, delimiter=",", header=header, comments="")


def read_points_csv(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3) mm, collision (N,) bool) from a points.csv."""
    with open(path) as f:
        header = f.readline().strip().split(",")
    if header[:4] != ["x", "y", "z", "collision"]:
        raise ValueError(f"{path}: not a points CSV (header starts {header[:4]})")
    table = np.loadtxt(path, delimiter=",", skiprows=1, usecols=(0, 1, 2, 3), ndmin=2)
    return table[:, :3], table[:, 3].astype(bool)
