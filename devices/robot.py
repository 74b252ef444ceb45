"""A generic robot arm twin: any common-structure URDF arm in a `World`, with checked moves.

`RobotTwin` places a tdgen `Robot` in a World (its own or a shared one: everything it does to the
pybullet client goes through `world.run`/`world.play`), moves it in joint space and answers where
it is. Units at this surface are the TD's: joints in deg (revolute) or mm (prismatic), Cartesian
positions in mm in the TD frame, i.e. the robot's base frame, or the real robot's frame when a
calibration is given (`real = A twin + t`, inverted here for moves).

A Cartesian move is checked before anything moves, in this order, each refusal a Problem naming
its `reason`: the workspace must be known (503 `workspace-generating` until the tdgen service has
generated it), the target inside the workspace hull (422 `outside-workspace`), the collision
probability from the nearest sampled points at most `max_collision_probability` (422
`collision-risk`, with the probability), an IK solution within the joint limits (422 `unreachable`)
and, cheaply, that solution's own configuration free of self- and scene collision (a few other IK
solutions are tried before 422 `collision-risk`). IK starts from the current configuration; unless
that lands close by, a few solutions from random starts are compared and the quickest motion wins.
A joint move is checked for the same configuration collision. Moves interpolate in joint space
(smoothstep) so that no joint exceeds its URDF velocity limit, in simulated time; the world's speed
factor maps that to wall time.

The scene can change under the robot (`set_scene`, e.g. a box put on the table): the collision
check uses the new scene at once, `version` is bumped and scene listeners are told (the Thing
binding asks the tdgen service for a new workspace); until that arrives, the hull and collision
probability of the previous workspace stay in use.
"""
from __future__ import annotations

import io
import math
import threading
from dataclasses import dataclass
from typing import Any, Callable, Mapping, Sequence

import msgspec
import numpy as np

from devices.compensation import KinematicArm
from devices.world import PEAK_SPEED, Interpolation, Snapshot, World
from mesh.problem import BadInput, Refused, Unavailable
from mesh.scene_model import Pose, TwinDescription
from tdgen.calibration import Calibration
from tdgen.check import DEFAULT_K, DEFAULT_MAX_PROBABILITY, DEFAULT_RADIUS_MM, Workspace
from tdgen.ik import solve
from tdgen.kinematics import ForwardKinematics
from tdgen.robot import Robot
from tdgen.sampling import CollisionWorld
from tdgen.scene import RobotPlacement, Scene, empty_scene

IK_ATTEMPTS = 5    # IK solutions tried for a Cartesian target before its configurations count as colliding
IK_CANDIDATES = 3  # collision-free solutions compared for the quickest motion...
NEAR_RAD = 0.1     # ...unless the first one moves no joint further than this (rad or m)
LIMIT_SLACK = 1e-9  # SI; joint targets this far past a limit are clipped, not refused


class MoveRefused(Refused):
    slug, title = "move-refused", "Move refused"


class WorkspacePending(Unavailable):
    slug, title = "workspace-generating", "Workspace not generated yet"


@dataclass(frozen=True)
class Base:
    """Where the robot base stands in the scene frame: position (m) and yaw about z (deg)."""

    position: tuple[float, float, float] = (0.0, 0.0, 0.0)
    yaw: float = 0.0

    @property
    def quaternion(self) -> tuple[float, float, float, float]:
        half = math.radians(self.yaw) / 2
        return (0.0, 0.0, math.sin(half), math.cos(half))

    def pose(self) -> Pose:
        return Pose(tuple(float(v) for v in self.position), self.quaternion)  # type: ignore[arg-type]

    @classmethod
    def from_pose(cls, pose: Pose) -> "Base":
        x, y, z, w = pose.q
        return cls(tuple(pose.p), math.degrees(2 * math.atan2(z, w)))  # type: ignore[arg-type]


def placed(scene: Scene | None, base: Base) -> Scene:
    """The scene with the robot standing at `base` (a scene's own `robot` placement is replaced)."""
    scene = scene or empty_scene()
    return msgspec.structs.replace(scene, robot=RobotPlacement(position=tuple(base.position), yaw=base.yaw))


def workspace_from_csv(data: bytes) -> Workspace:
    """The check's workspace from the bytes of a points.csv (`x,y,z,collision,...`)."""
    header = data.split(b"\n", 1)[0].decode().strip().split(",")
    if header[:4] != ["x", "y", "z", "collision"]:
        raise ValueError(f"not a points CSV (header starts {header[:4]})")
    table = np.loadtxt(io.BytesIO(data), delimiter=",", skiprows=1, usecols=(0, 1, 2, 3), ndmin=2)
    return Workspace(table[:, :3], table[:, 3].astype(bool))


