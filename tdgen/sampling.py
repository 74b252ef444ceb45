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
import pickle
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import Callable

import numpy as np
from tqdm import tqdm

from mesh.messages.scene_description import CollisionModel
from mesh.process import run_quietly
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.cores import compile_in_background, compiled
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
                     collision_model: CollisionModel = "fast", world: CollisionWorld | None = None) -> Samples:
    """Draw n configurations and find their end-effector positions and collisions.

    `collision_model` "fast" (the default) or "exact" (pybullet for every configuration). Exact checks
    run in this process with `workers=1` or when they are few; more use a spawn pool, which pickles
    the robot: its passive map, if any, must be a module-level function.
    A machine that has not compiled the fast model yet gets the exact test's answers (the same) for up to
    COLD_EXACT samples, while the model compiles in a process of its own (`cores.compile_in_background`):
    a first workspace without waiting for the compiler.
    The progress bar goes to stderr and only shows when asked and stderr is a terminal;
    `on_progress(fraction)` is called after each chunk of configurations is checked.
    `world`: a collision world of `robot` in `scene` the caller holds (and closes), else one is made here.
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
        owned = world is None
        world = CollisionWorld(robot, scene) if world is None else world
        try:
            if collision_model == "exact":
                tips = _tip_positions(world, robot, scene, q)
                collision = _exact(world, robot, scene, q, workers, done)
            elif len(q) <= COLD_EXACT and not compiled():
                from tdgen.robot import fast_collision

                compile_in_background(fast_collision)  # the fast model's next run loads it
                tips = _tip_positions_uncompiled(world, robot, scene, q)
                collision = _exact(world, robot, scene, q, workers, done)
            else:
                collision, tips = _fast(world, robot, scene, q, workers, done)
        finally:
            if owned:
                world.close()
    return Samples(q=q, positions=np.round(tips * 1000.0, 3), collision=collision)


FAST_CHUNK = 65_536  # configurations per call of the compiled model: memory stays flat in N
# up to this many samples, a machine that has not compiled the fast model yet asks pybullet's exact test (the
# same answers) while the model compiles in another process, rather than wait for the compiler
COLD_EXACT = 200_000


def _tip_positions_uncompiled(world: CollisionWorld, robot: Robot, scene: Surroundings, q: np.ndarray) -> np.ndarray:
    """`_tip_positions` in numpy (the same to well under a micrometre): nothing to compile first."""
    frames = LinkFrames(robot, scene.robot.position, scene.robot.quaternion(), world.link_names())
    slot = frames.names.index(robot.ee_link)
    return np.vstack([frames.to_base(frames.frames(q[i:i + FAST_CHUNK])[1][:, slot])
                      for i in range(0, len(q), FAST_CHUNK)])


def _tip_positions(world: CollisionWorld, robot: Robot, scene: Surroundings, q: np.ndarray) -> np.ndarray:
    """(N, 3) tip positions in the robot's base frame (m): the link frames of `LinkFrames`, compiled, in
    chunks (`ForwardKinematics` gives the same to well under a micrometre, at a third of the speed)."""
    frames = LinkFrames(robot, scene.robot.position, scene.robot.quaternion(), world.link_names())
    return np.vstack([frames.positions(q[i:i + FAST_CHUNK], robot.ee_link) for i in range(0, len(q), FAST_CHUNK)])


def _fast(world: CollisionWorld, robot: Robot, scene: Surroundings, q: np.ndarray, workers: int | None,
          done: Callable[[int], None]) -> tuple[np.ndarray, np.ndarray]:
    """The sphere model's verdicts, and pybullet's for the configurations it leaves unsure; and the tip
    positions (m, base frame) from the same compiled pass.

    pybullet's test takes one core (and the GIL) for the unsure ones. Once those pending would keep it
    busy as long as the compiled loop needs for the rest on one core fewer, the rest runs on a thread,
    on one core fewer, while this thread checks them, so the two end together (what it saves:
    docs/benchmarks.md).
    The answers are the same whatever runs when."""
    import numba

    from tdgen.robot.fast_collision import COLLIDES, FREE, UNSURE, FastCollision

    fast = FastCollision(world)
    verdict = np.empty(len(q), dtype=np.int8)
    tips = np.empty((len(q), 3))
    pending = np.zeros(0, dtype=np.int64)  # rows the spheres left unsure that pybullet has not checked yet
    cores = numba.get_num_threads()

    def spheres(start: int, stop: int) -> np.ndarray:
        """Rows start..stop on all cores; the rows it left unsure."""
        part, tip = fast.spheres.verdicts_and_tips(q[start:stop], robot.ee_link)
        verdict[start:stop], tips[start:stop] = part, tip
        done(int(np.sum(part != UNSURE)))
        return start + np.flatnonzero(part == UNSURE)

    def spheres_of_values(values: np.ndarray, start: int, threads: int) -> None:
        """The rows from `start` on, from their joint values, on `threads` cores (numba's setting is per
        thread), tips in the world frame."""
        numba.set_num_threads(threads)
        verdict[start:] = fast.spheres.verdicts_of_values(values, robot.ee_link, tips[start:])

    def settle(count: int) -> float:
        """pybullet for the first `count` rows pending; its seconds per row."""
        nonlocal pending
        rows, pending = pending[:count], pending[count:]
        t = time.perf_counter()
        verdict[rows] = np.where(world.colliding(q[rows]), COLLIDES, FREE)
        done(len(rows))
        return (time.perf_counter() - t) / max(1, len(rows))

    start, exact_per_row, split, found = 0, 0.0, len(q), 0
    while start < split:
        stop = min(start + FAST_CHUNK, split)
        t = time.perf_counter()
        unsure = spheres(start, stop)
        loop_per_row = (time.perf_counter() - t) / (stop - start)  # all cores
        pending = np.concatenate([pending, unsure])
        found += len(unsure)
        start = stop
        if cores > 1 and len(pending) and start < len(q) and split == len(q):
            if not exact_per_row:
                exact_per_row = settle(200)  # measured on the first few
            # the loop on one core fewer is busy for rest * one_fewer; pybullet for the pending and, as the
            # loop goes on, for its share of unsure ones: split where the two are even
            one_fewer = loop_per_row * cores / (cores - 1)
            share = exact_per_row * found / start
            even = ((len(q) - start) * one_fewer - len(pending) * exact_per_row) / (one_fewer + share)
            if even < FAST_CHUNK:
                split = start + max(0, int(even))
    if start < len(q):
        values = fast.spheres.frames.values(q[start:])  # here: the thread beside runs compiled code only
        with ThreadPoolExecutor(1, thread_name_prefix="tdgen-spheres") as pool:
            rest = pool.submit(spheres_of_values, values, start, cores - 1)
            while len(pending) and not rest.done():
                settle(CHUNK)
            rest.result()
        tips[start:] = fast.spheres.frames.to_base(tips[start:])
        done(int(np.sum(verdict[start:] != UNSURE)))
        pending = np.concatenate([pending, start + np.flatnonzero(verdict[start:] == UNSURE)])
    if len(pending):
        verdict[pending] = np.where(_exact(world, robot, scene, q[pending], workers, done), COLLIDES, FREE)
    return verdict == COLLIDES, tips


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
        with ctx.Pool(workers, initializer=run_quietly, initargs=(pickle.dumps((_init_worker, (robot, scene))),)) as pool:
            for chunk, result in zip(chunks, pool.imap(_check_chunk, chunks)):
                flags.append(result)
                done(len(chunk))
    return np.concatenate(flags) if flags else np.zeros(0, dtype=bool)

