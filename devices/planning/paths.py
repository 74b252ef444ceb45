"""Collision-free joint paths: a dense check of the straight joint-space path, OMPL where it collides.

The check is exact to a stated resolution: between two checked states of a segment no point of
any link moves more than `step_mm` (default 5 mm), by the bound `sum(|dq_i| * radius_i)` of
`CollisionWorld.sweep_radii`. States are checked in bisection order, so a colliding segment is
usually found out after a few checks.

Where the straight path collides, OMPL's RRTConnect plans in the same collision world (a plain
callable is its state validity checker; on the fast model, a motion validator judges each motion's
states in one batched call; the planner never knows how validity is computed) to any
of the goal configurations given, within a time budget; the path is simplified by OMPL and then
checked again by the dense check above, so a planner that was too coarse can never hand back a
colliding path: the plan is repeated at a finer planner resolution while the budget lasts.

The budget is spent in rounds (`ROUND_S`, then twice as long each time). A round that finds no path
at all usually means that the goal configurations at hand sit in pockets of the free space (an arm
folded under the table's edge); a caller that can draw more (`more_goals`: fresh IK solutions) gets
asked between rounds, and a fresh goal is often reached straight (how often: docs/benchmarks.md).
"""
from __future__ import annotations

import functools
import math
import time
from dataclasses import dataclass, field
from typing import Callable, Sequence

import numpy as np

from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import FastCollision

STEP_MM = 5.0            # no point of the robot moves further than this between two checked states
PLANNING_BUDGET_S = 1.0  # default time a plan may take
ROUND_S = 0.05           # the first planning round (with `more_goals`); each later round twice as long
DISTINCT_RAD = 1e-3      # two configurations closer than this (every joint, rad or m) are one
_COARSE = 20.0           # the planner's own motion checks are this much coarser than STEP_MM at first
_RANGE = 1.0             # RRTConnect's longest extension (rad or m): short ones waste fewer checks
BATCH = 4                # segments of this many states or more are judged at once by the fast model
GROWN_MM = 40.0          # the fast model's first pass over a segment: states this far apart, the robot grown by half


@dataclass(frozen=True)
class JointPath:
    """Waypoints (K, n) in SI units, first = start, last = goal; how they were found and at what cost."""

    waypoints: np.ndarray
    method: str          # "straight" | "planned"
    planning_ms: float
    checks: int          # collision checks made to find and verify it


@dataclass
class NoPath(Exception):
    """No collision-free path within the budget: what was tried, for the refusal's details."""

    detail: str
    tried: dict = field(default_factory=dict)

    def __str__(self) -> str:
        return self.detail


class PathChecker:
    """Collision checks of states and straight segments in one collision model (not thread-safe): the
    fast one (`FastCollision`, the exact test's answers) or pybullet's exact `CollisionWorld`."""

    def __init__(self, world: CollisionWorld | FastCollision, step_mm: float = STEP_MM):
        self.world = world
        self.step_m = step_mm / 1000.0
        self.radii = world.sweep_radii()
        self.grow_radii = world.grow_radii() if isinstance(world, FastCollision) else None
        self.checks = 0

    def free(self, q: np.ndarray) -> bool:
        self.checks += 1
        return not self.world.collides(q)

    def subdivisions(self, a: np.ndarray, b: np.ndarray, step_m: float | None = None) -> int:
        """How many equal parts a->b needs so that no point moves more than the step within one."""
        sweep = float(np.sum(np.abs(np.asarray(b) - np.asarray(a)) * self.radii))
        return max(1, math.ceil(sweep / (step_m or self.step_m)))

    def segment_free(self, a: np.ndarray, b: np.ndarray) -> bool:
        """Whether every state of a->b at the resolution is free (a itself is not checked at it).

        With the fast model, a pass of states `GROWN_MM` apart first, each judged with the robot grown
        by half that: one found free vouches for every state around it (no point of the robot is further
        from where it is there), and only the states no one vouches for are checked at the resolution."""
        a, b = np.asarray(a, dtype=float), np.asarray(b, dtype=float)
        n = self.subdivisions(a, b)
        if isinstance(self.world, FastCollision) and n >= BATCH:
            order = _bisection_order(n)
            assert self.grow_radii is not None
            per_link = np.abs(b - a) @ self.grow_radii  # how far each link (and pair) moves along the segment
            m = math.ceil(float(per_link.max()) / (GROWN_MM / 1000.0))
            if m * 2 <= n:
                coarse = np.append(_bisection_order(m), 0)
                self.checks += len(coarse)
                covered = self.world.covering(a + (b - a) * (coarse[:, None] / m), per_link / (2 * m))
                if covered is None:
                    return False
                vouched = np.zeros(m + 1, dtype=bool)
                vouched[coarse] = covered
                # the nearest coarse state of fine state j: |j/n - k/m| <= 1/(2m), where no link has moved further
                # than its grow, per_link/(2m)
                order = order[~vouched[np.rint(order * m / n).astype(int)]]
            self.checks += len(order)
            return not self.world.first_collision(a + (b - a) * (order[:, None].astype(float) / n))
        for k in _bisection_order(n).tolist():
            if not self.free(a + (b - a) * (k / n)):
                return False
        return True

    def path_free(self, waypoints: np.ndarray) -> bool:
        return all(self.segment_free(p, q) for p, q in zip(waypoints[:-1], waypoints[1:]))


