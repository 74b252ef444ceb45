"""A generic robot arm twin: any common-structure URDF arm in a `World`, with checked moves.

`RobotTwin` places a tdgen `Robot` in a World (its own or a shared one: everything it does to the
pybullet client goes through `world.run`/`world.play`), moves it in joint space and answers where
it is. Units at this surface are the TD's: joints in deg (revolute) or mm (prismatic), Cartesian
positions in mm in the TD frame, i.e. the robot's base frame, or the real robot's frame when a
calibration is given (`real = A twin + t`, inverted here for moves).

Every move is decided before anything moves, by the twin's `MovePlanner` (`devices.planning.moves`:
the workspace, IK, collisions and the path, each refusal a Problem naming its `reason`; nothing
moves after one). A Cartesian target waits for the workspace first (503 `workspace-generating`
until the tdgen service has generated it; a robot Thing waits for it a while first). Paths are
played segment by segment, eased in and out, with no joint above its URDF velocity limit in
simulated time; `stop()` halts a move where it is (409 `move-stopped` to its caller). `plan_move`
answers exactly like a move without moving.

The scene can change under the robot (`set_scene`, e.g. a box put on the table): the collision
check uses the new scene at once, `version` is bumped and scene listeners are told (the Thing
binding asks the tdgen service for a new workspace, which follows a box put down or taken away
within a tenth of a second). Cartesian requests wait for it (`RESCENE_WAIT` at most, then the
previous workspace's hull and collision probability serve).
"""
from __future__ import annotations

import threading
from dataclasses import dataclass
from typing import Any, Callable, Mapping

import msgspec
import numpy as np

from devices.planning.moves import TRACE_STEPS, MovePlan, MovePlanner, TdFrame, xyz
from devices.planning.paths import PLANNING_BUDGET_S
from devices.sim.compensation import KinematicArm
from devices.sim.pybullet_world import PEAK_SPEED, PathMotion, Snapshot, World
from devices.sim.vec import Vec
from mesh.messages.scene_description import CollisionModel, Pose, TwinDescription
from mesh.wot.invocation import ActionCancelled
from mesh.wot.problem import BadInput, Problem
from tdgen.robot import points_csv
from tdgen.robot.calibration import Calibration
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import Body, RobotPlacement, Surroundings, empty_scene
from tdgen.robot.workspace_check import DEFAULT_K, DEFAULT_RADIUS_MM, Workspace

LIMIT_SLACK = 1e-9  # SI; joint targets this far past a limit are clipped, not refused
WORKSPACE_WAIT = 120.0  # s a robot Thing's Cartesian request waits for a workspace being generated
RESCENE_WAIT = 10.0     # s it waits, after a scene change, for the new scene's workspace (else the old one serves)


class MoveStopped(Problem):
    """A move under way was stopped (the `stop` action): the robot stands where it halted."""

    status, slug, title = 409, "move-stopped", "Move stopped"


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


class RobotTwin:
    """One robot arm in a World. Thread-safe: moves run one at a time, reads never wait for them."""

    def __init__(self, world: World, robot: Robot, name: str, base: Base = Base(), scene: Surroundings | None = None, *,
                 calibration: Calibration | None = None,
                 max_collision_probability: float | None = None, k: int = DEFAULT_K,
                 radius_mm: float = DEFAULT_RADIUS_MM, home: Vec | None = None,
                 workspace_wait: float = 0.0, planning_budget: float = PLANNING_BUDGET_S,
                 collision_model: CollisionModel = "fast"):
        self.world, self.robot, self.name, self.base = world, robot, name, base
        self.planner = MovePlanner(robot, name, placed(scene, base), TdFrame(calibration), peak_speed=PEAK_SPEED,
                                   collision_model=collision_model, planning_budget=planning_budget,
                                   max_collision_probability=max_collision_probability, k=k, radius_mm=radius_mm)
        self.frame, self.fk = self.planner.frame, self.planner.fk
        self.version = 0
        self.workspace_hash: str | None = None
        self.workspace_error: str | None = None  # why the workspace could not be generated, if it could not
        self.workspace_wait = workspace_wait     # s a Cartesian request waits for a workspace being generated
        self.workspace_version = -1              # the scene version the workspace was generated for
        self._workspace_changed = threading.Condition()  # a workspace (or its failure) arrived
        self._workspace: Workspace | None = None
        self._motion: PathMotion | None = None
        self._move_lock = threading.RLock()   # one motion at a time (and its check)
        self._scene_lock = threading.Lock()   # the scene version
        self._state_listeners: list[Callable[[], None]] = []
        self._scene_listeners: list[Callable[[int], None]] = []
        self._main = [j.name for j in robot.joints]
        self._mimic = [n for n in robot.drives() if n not in {*self._main, *robot.passive_names}]
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
            if not self.planner.collides(q):
                return np.asarray(q, dtype=float)
        return q0

    def close(self) -> None:
        """Free the collision checkers' pybullet clients (the World stays the caller's)."""
        self.planner.close()

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
        return xyz(self.planner.td_position(self.arm.q))

    def tip_trace(self, waypoints: np.ndarray, per_segment: int = TRACE_STEPS) -> np.ndarray:
        """End-effector positions (TD frame, mm) along a joint path, `per_segment` per straight segment."""
        return self.planner.tip_trace(waypoints, per_segment)

    @property
    def scene(self) -> Surroundings:
        return self.planner.scene

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
            self.planner.set_scene(placed(scene, self.base))
            self.version += 1
            version = self.version
        for listener in list(self._scene_listeners):
            listener(version)
        return version

    def would_touch(self, bodies: list[Body]) -> bool:
        """Whether the robot, where it stands now, would touch any of these bodies if they were added to its
        scene (a box about to be put down). A world of only them is kept for it: the robot is loaded once."""
        return self.planner.would_touch(bodies, self.arm.q)

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
        """What the tdgen service generates this robot's TD from (mesh.messages.scene_description contract)."""
        cal = self.frame.calibration
        scene = msgspec.to_builtins(self.planner.scene)
        scene.pop("robot", None)
        return TwinDescription(
            robot=self.name, urdf=urdf, urdf_sha256=urdf_sha256, urdf_file=urdf_file,
            urdf_dir=str(self.robot.urdf_path.resolve().parent), base=self.base.pose(),
            ee=self.robot.ee_link, base_link=self.robot.base_link, fixed=self.robot.info()["heldJoints"],
            packages=self.robot.packages, allowed_collisions=list(self.robot.allowed_collisions), scene=scene,
            samples=samples, seed=seed, collision_model=self.planner.collision_model,
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
            plan = self.plan_pose(target_mm, orientation)
            self._play(plan)
        return plan

    def plan_pose(self, target_mm: Vec, orientation: Any) -> MovePlan:
        """The answer `move_to_pose` would give, from where the robot is now, without moving (a dry run)."""
        with self._move_lock:
            return self.planner.plan_pose(self.arm.q, target_mm, orientation)

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
        return self.planner.plan_joints(self.arm.q, goal)

    def plan_cartesian(self, target_mm: np.ndarray) -> MovePlan:
        """The path to a Cartesian target (TD frame, mm), or the refusal naming why (`MovePlanner`)."""
        return self.planner.plan_cartesian(self.arm.q, target_mm, self._workspace, self.workspace_error)

    def motion_duration(self, goal: np.ndarray) -> float:
        """Simulated seconds from now to `goal` (SI) in a straight joint-space line."""
        return self.planner.motion_duration(self.arm.q, goal)

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
