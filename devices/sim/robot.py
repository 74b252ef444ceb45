"""A generic robot arm twin: any common-structure URDF arm in a `World`, with checked moves.

`RobotTwin` places a tdgen `Robot` in a World (its own or a shared one: everything it does to the
pybullet client goes through `world.run`/`world.play`), moves it in joint space and answers where
it is. Units at this surface are the TD's: joints in deg (revolute) or mm (prismatic), Cartesian
positions in mm in the TD frame, i.e. the robot's base frame, or the real robot's frame when a
calibration is given (`real = A twin + t`, inverted here for moves).

Every move is decided before anything moves, each refusal a Problem naming its `reason` (nothing
moves after one). A Cartesian target: the workspace must be known (503 `workspace-generating`
until the tdgen service has generated it; a robot Thing waits for it a while first), the target
inside the workspace hull (422 `outside-workspace`), a joint configuration within the limits that
reaches it (422 `unreachable`, with the closest error), one of those configurations free of self-
and scene collision (422 `collision`, naming the colliding pairs), and a collision-free joint path
from where the robot stands to one of them (422 `no-path`, with the planning budget and what was
tried). The path is the straight joint-space segment where that is free (checked densely: no point
of the robot moves more than `devices.planning.paths.STEP_MM` between two checked states), else one planned
by OMPL's RRTConnect in the live scene (`devices.planning.paths`). The collision probability of the target's
sampled neighbours is information in every answer; it refuses a target (422 `collision-risk`) only
when `max_collision_probability` is set (the thesis's behaviour). Joint moves get the same path
treatment. Paths are played segment by segment, eased in and out, with no joint above its URDF
velocity limit in simulated time; `stop()` halts a move where it is (409 `move-stopped` to its
caller). `plan_move` answers exactly like a move without moving.

The scene can change under the robot (`set_scene`, e.g. a box put on the table): the collision
check uses the new scene at once, `version` is bumped and scene listeners are told (the Thing
binding asks the tdgen service for a new workspace, which follows a box put down or taken away
within a tenth of a second). Cartesian requests wait for it (`RESCENE_WAIT` at most, then the
previous workspace's hull and collision probability serve).
"""
from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass, replace
from typing import Any, Callable, Literal, Mapping, cast

import msgspec
import numpy as np
from scipy.spatial.transform import Rotation

from devices.planning.paths import PLANNING_BUDGET_S, JointPath, NoPath, PathChecker, find_path
from devices.sim.compensation import KinematicArm
from devices.sim.vec import Vec
from devices.sim.world import PEAK_SPEED, PathMotion, Snapshot, World
from mesh.messages.scene import Pose, TwinDescription
from mesh.wot.invocation import ActionCancelled
from mesh.wot.problem import BadInput, Problem, Refused, Unavailable
from tdgen.robot import points_csv
from tdgen.robot.calibration import Calibration
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import FastCollision
from tdgen.robot.ik import solve, solve_many
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot
from tdgen.robot.pose_ik import rotation_of, solve_pose
from tdgen.robot.surroundings import Body, RobotPlacement, Surroundings, empty_scene
from tdgen.robot.workspace_check import DEFAULT_K, DEFAULT_RADIUS_MM, Workspace

IK_SEEDS = 24       # IK runs per Cartesian target: from the current configuration and from random starts
IK_RESTARTS = 20    # random restarts each run may take before it gives up
QUICK_RESTARTS = 16  # random restarts of the first IK run, from where the arm stands (an unreachable target: 65 -> 8 ms)
DISTINCT_RAD = 1e-3  # two solutions closer than this (every joint, rad or m) are one
IK_CANDIDATES = 8   # collision-free solutions offered to the path search, the quickest motion first
LIMIT_SLACK = 1e-9  # SI; joint targets this far past a limit are clipped, not refused
POSE_SOLUTIONS = 4  # pose IK solutions looked for (the first from the current configuration), collision-free ones kept
POSE_RESTARTS = 60  # random restarts per pose IK run
TRACE_STEPS = 8    # end-effector points per path segment in a move's answer (`path.tip`)
WORKSPACE_WAIT = 120.0  # s a robot Thing's Cartesian request waits for a workspace being generated
RESCENE_WAIT = 10.0     # s it waits, after a scene change, for the new scene's workspace (else the old one serves)