@functools.lru_cache(maxsize=4096)
def _bisection_order(n: int) -> np.ndarray:
    """1..n, the end first, then midpoints of ever finer halves: collisions show up early. (Each k is ranked
    by the lowest set bit of its nearest place on a grid of 2^L <= n steps: halves, then quarters, ...)
    Kept per n, read-only: a planner asks it for every motion it tries (a quarter of their checking time)."""
    k = np.arange(1, n)
    grid = 1 << (n.bit_length() - 1)
    place = np.maximum((2 * k * grid + n) // (2 * n), 1).astype(np.int64)
    lowest_bit = np.bitwise_and(place, np.negative(place))
    order = np.concatenate([[n], k[np.argsort(np.negative(lowest_bit), kind="stable")]]).astype(np.int64)
    order.flags.writeable = False
    return order


def find_path(checker: PathChecker, start: np.ndarray, goals: Sequence[np.ndarray], lows: np.ndarray,
              highs: np.ndarray, budget_s: float = PLANNING_BUDGET_S,
              more_goals: Callable[[], Sequence[np.ndarray]] | None = None) -> JointPath:
    """A collision-free path from `start` to one of `goals` (tried in the order given): straight if
    one is free, else planned. `more_goals` (optional) draws further goal configurations, asked after
    each planning round that found no path. Raises NoPath with what was tried."""
    started, checks0 = time.perf_counter(), checker.checks
    start = np.asarray(start, dtype=float)
    goals = [np.asarray(g, dtype=float) for g in goals]

    def straight(candidates: list[np.ndarray]) -> JointPath | None:
        goal = next((g for g in candidates if checker.segment_free(start, g)), None)
        return None if goal is None else JointPath(np.array([start, goal]), "straight", _ms(started),
                                                   checker.checks - checks0)

    if found := straight(goals):
        return found
    if not checker.free(start):
        raise NoPath("the robot collides where it stands, so no path can leave it",
                     {"start_collides": True})
    tried: dict = {"straight": len(goals), "planner": "RRTConnect", "budget_s": budget_s, "attempts": 0,
                   "goal_draws": 1}
    resolution = checker.step_m * _COARSE
    round_s = ROUND_S if more_goals is not None else budget_s
    while True:
        left = budget_s - (time.perf_counter() - started)
        if left <= 0.005:
            break
        tried["attempts"] += 1
        paths = _ompl_paths(checker, start, goals, lows, highs, resolution, min(left, round_s))
        for path in paths:
            if checker.path_free(path):
                return JointPath(path, "planned", _ms(started), checker.checks - checks0)
        if paths:  # found, but it clips an obstacle between the planner's checks: plan finer
            if resolution <= checker.step_m:
                tried["resolution_mm"] = resolution * 1000
            resolution = max(checker.step_m, resolution / 2)
            continue
        round_s *= 2
        if more_goals is None or budget_s - (time.perf_counter() - started) <= 0.005:
            continue
        fresh = [g for g in map(np.asarray, more_goals())
                 if all(np.abs(g - other).max() > DISTINCT_RAD for other in goals)]
        tried["goal_draws"] += 1
        tried["straight"] += len(fresh)
        if found := straight(fresh):
            return found
        goals += fresh
    tried["checks"] = checker.checks - checks0
    tried["goals"] = len(goals)
    draws = f" from {tried['goal_draws']} draws" if tried["goal_draws"] > 1 else ""
    raise NoPath(f"no collision-free path found within {budget_s:g} s (RRTConnect, {tried['attempts']} "
                 f"attempt{'s' if tried['attempts'] != 1 else ''}, {len(goals)} goal configuration"
                 f"{'s' if len(goals) != 1 else ''}{draws})", tried)


def _ms(started: float) -> float:
    return round((time.perf_counter() - started) * 1000.0, 3)


_quiet = False


def _silence_ompl() -> None:
    global _quiet
    if not _quiet:
        from ompl import util as ou

        ou.setLogLevel(ou.LOG_NONE)
        _quiet = True


def _ompl_paths(checker: PathChecker, start: np.ndarray, goals: Sequence[np.ndarray], lows: np.ndarray,
                highs: np.ndarray, resolution_m: float, budget_s: float) -> list[np.ndarray]:
    """RRTConnect from start to any goal; the simplified path and then the raw one (each may still
    clip an obstacle between the planner's coarser checks: the caller checks them densely)."""
    from ompl import base as ob
    from ompl import geometric as og

    _silence_ompl()
    n = len(start)
    space = ob.RealVectorStateSpace(n)
    bounds = ob.RealVectorBounds(n)
    for i in range(n):
        bounds.setLow(i, float(lows[i]))
        bounds.setHigh(i, float(highs[i]))
    space.setBounds(bounds)
    setup = og.SimpleSetup(space)
    setup.setStateValidityChecker(lambda s: checker.free(np.array([s[i] for i in range(n)])))
    si = setup.getSpaceInformation()
    if isinstance(checker.world, FastCollision):  # a motion's states judged in one call
        motions = _batched_motions()(si, checker, n, resolution_m)  # held here while OMPL plans with it
        si.setMotionValidator(motions)
    else:
        # the planner checks motions every `fraction` of the space's extent; a joint step of size d
        # moves no point more than d * |radii| (Cauchy-Schwarz), so this keeps its checks near resolution_m
        step = resolution_m / max(float(np.linalg.norm(checker.radii)), 1e-9)
        si.setStateValidityCheckingResolution(min(0.05, step / space.getMaximumExtent()))

    def state(values: np.ndarray):
        s = space.allocState()
        for i, v in enumerate(values):
            s[i] = float(v)
        return s

    goal = ob.GoalStates(si)
    for g in goals:
        goal.addState(state(np.clip(g, lows, highs)))
    setup.setStartState(state(start))
    setup.setGoal(goal)
    planner = og.RRTConnect(si)
    if _RANGE > 0:
        planner.setRange(_RANGE)
    setup.setPlanner(planner)
    deadline = time.perf_counter() + budget_s
    setup.solve(budget_s)
    if not setup.haveExactSolutionPath():
        return []
    raw = _states(setup.getSolutionPath(), n)
    setup.simplifySolution(max(0.0, min(0.25, deadline - time.perf_counter())))
    simplified = _states(setup.getSolutionPath(), n)
    for path in (simplified, raw):  # exact ends: the start and the goal as given, not as float-copied
        path[0] = start
        path[-1] = min(goals, key=lambda g: float(np.abs(np.asarray(g) - path[-1]).max()))
    return [simplified, raw]


@functools.cache
def _batched_motions() -> type:
    """OMPL's motion validator for the fast model: a motion's states at the planner's resolution judged in
    one call (`FastCollision.first_collision`: the spheres for all of them at once, the exact test for
    the unsure ones), instead of one Python call per state."""
    from ompl import base as ob

    class BatchedMotions(ob.MotionValidator):
        def __init__(self, si, checker: PathChecker, n: int, resolution_m: float):
            super().__init__(si)
            self.checker, self.n, self.resolution_m = checker, n, resolution_m

        def checkMotion(self, s1, s2, *last_valid) -> bool:  # noqa: N802 - OMPL's name
            # (the overload with `last_valid` is not used by RRTConnect or the path simplifier)
            n, checker = self.n, self.checker
            a, b = np.array([s1[i] for i in range(n)]), np.array([s2[i] for i in range(n)])
            k = checker.subdivisions(a, b, self.resolution_m)
            checker.checks += k
            assert isinstance(checker.world, FastCollision)
            return not checker.world.first_collision(a + (b - a) * (_bisection_order(k)[:, None] / k))

    return BatchedMotions


def _states(path, n: int) -> np.ndarray:
    return np.array([[path.getState(k)[i] for i in range(n)] for k in range(path.getStateCount())])
