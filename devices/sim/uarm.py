"""The uArm Swift Pro (`uarm`): moves in the real robot's millimetre frame, grips cubes.

The real frame is the firmware's: origin on the base axis at the bottom of the base, x forward,
y left, z up, in mm, the point being the tool point (56.65 mm in front of and 74.55 mm below the
wrist). The twin's base stands upright and unrotated in the scene, so
`real = 1000 * twin - 1000 * base_position` on every axis. `real_fk`/`real_ik` are the firmware's
own kinematics (analytic, elbow up) and refuse what the firmware refuses (motor angle limits and
the angle between the arms).

Every motion returns when it is over: joint-space interpolation taking the longer of the
Cartesian distance at the commanded speed (mm/min, like the firmware's F; goTo uses 3000) and the
largest joint change at the joint speed limit. The twin turns the hand servo against the base
(`hand = -base`) so the fingers stay square to the table and meet cubes face-on.
"""
from __future__ import annotations

import csv
import math
import threading
from pathlib import Path
from typing import Callable, Iterable, Mapping, Sequence

import numpy as np
import pybullet as pb

from devices.sim.compensation import UARM_MAIN_JOINTS, UARM_PASSIVE_JOINTS, UARM_URDF, KinematicArm, uarm_passive
from devices.sim.pybullet_world import PEAK_SPEED, Interpolation, Snapshot, World, attach
from devices.sim.vec import Vec
from mesh.wot.problem import Refused

# firmware geometry (mm) and motor limits (deg), Swift Pro firmware uarm_coord_convert.h
LOWER_ARM, UPPER_ARM = 142.07, 158.81
SHOULDER_Z, SHOULDER_X = 107.4, 13.2
TOOL_FRONT, TOOL_DOWN = 56.65, 74.55
LIMITS_DEG = {"base": (-90.0, 90.0), "lower_arm": (-4.0, 135.6), "upper_arm": (-4.0, 119.9)}
BETWEEN_ARMS_DEG = (10.0, 151.0)  # 180 - A - B

GOTO_RANGE = {"x": (120, 200), "y": (-200, 200), "z": (52, 100)}      # real TD, goTo/go/location
HOME_RANGE = {"x": (50, 250), "y": (-330, 330), "z": (52, 100)}       # real TD, homeLoc
SPEED_RANGE = (100, 10000)   # mm/min, real TD `go`
GOTO_SPEED = 3000            # mm/min, real TD `goTo`
DEFAULT_HOME = (200, 0, 100)
TURN_STEP_MM = 10            # one step of turnLeft / turnRight, in y
JOINT_SPEED = math.radians(120.0)
HAND_SPEED = math.radians(180.0)
FINGER_OPEN, FINGER_EMPTY, GRIP_TIME = 0.022, 0.002, 0.4  # finger offset from centre (m), s
GRIP_BOX = (0.015, 0.02)     # a cube is between the fingers: |x| <= 15 mm, |z| <= 20 mm of the tool point


class UarmRefused(Refused):
    slug, title = "uarm-refused", "uArm cannot do this move"


class OutOfRange(UarmRefused):
    """Outside the ranges of the real uArm's TD."""


class Unreachable(UarmRefused):
    """Inside the ranges, but the arm cannot get there (motor limits)."""