class MoveRefused(Refused):
    slug, title = "move-refused", "Move refused"


class MoveStopped(Problem):
    """A move under way was stopped (the `stop` action): the robot stands where it halted."""

    status, slug, title = 409, "move-stopped", "Move stopped"


class WorkspacePending(Unavailable):
    slug, title = "workspace-generating", "Workspace not generated yet"


@dataclass(frozen=True)
class Base:
    """Where the robot base stands in the scene frame: position (m), yaw about z (deg) and, for a wall
    or ceiling mount, roll and pitch (deg; fixed axes x, y, z as in a scene's `rpy`)."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0

    @property
    def placement(self) -> RobotPlacement:
        x, y, z = self.position
        return RobotPlacement(position=(x, y, z), yaw=self.yaw, roll=self.roll, pitch=self.pitch)

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        return self.placement.quaternion()

    def pose(self) -> Pose:
        return Pose(tuple(float(v) for v in self.position), self.quaternion)  # type: ignore[arg-type]

    @classmethod
    def from_pose(cls, pose: Pose) -> "Base":
        p = RobotPlacement.from_quaternion(tuple(pose.p), tuple(pose.q))  # type: ignore[arg-type]
        return cls(p.position, p.yaw, p.roll, p.pitch)


def placed(scene: Surroundings | None, base: Base) -> Surroundings:
    """The scene with the robot standing at `base` (a scene's own `robot` placement is replaced)."""
    scene = scene or empty_scene()
    return msgspec.structs.replace(scene, robot=base.placement)


def workspace_from_csv(data: bytes) -> Workspace:
    """The check's workspace from the bytes of a points.csv (`x,y,z,collision,...`)."""
    return Workspace(*points_csv.read_bytes(data))


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

    def answer(self, twin: "RobotTwin") -> dict[str, Any]:
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
            "reached": _xyz(np.array(self.reached_mm)), "error_mm": round(self.error_mm, 6),
            "method": self.path.method, "planning_ms": self.path.planning_ms}
        if self.info.get("collision_probability") is not None:
            out["collision_probability"] = round(float(self.info["collision_probability"]), 6)
        if self.info.get("orientation") is not None:  # where the tip points at the end
            out["orientation"] = self.info["orientation"]
        if self.info.get("error_deg") is not None:    # pose moves: how far from the asked orientation
            out["error_deg"] = self.info["error_deg"]
        return out


