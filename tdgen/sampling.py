"""Workspace sampling: random joint configurations, their end-effector positions and collisions.

Configurations are drawn uniformly within the joint limits (random, not a grid: no aliasing, and
any N works). The end-effector positions come from the link frames of `LinkFrames` in compiled code
(they agree with pybullet's link frames to well under a micrometre, see the tests), the collision
flags from the collision model: by default the fast one (`tdgen.robot.fast_collision`: spheres and hull faces in
compiled code on all cores, pybullet's exact test only for what they cannot decide, so the same
answers), or with `collision_model="exact"` pybullet for every configuration. The exact checks run
in worker processes (spawn context; each worker owns one DIRECT client holding the scene and the
robot) when there are many. All random numbers are drawn up front from one seeded generator and
chunks come back in order, so a seed gives the same points whatever the number of workers.

What counts as a collision: see `tdgen.robot.collision`.

Positions are in the robot's base frame, in mm, wherever the scene puts the robot.
"""
from __future__ import annotations

import multiprocessing
import os
import sys
from dataclasses import dataclass
from typing import Callable

import numpy as np
from tqdm import tqdm

from tdgen.robot.collision import CollisionWorld
from tdgen.robot.link_frames import LinkFrames
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import Surroundings

CHUNK = 1000
COLLISION_MODELS = ("fast", "exact")
IN_PROCESS = 20_000  # exact checks up to this many run here: a pool costs about a second to start


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
                     progress: bool = False, on_progress: Callable[[float], None] | None = None,
                     collision_model: str = "fast") -> Samples:
    """Draw n configurations and find their end-effector positions and collisions.

    `collision_model` "fast" (the default) or "exact" (pybullet for every configuration). Exact checks
    run in this process with `workers=1` or when they are few; more use a spawn pool, which pickles
    the robot: its passive map, if any, must be a module-level function.
    The progress bar goes to stderr and only shows when asked and stderr is a terminal;
    `on_progress(fraction)` is called after each chunk of configurations is checked.
    """
    if n < 1:
        raise ValueError("need at least one sample")
    if collision_model not in COLLISION_MODELS:
        raise ValueError(f"collision model must be one of {', '.join(COLLISION_MODELS)}, not {collision_model!r}")
    q = random_configurations(robot, n, seed)
    bar = tqdm(total=n, unit="samples", file=sys.stderr, disable=not (progress and sys.stderr.isatty()))
    checked = 0

    def done(count: int) -> None:
        nonlocal checked
        checked += count
        bar.update(count)
        if on_progress is not None:
            on_progress(checked / n)

    with bar:
        # a scene or robot pybullet cannot load fails here, in a fraction of a second
        world = CollisionWorld(robot, scene)
        try:
            if collision_model == "exact":
                tips = _tip_positions(world, robot, scene, q)
                collision = _exact(world, robot, scene, q, workers, done)
            else:
                collision, tips = _fast(world, robot, scene, q, workers, done)
        finally:
            world.close()
    return Samples(q=q, positions=np.round(tips * 1000.0, 3), collision=collision)


FAST_CHUNK = 65_536  # configurations per call of the compiled model: memory stays flat in N


def _tip_positions(world: CollisionWorld, robot: Robot, scene: Surroundings, q: np.ndarray) -> np.ndarray:
    """(N, 3) tip positions in the robot's base frame (m): the link frames of `LinkFrames`, compiled, in
    chunks (`ForwardKinematics` gives the same to well under a micrometre, at a third of the speed)."""
    frames = LinkFrames(robot, scene.robot.position, scene.robot.quaternion(), world.link_names())
    return np.vstack([frames.positions(q[i:i + FAST_CHUNK], robot.ee_link) for i in range(0, len(q), FAST_CHUNK)])


def _fast(world: CollisionWorld, robot: Robot, scene: Surroundings, q: np.ndarray, workers: int | None,
          done: Callable[[int], None]) -> tuple[np.ndarray, np.ndarray]:
    """The sphere model's verdicts, and pybullet's for the configurations it leaves unsure; and the tip
    positions (m, base frame) from the same compiled pass."""
    from tdgen.robot.fast_collision import COLLIDES, UNSURE, FastCollision

    fast = FastCollision(world)
    verdicts, tips = [], []
    for start in range(0, len(q), FAST_CHUNK):
        verdict, tip = fast.spheres.verdicts_and_tips(q[start:start + FAST_CHUNK], robot.ee_link)
        verdicts.append(verdict)
        tips.append(tip)
        done(int(np.sum(verdict != UNSURE)))
    verdict = np.concatenate(verdicts)
    collision = verdict == COLLIDES
    unsure = np.flatnonzero(verdict == UNSURE)
    if len(unsure):
        collision[unsure] = _exact(world, robot, scene, q[unsure], workers, done)
    return collision, np.vstack(tips)


def _exact(world: CollisionWorld, robot: Robot, scene: Surroundings, q: np.ndarray, workers: int | None,
           done: Callable[[int], None]) -> np.ndarray:
    """pybullet's exact test for every row of q: here for few rows (or one worker), else in a spawn pool."""
    chunks = [q[i:i + CHUNK] for i in range(0, len(q), CHUNK)]
    workers = max(1, min(workers or default_workers(), len(chunks)))
    flags = []
    if workers == 1 or len(q) <= IN_PROCESS:
        for chunk in chunks:
            flags.append(world.colliding(chunk))
            done(len(chunk))
    else:
        ctx = multiprocessing.get_context("spawn")
        with ctx.Pool(workers, initializer=_init_worker, initargs=(robot, scene)) as pool:
            for chunk, result in zip(chunks, pool.imap(_check_chunk, chunks)):
                flags.append(result)
                done(len(chunk))
    return np.concatenate(flags) if flags else np.zeros(0, dtype=bool)