# --- kinematics (real frame, mm; main joints in rad) -----------------------------------------------
def real_fk(q: np.ndarray) -> np.ndarray:
    """(N, >=3) [base, lower_arm, upper_arm, ...] -> (N, 3) tool point in the real frame (mm)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    c, a, b = q[:, 0], q[:, 1], q[:, 2]
    reach = LOWER_ARM * np.cos(a) + UPPER_ARM * np.cos(b) + SHOULDER_X + TOOL_FRONT
    z = LOWER_ARM * np.sin(a) - UPPER_ARM * np.sin(b) + SHOULDER_Z - TOOL_DOWN
    return np.stack([reach * np.cos(c), reach * np.sin(c), z], axis=1)


def real_ik(x: float, y: float, z: float) -> np.ndarray:
    """Main joints [base, lower_arm, upper_arm, hand] (rad) for a real-frame tool point; Unreachable if none."""
    where = f"({x:g}, {y:g}, {z:g}) mm"
    if x <= 0:
        raise Unreachable(f"{where}: the uArm only reaches points in front of it (x > 0)", reason="unreachable")
    c = math.atan2(y, x)
    s = math.hypot(x, y) - SHOULDER_X - TOOL_FRONT
    h = z + TOOL_DOWN - SHOULDER_Z
    d = math.hypot(s, h)
    if not abs(LOWER_ARM - UPPER_ARM) < d < LOWER_ARM + UPPER_ARM:
        raise Unreachable(f"{where} is out of the arm's reach", reason="unreachable")
    a = math.atan2(h, s) + math.acos((LOWER_ARM ** 2 + d * d - UPPER_ARM ** 2) / (2 * LOWER_ARM * d))
    b = math.atan2(LOWER_ARM * math.sin(a) - h, s - LOWER_ARM * math.cos(a))
    angles = {"base": math.degrees(c), "lower_arm": math.degrees(a), "upper_arm": math.degrees(b)}
    for name, v in angles.items():
        lo, hi = LIMITS_DEG[name]
        if not lo - 1e-9 <= v <= hi + 1e-9:
            raise Unreachable(f"{where} needs the {name.replace('_', ' ')} motor at {v:.1f} deg, "
                              f"outside {lo:g}..{hi:g} deg", reason="unreachable")
    between = 180.0 - angles["lower_arm"] - angles["upper_arm"]
    if not BETWEEN_ARMS_DEG[0] <= between <= BETWEEN_ARMS_DEG[1]:
        raise Unreachable(f"{where} needs {between:.1f} deg between the arms, outside "
                          f"{BETWEEN_ARMS_DEG[0]:g}..{BETWEEN_ARMS_DEG[1]:g} deg", reason="unreachable")
    return np.array([c, a, b, -c])


def check_range(point: Mapping[str, float], ranges: dict[str, tuple[int, int]], what: str) -> None:
    for axis, (lo, hi) in ranges.items():
        v = point[axis]
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not lo <= v <= hi:
            raise OutOfRange(f"{what}: {axis} must be within {lo}..{hi} mm, got {v!r}", reason="out-of-range")


class Uarm:
    """The uArm's behaviour. Actions block until the motion is over; one action at a time."""

    def __init__(self, world: World, base_position: Vec, graspable: Callable[[], Iterable[int]],
                 home: Sequence[int] = DEFAULT_HOME, name: str = "uarm"):
        self.world, self.name = world, name
        self.base_position = np.asarray(base_position, dtype=float)
        self.arm = KinematicArm(world.client, str(UARM_URDF), base_position, (0, 0, 0, 1),
                                UARM_MAIN_JOINTS, UARM_PASSIVE_JOINTS, uarm_passive, world)
        self._graspable = graspable
        self._default_home = dict(zip("xyz", home))
        self._home = dict(self._default_home)
        self.lock = threading.RLock()
        self._held: int | None = None
        self._constraint: int | None = None
        self._opening = FINGER_OPEN
        self._set_fingers(FINGER_OPEN)
        self.arm.apply(real_ik(*home))
        world.add_snapshot_source(self._fill)

    # --- properties -----------------------------------------------------------------------------
    @property
    def position_mm(self) -> tuple[float, float, float]:
        """The tool point in the real frame (mm), unrounded."""
        return tuple(float(v) for v in real_fk(self.arm.q)[0])  # type: ignore[return-value]

    @property
    def location(self) -> dict[str, int]:
        """Real TD `location`: integer mm."""
        return {k: round(v) for k, v in zip("xyz", self.position_mm)}

    @property
    def home_loc(self) -> dict[str, int]:
        return dict(self._home)

    @home_loc.setter
    def home_loc(self, value: dict[str, int]) -> None:
        point = {k: value[k] for k in "xyz"}  # the schema requires x, y and z
        check_range(point, HOME_RANGE, "homeLoc")
        real_ik(*(point[k] for k in "xyz"))  # refuse a home the arm cannot reach
        self._home = {k: point[k] for k in "xyz"}

    @property
    def holding(self) -> int | None:
        """The body id of the gripped cube, if any."""
        return self._held

    def to_world(self, point_mm: Vec) -> np.ndarray:
        return self.base_position + np.asarray(point_mm, dtype=float) / 1000.0

    def to_real(self, point_world: Vec) -> np.ndarray:
        return (np.asarray(point_world, dtype=float) - self.base_position) * 1000.0

    # --- actions --------------------------------------------------------------------------------
    def check_go_to(self, x: float, y: float, z: float, speed: float = GOTO_SPEED) -> None:
        """What `go_to` refuses, without moving: out of the goTo box or speed range, or out of reach."""
        check_range({"x": x, "y": y, "z": z}, GOTO_RANGE, "goTo")
        lo, hi = SPEED_RANGE
        if isinstance(speed, bool) or not isinstance(speed, (int, float)) or not lo <= speed <= hi:
            raise OutOfRange(f"go: speed must be within {lo}..{hi} mm/min, got {speed!r}", reason="out-of-range")
        real_ik(x, y, z)

    def go_to(self, x: float, y: float, z: float, speed: float = GOTO_SPEED) -> None:
        """Real TD `goTo` (and `go` with a speed, mm/min): refuses before anything moves."""
        self.check_go_to(x, y, z, speed)
        self._move((x, y, z), speed)

    def check_turn(self, dy: float) -> None:
        """What a turn of `dy` mm refuses, without moving."""
        _, y, _ = self.position_mm
        lo, hi = GOTO_RANGE["y"]
        if not lo <= y + dy <= hi:
            raise OutOfRange(f"turn: y would be {y + dy:.0f} mm, outside {lo}..{hi} mm", reason="out-of-range")

    def place(self, x: float, y: float, z: float) -> None:
        """Put the tool point at (x, y, z) at once (the twin following its real arm, which is already
        there); any point the arm reaches, inside the goTo box or not. Unreachable: Unreachable."""
        goal = real_ik(x, y, z)
        with self.lock:
            self.world.run(lambda: self.arm.apply(goal))

    def go(self, x: float, y: float, z: float, speed: float) -> None:
        self.go_to(x, y, z, speed)

    def go_home(self) -> None:
        self._move(tuple(self._home[k] for k in "xyz"), GOTO_SPEED)

    def turn_left(self, step: float = TURN_STEP_MM) -> dict[str, int]:
        """One step towards +y; returns the new y."""
        return self._turn(+step)

    def turn_right(self, step: float = TURN_STEP_MM) -> dict[str, int]:
        """One step towards -y; returns the new y."""
        return self._turn(-step)

    def grip_close(self) -> None:
        """Close the fingers; a cube between them is held (fixed constraint) until `grip_open`."""
        with self.lock:
            if self._held is not None:
                return
            target = self.world.run(self._find_cube)
            self._play_fingers(target[1] if target else FINGER_EMPTY)
            if target:
                self.world.run(lambda: self._hold(target[0]))

    def grip_open(self) -> None:
        with self.lock:
            self.world.run(self._release)
            self._play_fingers(FINGER_OPEN)

    # --- internals ------------------------------------------------------------------------------
    def _turn(self, dy: float) -> dict[str, int]:
        with self.lock:
            self.check_turn(dy)
            x, y, z = self.position_mm
            new_y = y + dy
            self._move((x, new_y, z), GOTO_SPEED)
            return {"y": round(new_y)}

    def _move(self, target: Vec, speed: float) -> None:
        goal = real_ik(*target)
        with self.lock:
            start = self.arm.q
            dist = float(np.linalg.norm(real_fk(start)[0] - np.asarray(target, float)))
            dq = np.abs(goal - start)
            duration = max(dist / (speed / 60.0), PEAK_SPEED * float(dq[:3].max()) / JOINT_SPEED,
                           PEAK_SPEED * float(dq[3]) / HAND_SPEED, 0.02)
            self.world.play(Interpolation(lambda: self.arm.q, goal, duration, self.arm.apply)).result()

    def _play_fingers(self, target: float) -> None:
        duration = GRIP_TIME * abs(target - self._opening) / (FINGER_OPEN - FINGER_EMPTY)
        self.world.play(Interpolation(lambda: np.array([self._opening]), [target], duration,
                                      lambda v: self._set_fingers(float(v[0])))).result()

    def _set_fingers(self, opening: float) -> None:
        self._opening = opening
        self.arm.set_joint("finger_left", opening)
        self.arm.set_joint("finger_right", opening)

    def _find_cube(self) -> tuple[int, float] | None:
        """(body, finger offset to close on it) of the nearest free cube between the fingers."""
        c = self.world.client
        tpos, torn = self.arm.link_pose("tcp")
        ipos, iorn = pb.invertTransform(tpos, torn)
        best = None
        for body in self._graspable():
            if body in self.world.held:
                continue
            pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=c)
            rpos, rorn = pb.multiplyTransforms(ipos, iorn, pos, orn)
            if abs(rpos[0]) > GRIP_BOX[0] or abs(rpos[2]) > GRIP_BOX[1] or abs(rpos[1]) > self._opening:
                continue
            half = np.asarray(pb.getCollisionShapeData(body, -1, physicsClientId=c)[0][3]) / 2
            rot = np.asarray(pb.getMatrixFromQuaternion(rorn)).reshape(3, 3)
            width = float(np.abs(rot[1, :]) @ half)  # half-extent across the fingers
            d = math.hypot(*rpos)
            if best is None or d < best[0]:
                best = (d, body, min(width, FINGER_OPEN))
        return None if best is None else (best[1], best[2])

    def _hold(self, body: int) -> None:
        self._constraint = attach(self.world.client, self.arm.body, self.arm.link_index["tcp"], body)
        self._held = body
        self.world.held.add(body)

    def _release(self) -> None:
        if self._constraint is not None:
            pb.removeConstraint(self._constraint, physicsClientId=self.world.client)
        if self._held is not None:
            self.world.held.discard(self._held)
        self._constraint, self._held = None, None

    def reset_state(self) -> None:
        """Home, gripper open and empty, default home location (scene reset; stepping thread only)."""
        self._release()
        self._set_fingers(FINGER_OPEN)
        self._home = dict(self._default_home)
        self.arm.apply(real_ik(*(self._home[k] for k in "xyz")))

    def _fill(self, snap: Snapshot) -> None:
        snap.joints[self.name] = self.arm.joint_values()
        snap.states[self.name] = {"location": self.location, "holding": self._held is not None}