class RobotTwin:
    """One robot arm in a World. Thread-safe: moves run one at a time, reads never wait for them."""

    def __init__(self, world: World, robot: Robot, name: str, base: Base = Base(), scene: Surroundings | None = None, *,
                 calibration: Calibration | None = None,
                 max_collision_probability: float | None = None, k: int = DEFAULT_K,
                 radius_mm: float = DEFAULT_RADIUS_MM, home: Vec | None = None,
                 workspace_wait: float = 0.0, planning_budget: float = PLANNING_BUDGET_S,
                 collision_model: str = "fast"):
        if max_collision_probability is not None and not 0.0 <= max_collision_probability <= 1.0:
            raise ValueError("max_collision_probability must be within 0..1")
        self.world, self.robot, self.name, self.base = world, robot, name, base
        self.collision_model = collision_model  # sampling, target checks and planning stand on the same one
        self.frame = TdFrame(calibration)
        self.max_collision_probability, self.k, self.radius_mm = max_collision_probability, k, radius_mm
        self.fk = ForwardKinematics(robot)
        self.version = 0
        self.workspace_hash: str | None = None
        self.workspace_error: str | None = None  # why the workspace could not be generated, if it could not
        self.workspace_wait = workspace_wait     # s a Cartesian request waits for a workspace being generated
        self.workspace_version = -1              # the scene version the workspace was generated for
        self._workspace_changed = threading.Condition()  # a workspace (or its failure) arrived
        self._scene = placed(scene, base)
        self._workspace: Workspace | None = None
        self._checker: PathChecker | None = None  # the live scene's collision world, for checks and paths
        self._touch_world: CollisionWorld | None = None  # only bodies about to be added (`would_touch`)
        self._motion: PathMotion | None = None
        self.planning_budget = planning_budget
        self._move_lock = threading.RLock()   # one motion at a time (and its check)
        self._scene_lock = threading.Lock()   # the scene and its collision world
        self._state_listeners: list[Callable[[], None]] = []
        self._scene_listeners: list[Callable[[int], None]] = []
        self._main = [j.name for j in robot.joints]
        self._vmax = np.array([j.max_velocity for j in robot.joints])
        self._mimic = [n for n in robot.drives() if n not in {*self._main, *robot.passive_names}]
        self._turning = [i for i, j in enumerate(robot.joints)  # revolute joints with more than a turn of range
                         if j.type != "prismatic" and j.upper - j.lower > 2 * math.pi + 1e-9]
        q0 = np.clip(np.zeros(len(robot.joints)) if home is None else robot.from_user_units(np.asarray(home)),
                     robot.lows(), robot.highs())
        if home is None:
            q0 = self._free_home(q0)
        self.home = q0
        self.arm: KinematicArm = world.run(lambda: self._build(q0))

    def _build(self, q0: np.ndarray) -> KinematicArm:  # stepping thread (or before the world starts)
        urdf = str(self.robot.load_path or self.robot.urdf_path)  # meshes resolved (tdgen.robot.model)
        arm = KinematicArm(self.world.client, urdf, self.base.position, self.base.quaternion,
                           self._main, self.robot.passive_names, self.robot.passive, self.world)
        self.arm = arm
        self._apply(q0)
        self.world.add_snapshot_source(self._fill)
        return arm

    def _free_home(self, q0: np.ndarray) -> np.ndarray:
        """Where the robot starts: q0 (all joints at 0) unless that collides (the Panda's coarse meshes
        overlap when it stands straight up), then mid-range, then the free random configuration nearest
        to q0: a robot that stood in collision could not move anywhere along a checked path."""
        rng = np.random.default_rng(0)
        lows, highs = self.robot.lows(), self.robot.highs()
        near = rng.uniform(lows, highs, (400, len(q0)))
        near = near[np.argsort(np.abs(near - q0).max(axis=1))]
        for q in [q0, (lows + highs) / 2, *near]:
            if not self._collides(q):
                return np.asarray(q, dtype=float)
        return q0

    def close(self) -> None:
        """Free the collision checker's pybullet client (the World stays the caller's)."""
        with self._scene_lock:
            if self._checker is not None:
                self._checker.world.close()
                self._checker = None
            if self._touch_world is not None:
                self._touch_world.close()
                self._touch_world = None

    # --- listeners ------------------------------------------------------------------------------
    def on_state(self, listener: Callable[[], None]) -> None:
        """`listener()` after every change of the joints, on the stepping thread: keep it tiny."""
        self._state_listeners.append(listener)

    def on_scene_changed(self, listener: Callable[[int], None]) -> None:
        """`listener(version)` after `set_scene`, on the caller's thread."""
        self._scene_listeners.append(listener)

    # --- state ----------------------------------------------------------------------------------
    @property
    def q(self) -> np.ndarray:
        """Main joint values now (SI)."""
        return self.arm.q

    def joint_position(self) -> dict[str, float]:
        """`getJointposition`: deg or mm per main joint."""
        return {n: round(float(v), 6) for n, v in zip(self._main, self.robot.to_user_units(self.arm.q))}

    def cartesian_position(self) -> dict[str, float]:
        """`getCartesianposition`: the end effector (mm) in the TD frame."""
        return _xyz(self._td_position(self.arm.q))

    def tip_trace(self, waypoints: np.ndarray, per_segment: int = TRACE_STEPS) -> np.ndarray:
        """End-effector positions (TD frame, mm) along a joint path, `per_segment` per straight segment."""
        u = np.linspace(0.0, 1.0, per_segment, endpoint=False)[:, None]
        qs = [a + (b - a) * u for a, b in zip(waypoints[:-1], waypoints[1:])] + [waypoints[-1:]]
        return self._td_position(np.vstack(qs))

    def _td_position(self, q: np.ndarray) -> np.ndarray:
        return self.frame.from_base(self.fk.positions(q) * 1000.0)

    @property
    def scene(self) -> Surroundings:
        return self._scene

    @property
    def workspace(self) -> Workspace | None:
        return self._workspace

    def set_workspace(self, workspace: Workspace | None, hash: str | None = None, version: int | None = None) -> None:
        """The sampled points (TD frame) Cartesian targets are checked against, generated for scene
        `version` (default: the scene now); None: not known yet."""
        with self._workspace_changed:
            self._workspace, self.workspace_hash = workspace, hash
            self.workspace_version = self.version if version is None else version
            if workspace is not None:
                self.workspace_error = None
            self._workspace_changed.notify_all()

    def set_workspace_failed(self, error: str) -> None:
        """The workspace could not be generated: Cartesian requests stop waiting and answer 503 with `error`
        (or, with the workspace of an earlier scene at hand, are checked against that one)."""
        with self._workspace_changed:
            self.workspace_error = error
            self._workspace_changed.notify_all()

    def await_workspace(self) -> None:
        """Wait while the workspace is still being generated (up to `workspace_wait` s): a client that asks
        right after the robot joined gets its answer, not a 503 to retry. After a scene change, wait for
        the workspace of the new scene (up to RESCENE_WAIT s; a live update brings it in a tenth of a
        second): a target asked for right after a box was put down is checked against the box."""
        if self.workspace_wait <= 0:
            return
        with self._workspace_changed:
            if self._workspace is None:
                self._workspace_changed.wait_for(lambda: self._workspace is not None or bool(self.workspace_error),
                                                 self.workspace_wait)
            elif self.workspace_version < self.version:
                self._workspace_changed.wait_for(
                    lambda: self.workspace_version >= self.version or bool(self.workspace_error),
                    min(RESCENE_WAIT, self.workspace_wait))

    def set_scene(self, scene: Surroundings | Mapping[str, Any]) -> int:
        """New surroundings (the robot keeps its base): bump `version`, tell the listeners. Returns it."""
        try:  # a plain, checked copy (numpy numbers from the caller's geometry included)
            scene = msgspec.json.decode(msgspec.json.encode(scene, enc_hook=_plain), type=Surroundings)
        except (msgspec.ValidationError, msgspec.DecodeError, TypeError) as e:
            raise BadInput(f"{self.name}: not a scene ({e})") from None
        with self._scene_lock:
            self._scene = placed(scene, self.base)
            if self._checker is not None:
                self._checker.world.close()
                self._checker = None
            self.version += 1
            version = self.version
        for listener in list(self._scene_listeners):
            listener(version)
        return version

    def would_touch(self, bodies: list[Body]) -> bool:
        """Whether the robot, where it stands now, would touch any of these bodies if they were added to its
        scene (a box about to be put down). A world of only them is kept for it: the robot is loaded once."""
        with self._scene_lock:
            if self._touch_world is None:
                self._touch_world = CollisionWorld(self.robot, msgspec.structs.replace(self._scene, bodies=[]),
                                                   part=True)
            self._touch_world.set_bodies(list(bodies))
            return bool(self._touch_world.colliding(self.arm.q[None])[0])

    def place_joints(self, joints: Mapping[str, float]) -> None:
        """Stand at these joint values (TD units) at once: the twin following its real arm, which is
        already there (`devices.things.guard`). BadInput beyond the limits; never during a move."""
        goal = self.joint_goal(joints)
        with self._move_lock:
            self.world.run(lambda: self._apply(goal))

    def reset(self) -> None:
        """Back to the home configuration at once (a scene reset; the world cancels a move under way first)."""
        with self._move_lock:
            self.world.run(lambda: self._apply(self.home))

    def description(self, urdf: str, urdf_sha256: str, urdf_file: str, samples: int, seed: int = 0) -> TwinDescription:
        """What the tdgen service generates this robot's TD from (mesh.messages.scene contract)."""
        cal = self.frame.calibration
        scene = msgspec.to_builtins(self._scene)
        scene.pop("robot", None)
        return TwinDescription(
            robot=self.name, urdf=urdf, urdf_sha256=urdf_sha256, urdf_file=urdf_file,
            urdf_dir=str(self.robot.urdf_path.resolve().parent), base=self.base.pose(),
            ee=self.robot.ee_link, base_link=self.robot.base_link, fixed=self.robot.info()["heldJoints"],
            packages=self.robot.packages, allowed_collisions=list(self.robot.allowed_collisions), scene=scene,
            samples=samples, seed=seed, collision_model=cast(Literal["fast", "exact"], self.collision_model),
            calibration=None if cal is None else [[*t, *r] for t, r in zip(cal.twin, cal.real)],
            frame=self.frame.name, version=self.version)

    # --- moves ----------------------------------------------------------------------------------
    def move_to_joints(self, joints: Mapping[str, float] | Vec) -> MovePlan:
        """Move to joint values (deg / mm, by name or in joint order) along a collision-free path;
        returns when the motion is over."""
        goal = self.joint_goal(joints)
        with self._move_lock:
            plan = self.plan_joints(goal)
            self._play(plan)
        return plan

    def move_to_cartesian(self, target_mm: Vec) -> MovePlan:
        """Move the end effector to `target_mm` (TD frame) along a collision-free path; refused (nothing
        moves) unless one is found."""
        target = np.asarray(target_mm, dtype=float).reshape(3)
        self.await_workspace()
        with self._move_lock:
            plan = self.plan_cartesian(target)
            self._play(plan)
        return plan

    def move_to_pose(self, target_mm: Vec, orientation: Any) -> MovePlan:
        """Move the tip to `target_mm` (TD frame) in `orientation` (roll/pitch/yaw in deg, or a quaternion
        x, y, z, w; base frame) along a collision-free path; refused (nothing moves) unless one is found."""
        with self._move_lock:
            plan = self._plan_pose(target_mm, orientation)
            self._play(plan)
        return plan

    def plan_pose(self, target_mm: Vec, orientation: Any) -> MovePlan:
        """The answer `move_to_pose` would give, from where the robot is now, without moving (a dry run)."""
        with self._move_lock:
            return self._plan_pose(target_mm, orientation)

    def _plan_pose(self, target_mm: Vec, orientation: Any) -> MovePlan:
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
        first = solve_pose(self.fk, target_m, rotation, seed=self.arm.q, rng=0, max_restarts=POSE_RESTARTS)
        if not first.ok:
            raise MoveRefused(f"{where}: no joint configuration within the limits reaches it (closest "
                              f"{first.error_m * 1000:.3f} mm and {math.degrees(first.error_rad):.3f} deg away)",
                              reason="unreachable", extra={"error_mm": round(first.error_m * 1000, 6),
                                                           "error_deg": round(math.degrees(first.error_rad), 6)})
        with self._scene_lock:
            checker = self._path_checker()
            free: list[np.ndarray] = []
            for attempt in range(POSE_SOLUTIONS):
                found = first if attempt == 0 else solve_pose(self.fk, target_m, rotation, rng=attempt,
                                                              max_restarts=POSE_RESTARTS, accept=checker.free)
                q = self._nearest_turn(found.q)
                if found.ok and checker.free(q) and all(np.abs(q - other).max() > DISTINCT_RAD for other in free):
                    free.append(q)
            if not free:
                pairs = checker.world.what_collides(first.q)
                raise MoveRefused(f"{where}: every joint configuration found for it collides, e.g. "
                                  f"{'; '.join(pairs)}", reason="collision", extra={"collisions": pairs})
            free.sort(key=self.motion_duration)
            path = self._find_path(checker, free, started, where)
        _, reached_rot, _ = self.fk.poses_and_jacobians(path.waypoints[-1][None])
        error = np.linalg.norm((Rotation.from_matrix(rotation) * Rotation.from_matrix(reached_rot[0]).inv()).as_rotvec())
        return self._plan(path, target, {"error_deg": round(math.degrees(float(error)), 6)})

    def plan_move(self, joints: Mapping[str, float] | Vec | None = None,
                  target_mm: Vec | None = None) -> MovePlan:
        """The answer a move would give, from where the robot is now, without moving (a dry run)."""
        if (joints is None) == (target_mm is None):
            raise BadInput(f"{self.name}: give either a Cartesian target (x, y, z) or joint values, not both")
        if target_mm is not None:
            self.await_workspace()
        goal = None if joints is None else self.joint_goal(joints)
        with self._move_lock:
            if goal is not None:
                return self.plan_joints(goal)
            return self.plan_cartesian(np.asarray(target_mm, dtype=float).reshape(3))

    def stop(self) -> bool:
        """Halt a move under way where it is (its caller gets MoveStopped); False when none was moving."""
        motion = self._motion
        if motion is None:
            return False
        motion.stop()
        return True

    def joint_goal(self, joints: Mapping[str, float] | Vec) -> np.ndarray:
        """Joint values in TD units (by name or in order) -> SI, within the limits, or BadInput."""
        if isinstance(joints, Mapping):
            missing = [n for n in self._main if n not in joints]
            if missing:
                raise BadInput(f"{self.name}: no value for joints {', '.join(missing)}")
            joints = [joints[n] for n in self._main]
        if len(joints) != len(self._main):
            raise BadInput(f"{self.name}: {len(self._main)} joint values expected, got {len(joints)}")
        goal = self.robot.from_user_units(np.asarray(joints, dtype=float))
        lows, highs = self.robot.lows(), self.robot.highs()
        outside = [n for n, v, lo, hi in zip(self._main, goal, lows, highs)
                   if not lo - LIMIT_SLACK <= v <= hi + LIMIT_SLACK]
        if outside:
            raise BadInput(f"{self.name}: joints {', '.join(outside)} outside their limits")
        return np.clip(goal, lows, highs)

    def plan_joints(self, goal: np.ndarray) -> MovePlan:
        """The path to joint values `goal` (SI), or the refusal (`collision`, `no-path`)."""
        started = time.perf_counter()
        with self._scene_lock:
            checker = self._path_checker()
            if not checker.free(goal):
                raise MoveRefused(f"{self.name}: the configuration {self._user(goal)} collides: "
                                  f"{'; '.join(checker.world.what_collides(goal))}", reason="collision",
                                  extra={"collisions": checker.world.what_collides(goal)})
            path = self._find_path(checker, [goal], started)
        return self._plan(path, None, {})

    def plan_cartesian(self, target_mm: np.ndarray) -> MovePlan:
        """The path to a Cartesian target (TD frame, mm), or the refusal naming why: `outside-workspace`,
        `collision-risk` (only with a collision-probability gate), `unreachable`, `collision`, `no-path`."""
        started = time.perf_counter()
        target = np.asarray(target_mm, dtype=float).reshape(3)
        where = f"{self.name}: target ({', '.join(f'{v:g}' for v in target)}) mm"
        info, outside = self._check_workspace(target, where)
        try:
            return self._plan_to(target, where, info, started)
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

    def _plan_to(self, target: np.ndarray, where: str, info: dict[str, Any], started: float) -> MovePlan:
        """IK candidates, their collisions, the path: the exact decision for a Cartesian target."""
        target_m = self.frame.to_base(target) / 1000.0
        # usually the nearest solution, in a few ms; few restarts: the search below is the thorough one
        quick = solve(self.fk, target_m, seed=self.arm.q, rng=0, max_restarts=QUICK_RESTARTS)
        quick = replace(quick, q=self._nearest_turn(quick.q))
        if quick.ok:
            with self._scene_lock:
                checker = self._path_checker()
                if checker.free(quick.q) and checker.segment_free(self.arm.q, quick.q):
                    path = JointPath(np.array([self.arm.q, quick.q]), "straight",
                                     round((time.perf_counter() - started) * 1000.0, 3), 0)
                    return self._plan(path, target, info)
        candidates, best_error_m = self._ik_candidates(target_m)
        if quick.ok:
            candidates.append(quick.q)
        if not candidates:
            raise MoveRefused(f"{where}: no joint configuration within the limits reaches it (closest "
                              f"{best_error_m * 1000:.3f} mm away)", reason="unreachable",
                              extra={**info, "error_mm": round(best_error_m * 1000, 6)})
        with self._scene_lock:
            checker = self._path_checker()
            free = [q for q in candidates if checker.free(q)]
            if not free:
                pairs = checker.world.what_collides(candidates[0])
                raise MoveRefused(f"{where}: every joint configuration found for it ({len(candidates)}) collides, "
                                  f"e.g. {'; '.join(pairs)}", reason="collision",
                                  extra={**info, "configurations": len(candidates), "collisions": pairs})
            free.sort(key=self.motion_duration)
            path = self._find_path(checker, free[:IK_CANDIDATES], started, where)
        return self._plan(path, target, info)

    def _check_workspace(self, target: np.ndarray, where: str) -> tuple[dict[str, Any], str | None]:
        """The neighbour collision probability (information for the answer) and, when the target is
        outside the hull, why. With a collision-probability gate set (the thesis's check), the hull and
        the gate refuse at once."""
        ws = self._workspace
        if ws is None and self.workspace_error:
            raise WorkspacePending(f"{self.name}: its workspace could not be generated ({self.workspace_error}); "
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

    def _ik_candidates(self, target_m: np.ndarray) -> tuple[list[np.ndarray], float]:
        """Distinct joint solutions within the limits for a base-frame target (from the current
        configuration and from random starts), and the closest error when there are none."""
        seeds = np.random.default_rng().uniform(self.robot.lows(), self.robot.highs(), (IK_SEEDS, len(self._main)))
        seeds[0] = self.arm.q
        result = solve_many(self.fk, np.repeat(target_m[None], IK_SEEDS, axis=0), seeds, max_restarts=IK_RESTARTS)
        found: list[np.ndarray] = []
        for q in result.q[result.ok]:
            q = self._nearest_turn(q)
            if all(np.abs(q - other).max() > DISTINCT_RAD for other in found):
                found.append(q)
        return found, float(result.error_m.min())

    def _nearest_turn(self, q: np.ndarray) -> np.ndarray:
        """The same pose with every multi-turn revolute joint (a UR's ±360°) a whole turn nearer to where
        it stands now, where the limits allow: the shorter way, and no detour through a fold of the arm."""
        q = np.asarray(q, dtype=float).copy()
        now, lows, highs = self.arm.q, self.robot.lows(), self.robot.highs()
        for i in self._turning:
            turns = np.round((now[i] - q[i]) / (2 * math.pi))
            for k in (turns, turns - np.sign(turns)):
                shifted = q[i] + k * 2 * math.pi
                if lows[i] <= shifted <= highs[i]:
                    q[i] = shifted
                    break
        return q

    def _find_path(self, checker: PathChecker, goals: list[np.ndarray], started: float, where: str = "") -> JointPath:
        try:
            path = find_path(checker, self.arm.q, goals, self.robot.lows(), self.robot.highs(), self.planning_budget)
        except NoPath as e:
            raise MoveRefused(f"{where or self.name}: {e.detail}", reason="no-path",
                              extra={"budget_s": self.planning_budget, **e.tried}) from None
        return JointPath(path.waypoints, path.method, round((time.perf_counter() - started) * 1000.0, 3),
                         path.checks)

    def _plan(self, path: JointPath, target: np.ndarray | None, info: dict[str, Any]) -> MovePlan:
        goal = path.waypoints[-1]
        reached = self._td_position(goal)
        if self.frame.name == "twin":  # a calibration maps positions only: no orientation in the real frame
            _, rotation, _ = self.fk.poses_and_jacobians(goal[None])
            roll, pitch, yaw = Rotation.from_matrix(rotation[0]).as_euler("xyz", degrees=True)
            info = {**info, "orientation": {"roll": round(float(roll), 6), "pitch": round(float(pitch), 6),
                                            "yaw": round(float(yaw), 6)}}
        error = 0.0 if target is None else float(np.linalg.norm(reached - target))
        return MovePlan(path, self._durations(path.waypoints), _triple(reached), error, info)

    def _path_checker(self) -> PathChecker:  # under _scene_lock
        if self._checker is None:
            world = CollisionWorld(self.robot, self._scene)
            self._checker = PathChecker(FastCollision(world, warm=True) if self.collision_model == "fast" else world)
        return self._checker

    def _collides(self, q: np.ndarray) -> bool:
        with self._scene_lock:
            return not self._path_checker().free(q)

    def _durations(self, waypoints: np.ndarray) -> list[float]:
        """Simulated seconds per segment with no joint above its velocity limit (eased: PEAK_SPEED)."""
        steps = np.abs(np.diff(waypoints, axis=0)) / self._vmax
        return [PEAK_SPEED * float(np.max(row, initial=0.0)) for row in steps]

    def motion_duration(self, goal: np.ndarray) -> float:
        """Simulated seconds from now to `goal` (SI) in a straight joint-space line."""
        return PEAK_SPEED * float(np.max(np.abs(np.asarray(goal) - self.arm.q) / self._vmax, initial=0.0))

    def _play(self, plan: MovePlan) -> None:
        motion = PathMotion(plan.path.waypoints, plan.durations, self._apply)
        self._motion = motion
        try:
            self.world.play(motion).result()
        except ActionCancelled:  # an asynchronous move cancelled: say where it stopped
            raise ActionCancelled(f"{self.name}: the move was cancelled; it stopped at {self._user(self.arm.q)} "
                                  f"({', '.join(self._main)})", extra={"joints": self.joint_position()}) from None
        finally:
            self._motion = None
        if motion.stopped:
            raise MoveStopped(f"{self.name}: the move was stopped at {self._user(self.arm.q)} "
                              f"({', '.join(self._main)})", reason="stopped",
                              extra={"joints": self.joint_position()})

    def _apply(self, q: np.ndarray) -> None:  # stepping thread
        if self._mimic:
            values = self.robot.joint_values(np.asarray(q)[None])
            self.arm.extra = {n: float(values[n][0]) for n in self._mimic}
        self.arm.apply(q)
        for listener in self._state_listeners:
            listener()

    def _fill(self, snap: Snapshot) -> None:  # stepping thread: a snapshot source for recorders
        snap.joints[self.name] = self.arm.joint_values()

    def _user(self, q: np.ndarray) -> list[float]:
        return [round(float(v), 3) for v in self.robot.to_user_units(q)]


def _plain(obj: Any) -> Any:
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    raise TypeError(f"cannot encode {type(obj).__name__}")


def _xyz(p: np.ndarray) -> dict[str, float]:
    return {axis: round(float(v), 4) for axis, v in zip("xyz", p)}


def _triple(p: np.ndarray) -> tuple[float, float, float]:
    return float(p[0]), float(p[1]), float(p[2])


def _rpy_text(rotation: np.ndarray) -> str:
    roll, pitch, yaw = Rotation.from_matrix(rotation).as_euler("xyz", degrees=True)
    return f"roll {roll:.6g}, pitch {pitch:.6g}, yaw {yaw:.6g} deg"
