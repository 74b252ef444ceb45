"""Deciding a robot's moves: every check a move passes before anything moves, and its path.

`MovePlanner` holds one robot's scene and its collision world (the fast model or pybullet's exact
test, `collision_model`) and answers with a `MovePlan` or a `MoveRefused` naming its `reason`:
a Cartesian target must be inside the sampled workspace's hull (`outside-workspace`), reachable
within the joint limits (`unreachable`), by a configuration free of collision (`collision`), along
a collision-free joint path from where the robot stands (`no-path`); with a collision-probability
gate set, a target whose sampled neighbours collide too often is refused (`collision-risk`). Paths
come from `devices.planning.paths` (a checked straight segment, else OMPL). The twin that plays the
plans (`devices.sim.robot_twin.RobotTwin`) keeps the motion, the workspace and the listeners.
"""
from __future__ import annotations

import itertools
import math
import threading
import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Iterable, Literal, Protocol

import msgspec
import numpy as np
from scipy.spatial.transform import Rotation

from devices.planning.paths import DISTINCT_RAD, PLANNING_BUDGET_S, JointPath, NoPath, PathChecker, find_path
from mesh.messages.scene_description import CollisionModel
from mesh.wot.problem import BadInput, Refused, Unavailable
from tdgen.robot.calibration import Calibration
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import FastCollision
from tdgen.robot.ik import solve, solve_many
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot
from tdgen.robot.pose_ik import rotation_of, solve_pose
from tdgen.robot.surroundings import Body, Surroundings
from tdgen.robot.workspace_check import DEFAULT_K, DEFAULT_RADIUS_MM, Workspace

IK_SEEDS = 24       # IK runs per Cartesian target: from the current configuration and from random starts
IK_RESTARTS = 20    # random restarts each run may take before it gives up
QUICK_RESTARTS = 16  # random restarts of the first IK run, from where the arm stands (an unreachable one: given up sooner)
POSE_SOLUTIONS = 4  # pose IK solutions looked for (the first from the current configuration), collision-free ones kept
POSE_RESTARTS = 60  # random restarts per pose IK run
TRACE_STEPS = 8    # end-effector points per path segment in a move's answer (`path.tip`)


class MoveRefused(Refused):
    slug, title = "move-refused", "Move refused"


class WorkspacePending(Unavailable):
    slug, title = "workspace-generating", "Workspace not generated yet"


class TdFrame:
    """The TD's Cartesian frame: the robot's base frame (mm), or the real robot's through a calibration."""

    def __init__(self, calibration: Calibration | None = None):
        self.calibration = calibration
        if calibration is not None:
            m = np.array(calibration.fit(calibration.used).matrix)
            self._a, self._t, self._a_inv = m[:, :3], m[:, 3], np.linalg.inv(m[:, :3])

    @property
    def name(self) -> Literal["twin", "real"]:
        return "twin" if self.calibration is None else "real"

    def from_base(self, base_mm: np.ndarray) -> np.ndarray:
        p = np.asarray(base_mm, dtype=float)
        return p if self.calibration is None else p @ self._a.T + self._t

    def to_base(self, td_mm: np.ndarray) -> np.ndarray:
        p = np.asarray(td_mm, dtype=float)
        return p if self.calibration is None else (p - self._t) @ self._a_inv.T


class Tracer(Protocol):
    """What a plan's answer is drawn with: the robot's units and its tip along a path."""

    robot: Robot

    def tip_trace(self, waypoints: np.ndarray, per_segment: int = TRACE_STEPS) -> np.ndarray: ...


@dataclass(frozen=True)
class MovePlan:
    """A checked move: its collision-free path, where it ends (TD frame) and what was learnt on the way."""

    path: JointPath
    durations: list[float]                  # simulated seconds per path segment
    reached_mm: tuple[float, float, float]  # TD frame
    error_mm: float                         # from the target (Cartesian moves), else 0
    info: dict[str, Any]                    # collision_probability and neighbours, for Cartesian targets

    @property
    def q(self) -> np.ndarray:
        return self.path.waypoints[-1]

    def answer(self, twin: "Tracer") -> dict[str, Any]:
        """The move actions' output (SPEC §7): the path in TD units with its times, where it ends, how;
        `path.tip` traces the end effector along it (TD frame, mm), for drawing."""
        robot = twin.robot
        points = robot.to_user_units(self.path.waypoints)
        times = np.concatenate([[0.0], np.cumsum(self.durations)])
        out: dict[str, Any] = {
            "path": {"joints": [j.name for j in robot.joints],
                     "points": [[round(float(v), 6) for v in row] for row in points],
                     "times": [round(float(t), 6) for t in times],
                     "tip": [[round(float(v), 3) for v in p] for p in twin.tip_trace(self.path.waypoints)]},
            "reached": xyz(np.array(self.reached_mm)), "error_mm": round(self.error_mm, 6),
            "method": self.path.method, "planning_ms": self.path.planning_ms}
        if self.info.get("collision_probability") is not None:
            out["collision_probability"] = round(float(self.info["collision_probability"]), 6)
        if self.info.get("orientation") is not None:  # where the tip points at the end
            out["orientation"] = self.info["orientation"]
        if self.info.get("error_deg") is not None:    # pose moves: how far from the asked orientation
            out["error_deg"] = self.info["error_deg"]
        return out