# --- twin-to-real calibration pairs ---------------------------------------------------------------
def calibration_pairs(base_position: Vec, n: int = 40, seed: int = 7) -> list[tuple[float, ...]]:
    """(twin x,y,z, real x,y,z), both in mm, for `n` reachable configurations.

    The twin side is the tool link as pybullet places it with the uArm at `base_position`, in mm in
    the robot's base frame: the frame of tdgen's sampled points, which a calibration maps. The real
    side is the firmware's forward kinematics of the same motor angles.
    """
    rng = np.random.default_rng(seed)
    qs: list[np.ndarray] = []
    while len(qs) < n:
        target = [rng.uniform(*GOTO_RANGE[k]) for k in "xyz"]
        try:
            qs.append(real_ik(*target))
        except Unreachable:
            continue
    client = pb.connect(pb.DIRECT)
    try:
        arm = KinematicArm(client, str(UARM_URDF), base_position, (0, 0, 0, 1),
                           UARM_MAIN_JOINTS, UARM_PASSIVE_JOINTS, uarm_passive)
        rows = []
        for q in qs:
            arm.apply(q)
            twin = (np.array(arm.link_pose("tcp")[0]) - np.array(base_position)) * 1000.0  # base frame, mm
            rows.append((*(float(v) for v in twin), *real_fk(q)[0]))
        return rows
    finally:
        pb.disconnect(client)


def write_calibration_csv(path: Path, base_position: Vec, n: int = 40) -> None:
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["twin_x", "twin_y", "twin_z", "real_x", "real_y", "real_z"])
        for row in calibration_pairs(base_position, n):
            w.writerow([f"{v:.3f}" for v in row])
