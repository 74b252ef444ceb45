"""Workspace sampling: random joint configurations, their end-effector positions and collisions.

Configurations are drawn uniformly within the joint limits (random, not a grid: no aliasing, and
any N works). The end-effector positions come from the vectorised `ForwardKinematics` (it agrees
with pybullet's link frames to well under a micrometre, see the tests), the collision flags from
pybullet worlds in worker processes (spawn context; each worker owns one DIRECT client holding the
scene and the robot). All random numbers are drawn up front from one seeded generator and chunks
come back in order, so a seed gives the same points whatever the number of workers.

What counts as a collision: see `tdgen.robot.collision`.

Positions are in the robot's base frame, in mm, wherever the scene puts the robot.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from tqdm import tqdm

from tdgen.robot.collision import CollisionWorld
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import Surroundings

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


_world: CollisionWorld | Exception | None = None  # the worker process's own world, or why it has none


def _init_worker(robot: Robot, scene: Surroundings) -> None:
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


def sample_workspace(robot: Robot, scene: Surroundings, n: int, seed: int | None = 0, workers: int | None = None,
                     progress: bool = False, on_progress: Callable[[float], None] | None = None) -> Samples:
    """Draw n configurations and find their end-effector positions and collisions.

    `workers=1` checks in this process (no start-up cost: small runs, tests); more use a spawn pool,
    which pickles the robot: its passive map, if any, must be a module-level function.
    The progress bar goes to stderr and only shows when asked and stderr is a terminal;
    `on_progress(fraction)` is called after each chunk of configurations is checked.
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
                    if on_progress is not None:
                        on_progress(sum(map(len, flags)) / n)  # a disabled bar counts nothing
            finally:
                world.close()
        else:
            # a scene or robot pybullet cannot load fails here, in a fraction of a second, not in every
            # worker (where it also used to leave Pool.terminate hanging now and then)
            CollisionWorld(robot, scene).close()
            ctx = multiprocessing.get_context("spawn")
            with ctx.Pool(workers, initializer=_init_worker, initargs=(robot, scene)) as pool:
                for chunk, result in zip(chunks, pool.imap(_check_chunk, chunks)):
                    flags.append(result)
                    bar.update(len(chunk))
                    if on_progress is not None:
                        on_progress(sum(map(len, flags)) / n)  # a disabled bar counts nothing
    return Samples(q=q, positions=positions, collision=np.concatenate(flags))


def write_points_csv(path: Path, robot: Robot, samples: Samples) -> None:
    """points.csv: `x,y,z,collision,<joint names>`; mm, 0/1, then deg or mm per joint."""
    joints = robot.to_user_units(samples.q)
    header = ",".join(["x", "y", "z", "collision", *(j.name for j in robot.joints)])
    table = np.column_stack([samples.positions, samples.collision.astype(int), joints])
    fmt = ["%.3f"] * 3 + ["%d"] + ["%.6f"] * joints.shape[1]
    np.savetxt(path, table, fmt=fmt, delimiter=",", header=header, comments="")