class MovePlanner:
    """One robot's moves decided in its scene. Thread-safe: the scene and its collision world are
    behind one lock; the caller says where the robot stands now (`now`, SI) on every call.
    `peak_speed`: the motion profile's peak over mean speed (a segment's duration is its longest
    joint step over that joint's velocity limit, times it)."""

    def __init__(self, robot: Robot, name: str, scene: Surroundings, frame: TdFrame, *, peak_speed: float,
                 collision_model: CollisionModel = "fast", planning_budget: float = PLANNING_BUDGET_S,
                 max_collision_probability: float | None = None, k: int = DEFAULT_K,
                 radius_mm: float = DEFAULT_RADIUS_MM):
        if max_collision_probability is not None and not 0.0 <= max_collision_probability <= 1.0:
            raise ValueError("max_collision_probability must be within 0..1")
        self.robot, self.name, self.frame = robot, name, frame
        self.collision_model = collision_model  # sampling, target checks and planning stand on the same one
        self.planning_budget = planning_budget
        self.max_collision_probability, self.k, self.radius_mm = max_collision_probability, k, radius_mm
        self.fk = ForwardKinematics(robot)
        self.peak_speed = peak_speed
        self._scene = scene
        self._checker: PathChecker | None = None  # the live scene's collision world, for checks and paths
        self._touch_world: CollisionWorld | None = None  # only bodies about to be added (`would_touch`)
        self._lock = threading.Lock()  # the scene and its collision worlds
        self._vmax = np.array([j.max_velocity for j in robot.joints])
        self._turning = [i for i, j in enumerate(robot.joints)  # revolute joints with more than a turn of range
                         if j.type != "prismatic" and j.upper - j.lower > 2 * math.pi + 1e-9]

    # --- the scene ------------------------------------------------------------------------------
    @property
    def scene(self) -> Surroundings:
        return self._scene

    def set_scene(self, scene: Surroundings) -> None:
        """New surroundings: the next check loads them."""
        with self._lock:
            self._scene = scene
            if self._checker is not None:
                self._checker.world.close()
                self._checker = None

    def close(self) -> None:
        """Free the collision worlds' pybullet clients."""
        with self._lock:
            if self._checker is not None:
                self._checker.world.close()
                self._checker = None
            if self._touch_world is not None:
                self._touch_world.close()
                self._touch_world = None

    def collides(self, q: np.ndarray) -> bool:
        with self._lock:
            return not self._path_checker().free(q)

    def would_touch(self, bodies: list[Body], now: np.ndarray) -> bool:
        """Whether the robot at `now` would touch any of these bodies if they were added to its scene (a box
        about to be put down). A world of only them is kept for it: the robot is loaded once."""
        with self._lock:
            if self._touch_world is None:
                self._touch_world = CollisionWorld(self.robot, msgspec.structs.replace(self._scene, bodies=[]),
                                                   part=True)
            self._touch_world.set_bodies(list(bodies))
            return bool(self._touch_world.colliding(now[None])[0])

    # --- where the tip is -----------------------------------------------------------------------
    def td_position(self, q: np.ndarray) -> np.ndarray:
        """End-effector positions (TD frame, mm) of joint values (SI, one row or many)."""
        return self.frame.from_base(self.fk.positions(q) * 1000.0)

    def tip_trace(self, waypoints: np.ndarray, per_segment: int = TRACE_STEPS) -> np.ndarray:
        """End-effector positions (TD frame, mm) along a joint path, `per_segment` per straight segment."""
        u = np.linspace(0.0, 1.0, per_segment, endpoint=False)[:, None]
        qs = [a + (b - a) * u for a, b in zip(waypoints[:-1], waypoints[1:])] + [waypoints[-1:]]
        return self.td_position(np.vstack(qs))

    def durations(self, waypoints: np.ndarray) -> list[float]:
        """Simulated seconds per segment with no joint above its velocity limit (eased: `peak_speed`)."""
        steps = np.abs(np.diff(waypoints, axis=0)) / self._vmax
        return [self.peak_speed * float(np.max(row, initial=0.0)) for row in steps]

    def motion_duration(self, now: np.ndarray, goal: np.ndarray) -> float:
        """Simulated seconds from `now` to `goal` (SI) in a straight joint-space line."""
        return self.peak_speed * float(np.max(np.abs(np.asarray(goal) - now) / self._vmax, initial=0.0))

    # --- plans ----------------------------------------------------------------------------------
    def plan_joints(self, now: np.ndarray, goal: np.ndarray) -> MovePlan:
        """The path to joint values `goal` (SI), or the refusal (`collision`, `no-path`)."""
        started = time.perf_counter()
        with self._lock:
            checker = self._path_checker()
            if not checker.free(goal):
                pairs = checker.world.what_collides(goal)
                raise MoveRefused(f"{self.name}: the configuration {self._user(goal)} collides: {'; '.join(pairs)}",
                                  reason="collision", extra={"collisions": pairs})
            path = self._find_path(checker, now, [goal], started)
        return self._plan(path, None, {})

    def plan_cartesian(self, now: np.ndarray, target_mm: np.ndarray, workspace: Workspace | None,
                       workspace_error: str | None = None) -> MovePlan:
        """The path to a Cartesian target (TD frame, mm), or the refusal naming why: `outside-workspace`,
        `collision-risk` (only with a collision-probability gate), `unreachable`, `collision`, `no-path`.
        `workspace`: the sampled points the target is checked against (None: not generated, yet or at
        all: `workspace_error` says why)."""
        started = time.perf_counter()
        target = np.asarray(target_mm, dtype=float).reshape(3)
        where = f"{self.name}: target ({', '.join(f'{v:g}' for v in target)}) mm"
        info, outside = self._check_workspace(target, where, workspace, workspace_error)
        try:
            return self._plan_to(now, target, where, info, started)
        except MoveRefused as refused:
            if outside is None:  # the workspace's figures in every Cartesian answer, refusals included
                refused.extra = {**info, **(refused.extra or {})}
                raise
            # the hull is the sampled workspace: outside it, the exact search above still decides, and
            # when it refuses, being outside the workspace is the better explanation
            raise MoveRefused(f"{where} is {outside} ({refused.detail.removeprefix(where + ': ')})",
                              reason="outside-workspace",
                              extra={**info, **(refused.extra or {}), "margin_mm": info["margin_mm"],
                                     "search": refused.reason}) from None

    def plan_pose(self, now: np.ndarray, target_mm: Any, orientation: Any) -> MovePlan:
        """The path to a pose, or the refusal: `unreachable` (no configuration within 0.01 mm and 0.01 deg),
        `collision` (every one found collides), `no-path`. Poses are in the twin's base frame only: a
        calibration maps positions, not orientations."""
        started = time.perf_counter()
        if self.frame.name != "twin":
            raise BadInput(f"{self.name}: pose targets are in the twin's base frame; this robot's TD is in the "
                           "real robot's frame (a calibration maps positions only): use moveToCartesianPosition")
        target = np.asarray(target_mm, dtype=float).reshape(3)
        try:
            rotation = rotation_of(orientation)
        except ValueError as e:
            raise BadInput(f"{self.name}: {e}") from None
        where = f"{self.name}: pose ({', '.join(f'{v:g}' for v in target)}) mm, {_rpy_text(rotation)}"
        target_m = target / 1000.0
        first = solve_pose(self.fk, target_m, rotation, seed=now, rng=0, max_restarts=POSE_RESTARTS)
        if not first.ok:
            raise MoveRefused(f"{where}: no joint configuration within the limits reaches it (closest "
                              f"{first.error_m * 1000:.3f} mm and {math.degrees(first.error_rad):.3f} deg away)",
                              reason="unreachable", extra={"error_mm": round(first.error_m * 1000, 6),
                                                           "error_deg": round(math.degrees(first.error_rad), 6)})
        with self._lock:
            checker = self._path_checker()

            def solutions(attempts: Iterable[int]) -> list[np.ndarray]:
                """Pose IK runs (run 0: from where the arm stands), the distinct collision-free ones, quickest first."""
                free: list[np.ndarray] = []
                for attempt in attempts:
                    found = first if attempt == 0 else solve_pose(self.fk, target_m, rotation, rng=attempt,
                                                                  max_restarts=POSE_RESTARTS, accept=checker.free)
                    q = self.nearest_turn(now, found.q)
                    if found.ok and checker.free(q) and all(np.abs(q - other).max() > DISTINCT_RAD for other in free):
                        free.append(q)
                return sorted(free, key=lambda q: self.motion_duration(now, q))

            free = solutions(range(POSE_SOLUTIONS))
            if not free:
                pairs = checker.world.what_collides(first.q)
                raise MoveRefused(f"{where}: every joint configuration found for it collides, e.g. "
                                  f"{'; '.join(pairs)}", reason="collision", extra={"collisions": pairs})
            draws = itertools.count(POSE_SOLUTIONS)  # further runs when the first ones all sit in pockets
            path = self._find_path(checker, now, free, started, where,
                                   lambda: solutions(itertools.islice(draws, POSE_SOLUTIONS)))
        _, reached_rot, _ = self.fk.poses_and_jacobians(path.waypoints[-1][None])
        error = np.linalg.norm((Rotation.from_matrix(rotation) * Rotation.from_matrix(reached_rot[0]).inv()).as_rotvec())
        return self._plan(path, target, {"error_deg": round(math.degrees(float(error)), 6)})

    def _plan_to(self, now: np.ndarray, target: np.ndarray, where: str, info: dict[str, Any],
                 started: float) -> MovePlan:
        """IK candidates, their collisions, the path: the exact decision for a Cartesian target."""
        target_m = self.frame.to_base(target) / 1000.0
        # usually the nearest solution, in a few ms; few restarts: the search below is the thorough one
        quick = solve(self.fk, target_m, seed=now, rng=0, max_restarts=QUICK_RESTARTS)
        quick = replace(quick, q=self.nearest_turn(now, quick.q))
        if quick.ok:
            with self._lock:
                checker = self._path_checker()
                if checker.free(quick.q) and checker.segment_free(now, quick.q):
                    path = JointPath(np.array([now, quick.q]), "straight",
                                     round((time.perf_counter() - started) * 1000.0, 3), 0)
                    return self._plan(path, target, info)
        candidates, best_error_m = self._ik_candidates(now, target_m)
        if quick.ok:
            candidates.append(quick.q)
        if not candidates:
            raise MoveRefused(f"{where}: no joint configuration within the limits reaches it (closest "
                              f"{best_error_m * 1000:.3f} mm away)", reason="unreachable",
                              extra={**info, "error_mm": round(best_error_m * 1000, 6)})
        with self._lock:
            checker = self._path_checker()
            # every collision-free solution goes to the path search, the quickest motion first: a straight
            # path to the 9th-25th is still found in a millisecond or two, and spares a planning round
            free = self._quickest_free(checker, now, candidates)
            if not free:
                pairs = checker.world.what_collides(candidates[0])
                raise MoveRefused(f"{where}: every joint configuration found for it ({len(candidates)}) collides, "
                                  f"e.g. {'; '.join(pairs)}", reason="collision",
                                  extra={**info, "configurations": len(candidates), "collisions": pairs})
            path = self._find_path(checker, now, free, started, where,  # fresh IK when these all sit in pockets
                                   lambda: self._quickest_free(checker, now, self._ik_candidates(now, target_m)[0]))
        return self._plan(path, target, info)

    def _check_workspace(self, target: np.ndarray, where: str, ws: Workspace | None,
                         error: str | None) -> tuple[dict[str, Any], str | None]:
        """The neighbour collision probability (information for the answer) and, when the target is
        outside the hull, why. With a collision-probability gate set (the thesis's check), the hull and
        the gate refuse at once."""
        if ws is None and error:
            raise WorkspacePending(f"{self.name}: its workspace could not be generated ({error}); "
                                   "Cartesian moves are refused", reason="workspace-failed")
        if ws is None:
            raise WorkspacePending(f"{self.name}: its workspace is being generated by the tdgen service; "
                                   "Cartesian moves are refused until it is known", reason="workspace-generating")
        gate = 1.0 if self.max_collision_probability is None else self.max_collision_probability
        check = ws.check(target, self.k, self.radius_mm, gate)
        info = {"collision_probability": check.collision_probability, "neighbours": check.neighbours,
                "margin_mm": round(check.margin_mm, 3)}
        gated = self.max_collision_probability is not None
        if gated and not check.inside:
            raise MoveRefused(f"{where} is {check.reason}", reason="outside-workspace",
                              extra={"margin_mm": info["margin_mm"]})
        if gated and not check.ok:
            raise MoveRefused(f"{where}: {check.reason}", reason="collision-risk",
                              extra={**info, "max_collision_probability": self.max_collision_probability})
        return info, (None if check.inside else check.reason)

    def _quickest_free(self, checker: PathChecker, now: np.ndarray, qs: Iterable[np.ndarray]) -> list[np.ndarray]:
        """The collision-free ones among `qs`, the quickest motion from `now` first."""
        return sorted((q for q in qs if checker.free(q)), key=lambda q: self.motion_duration(now, q))

    def _ik_candidates(self, now: np.ndarray, target_m: np.ndarray) -> tuple[list[np.ndarray], float]:
        """Distinct joint solutions within the limits for a base-frame target (from the current
        configuration and from random starts), and the closest error when there are none."""
        seeds = np.random.default_rng().uniform(self.robot.lows(), self.robot.highs(), (IK_SEEDS, len(now)))
        seeds[0] = now
        result = solve_many(self.fk, np.repeat(target_m[None], IK_SEEDS, axis=0), seeds, max_restarts=IK_RESTARTS)
        found: list[np.ndarray] = []
        for q in result.q[result.ok]:
            q = self.nearest_turn(now, q)
            if all(np.abs(q - other).max() > DISTINCT_RAD for other in found):
                found.append(q)
        return found, float(result.error_m.min())

    def nearest_turn(self, now: np.ndarray, q: np.ndarray) -> np.ndarray:
        """The same pose with every multi-turn revolute joint (a UR's ±360°) a whole turn nearer to where
        it stands `now`, where the limits allow: the shorter way, and no detour through a fold of the arm."""
        q = np.asarray(q, dtype=float).copy()
        lows, highs = self.robot.lows(), self.robot.highs()
        for i in self._turning:
            turns = np.round((now[i] - q[i]) / (2 * math.pi))
            for k in (turns, turns - np.sign(turns)):
                shifted = q[i] + k * 2 * math.pi
                if lows[i] <= shifted <= highs[i]:
                    q[i] = shifted
                    break
        return q

    def _find_path(self, checker: PathChecker, now: np.ndarray, goals: list[np.ndarray], started: float,
                   where: str = "", more_goals: Callable[[], list[np.ndarray]] | None = None) -> JointPath:
        try:
            path = find_path(checker, now, goals, self.robot.lows(), self.robot.highs(), self.planning_budget,
                             more_goals)
        except NoPath as e:
            raise MoveRefused(f"{where or self.name}: {e.detail}", reason="no-path",
                              extra={"budget_s": self.planning_budget, **e.tried}) from None
        return JointPath(path.waypoints, path.method, round((time.perf_counter() - started) * 1000.0, 3),
                         path.checks)

    def _plan(self, path: JointPath, target: np.ndarray | None, info: dict[str, Any]) -> MovePlan:
        goal = path.waypoints[-1]
        reached = self.td_position(goal)
        if self.frame.name == "twin":  # a calibration maps positions only: no orientation in the real frame
            _, rotation, _ = self.fk.poses_and_jacobians(goal[None])
            roll, pitch, yaw = Rotation.from_matrix(rotation[0]).as_euler("xyz", degrees=True)
            info = {**info, "orientation": {"roll": round(float(roll), 6), "pitch": round(float(pitch), 6),
                                            "yaw": round(float(yaw), 6)}}
        error = 0.0 if target is None else float(np.linalg.norm(reached - target))
        return MovePlan(path, self.durations(path.waypoints), _triple(reached), error, info)

    def _path_checker(self) -> PathChecker:  # under _lock
        if self._checker is None:
            world = CollisionWorld(self.robot, self._scene)
            self._checker = PathChecker(FastCollision(world, warm=True) if self.collision_model == "fast" else world)
        return self._checker

    def _user(self, q: np.ndarray) -> list[float]:
        return [round(float(v), 3) for v in self.robot.to_user_units(q)]


def xyz(p: np.ndarray) -> dict[str, float]:
    """A point as the TD's {x, y, z} object (mm, 0.1 µm)."""
    return {axis: round(float(v), 4) for axis, v in zip("xyz", p)}


def _triple(p: np.ndarray) -> tuple[float, float, float]:
    return float(p[0]), float(p[1]), float(p[2])


def _rpy_text(rotation: np.ndarray) -> str:
    roll, pitch, yaw = Rotation.from_matrix(rotation).as_euler("xyz", degrees=True)
    return f"roll {roll:.6g}, pitch {pitch:.6g}, yaw {yaw:.6g} deg"