class TdFrame:
    """The TD's Cartesian frame: the robot's base frame (mm), or the real robot's through a calibration."""

    def __init__(self, calibration: Calibration | None = None):
        self.calibration = calibration
        if calibration is not None:
            m = np.array(calibration.fit(calibration.used).matrix)
            self._a, self._t, self._a_inv = m[:, :3], m[:, 3], np.linalg.inv(m[:, :3])

    @property
    def name(self) -> str:
        return "twin" if self.calibration is None else "real"

    def from_base(self, base_mm: np.ndarray) -> np.ndarray:
        p = np.asarray(base_mm, dtype=float)
        return p if self.calibration is None else p @ self._a.T + self._t

    def to_base(self, td_mm: np.ndarray) -> np.ndarray:
        p = np.asarray(td_mm, dtype=float)
        return p if self.calibration is None else (p - self._t) @ self._a_inv.T


@dataclass(frozen=True)
class MoveResult:
    q: np.ndarray                           # SI
    reached_mm: tuple[float, float, float]  # TD frame
    error_mm: float                         # from the target (Cartesian moves), else 0


class RobotTwin:
    """One robot arm in a World. Thread-safe: moves run one at a time, reads never wait for them."""

    def __init__(self, world: World, robot: Robot, name: str, base: Base = Base(), scene: Scene | None = None, *,
                 calibration: Calibration | None = None,
                 max_collision_probability: float = DEFAULT_MAX_PROBABILITY, k: int = DEFAULT_K,
                 radius_mm: float = DEFAULT_RADIUS_MM, home: Sequence[float] | None = None):
        if not 0.0 <= max_collision_probability <= 1.0:
            raise ValueError("max_collision_probability must be within 0..1")
        self.world, self.robot, self.name, self.base = world, robot, name, base
        self.frame = TdFrame(calibration)
        self.max_collision_probability, self.k, self.radius_mm = max_collision_probability, k, radius_mm
        self.fk = ForwardKinematics(robot)
        self.version = 0
        self.workspace_hash: str | None = None
        self.workspace_error: str | None = None  # why the workspace could not be generated, if it could not
        self._scene = placed(scene, base)
        self._workspace: Workspace | None = None
        self._collision: CollisionWorld | None = None
        self._move_lock = threading.RLock()   # one motion at a time (and its check)
        self._scene_lock = threading.Lock()   # the scene and its collision world
        self._state_listeners: list[Callable[[], None]] = []
        self._scene_listeners: list[Callable[[int], None]] = []
        self._main = [j.name for j in robot.joints]
        self._vmax = np.array([j.max_velocity for j in robot.joints])
        self._mimic = [n for n in robot.drives() if n not in {*self._main, *robot.passive_names}]
        q0 = np.clip(np.zeros(len(robot.joints)) if home is None else robot.from_user_units(home),
                     robot.lows(), robot.highs())
        self.home = q0
        self.arm: KinematicArm = world.run(lambda: self._build(q0))

    def _build(self, q0: np.ndarray) -> KinematicArm:  # stepping thread (or before the world starts)
        arm = KinematicArm(self.world.client, str(self.robot.urdf_path), self.base.position, self.base.quaternion,
                           self._main, self.robot.passive_names, self.robot.passive, self.world)
        self.arm = arm
        self._apply(q0)
        self.world.add_snapshot_source(self._fill)
        return arm

    def close(self) -> None:
        """Free the collision checker's pybullet client (the World stays the caller's)."""
        with self._scene_lock:
            if self._collision is not None:
                self._collision.close()
                self._collision = None

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

    def _td_position(self, q: np.ndarray) -> np.ndarray:
        return self.frame.from_base(self.fk.positions(q) * 1000.0)

    @property
    def scene(self) -> Scene:
        return self._scene

    @property
    def workspace(self) -> Workspace | None:
        return self._workspace

    def set_workspace(self, workspace: Workspace | None, hash: str | None = None) -> None:
        """The sampled points (TD frame) Cartesian targets are checked against; None: not known yet."""
        self._workspace, self.workspace_hash = workspace, hash
        if workspace is not None:
            self.workspace_error = None

    def set_scene(self, scene: Scene | Mapping[str, Any]) -> int:
        """New surroundings (the robot keeps its base): bump `version`, tell the listeners. Returns it."""
        try:  # a plain, checked copy (numpy numbers from the caller's geometry included)
            scene = msgspec.json.decode(msgspec.json.encode(scene, enc_hook=_plain), type=Scene)
        except (msgspec.ValidationError, msgspec.DecodeError, TypeError) as e:
            raise BadInput(f"{self.name}: not a scene ({e})") from None
        with self._scene_lock:
            self._scene = placed(scene, self.base)
            if self._collision is not None:
                self._collision.close()
                self._collision = None
            self.version += 1
            version = self.version
        for listener in list(self._scene_listeners):
            listener(version)
        return version

    def collides_in(self, scene: Scene) -> bool:
        """Whether the robot, where it stands now, would collide in `scene` (e.g. with a box about to be added)."""
        world = CollisionWorld(self.robot, placed(scene, self.base))
        try:
            return bool(world.colliding(self.arm.q[None])[0])
        finally:
            world.close()

    def reset(self) -> None:
        """Back to the home configuration at once (a scene reset; the world cancels a move under way first)."""
        with self._move_lock:
            self.world.run(lambda: self._apply(self.home))

    def description(self, urdf: str, urdf_sha256: str, urdf_file: str, samples: int, seed: int = 0) -> TwinDescription:
        """What the tdgen service generates this robot's TD from (mesh.scene_model contract)."""
        cal = self.frame.calibration
        scene = msgspec.to_builtins(self._scene)
        scene.pop("robot", None)
        return TwinDescription(
            robot=self.name, urdf=urdf, urdf_sha256=urdf_sha256, urdf_file=urdf_file, base=self.base.pose(),
            ee=self.robot.ee_link, scene=scene, samples=samples, seed=seed,
            calibration=None if cal is None else [[*t, *r] for t, r in zip(cal.twin, cal.real)],
            frame=self.frame.name, version=self.version)

    # --- moves ----------------------------------------------------------------------------------
    def move_to_joints(self, joints: Mapping[str, float] | Sequence[float]) -> MoveResult:
        """Move to joint values (deg / mm, by name or in joint order); returns when the motion is over."""
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
        goal = np.clip(goal, lows, highs)
        with self._move_lock:
            if self._collides(goal):
                raise MoveRefused(f"{self.name}: the configuration {self._user(goal)} collides with the robot "
                                  "itself or the scene", reason="collision-risk",
                                  extra={"configuration_collides": True})
            self._play(goal)
        return MoveResult(goal, _triple(self._td_position(goal)), 0.0)

    def move_to_cartesian(self, target_mm: Sequence[float]) -> MoveResult:
        """Move the end effector to `target_mm` (TD frame); refused (nothing moves) unless every check passes."""
        target = np.asarray(target_mm, dtype=float).reshape(3)
        with self._move_lock:
            goal = self.check_cartesian(target)
            self._play(goal)
        reached = self._td_position(goal)
        return MoveResult(goal, _triple(reached), float(np.linalg.norm(reached - target)))

    def check_cartesian(self, target_mm: Sequence[float]) -> np.ndarray:
        """The joint values a Cartesian move would go to, or the Problem saying why it may not."""
        target = np.asarray(target_mm, dtype=float).reshape(3)
        where = f"{self.name}: target ({', '.join(f'{v:g}' for v in target)}) mm"
        ws = self._workspace
        if ws is None and self.workspace_error:
            raise WorkspacePending(f"{self.name}: its workspace could not be generated ({self.workspace_error}); "
                                   "Cartesian moves are refused", reason="workspace-failed")
        if ws is None:
            raise WorkspacePending(f"{self.name}: its workspace is being generated by the tdgen service; "
                                   "Cartesian moves are refused until it is known", reason="workspace-generating")
        check = ws.check(target, self.k, self.radius_mm, self.max_collision_probability)
        if not check.inside:
            raise MoveRefused(f"{where} is {check.reason}", reason="outside-workspace",
                              extra={"margin_mm": round(check.margin_mm, 3)})
        risk = {"collision_probability": check.collision_probability, "neighbours": check.neighbours,
                "max_collision_probability": self.max_collision_probability}
        if not check.ok:
            raise MoveRefused(f"{where}: {check.reason}", reason="collision-risk", extra=risk)
        target_m = self.frame.to_base(target) / 1000.0
        best, free = None, []
        for attempt in range(IK_ATTEMPTS):
            result = solve(self.fk, target_m, seed=self.arm.q if attempt == 0 else None, rng=attempt)
            if not result.ok:
                if best is None or result.error_m < best.error_m:
                    best = result
                if attempt == 0:
                    break  # 200 random restarts found nothing: more attempts will not either
                continue
            best = result
            if not self._collides(result.q):
                free.append(result.q)
                if len(free) == IK_CANDIDATES or np.abs(result.q - self.arm.q).max() <= NEAR_RAD:
                    break
        if free:
            return min(free, key=self.motion_duration)  # the quickest of the solutions found
        if best is not None and not best.ok:
            raise MoveRefused(f"{where}: no joint configuration within the limits reaches it (closest "
                              f"{best.error_m * 1000:.3f} mm away)", reason="unreachable",
                              extra={"error_mm": round(best.error_m * 1000, 6)})
        raise MoveRefused(f"{where}: every joint configuration found for it collides with the robot itself or "
                          "the scene", reason="collision-risk", extra={**risk, "configuration_collides": True})

    def _collides(self, q: np.ndarray) -> bool:
        with self._scene_lock:
            if self._collision is None:
                self._collision = CollisionWorld(self.robot, self._scene)
            return bool(self._collision.colliding(q[None])[0])

    def motion_duration(self, goal: np.ndarray) -> float:
        """Simulated seconds from now to `goal` (SI) with no joint above its velocity limit."""
        return PEAK_SPEED * float(np.max(np.abs(np.asarray(goal) - self.arm.q) / self._vmax, initial=0.0))

    def _play(self, goal: np.ndarray) -> None:
        duration = self.motion_duration(goal)
        self.world.play(Interpolation(lambda: self.arm.q, goal, duration, self._apply)).result()

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
