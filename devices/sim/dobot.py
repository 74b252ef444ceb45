"""The warehouse Dobot Magician on its linear track (`dobot`), its warehouse queue and the cubes.

`get_cube` takes the first cube of the warehouse queue with the suction cup (a fixed constraint),
puts it on the start of the right belt and pushes the queue forward; `return_cube` takes the cube
waiting at the end of the left belt (where infrared sensor 1 sees it) back to the end of the
queue; `calibrate` returns to the middle of the track. Every action returns when the motion is
over and refuses, before anything moves, what it cannot do (empty warehouse, no cube to return,
full warehouse).

`position` is what the real Dobot reports: `l` = track position (mm, 0..900), x/y/z = suction
cup tip in the arm's own frame (mm; origin on the base axis at shoulder height, x forward),
r = base + end rotation (deg).
"""
from __future__ import annotations

import math
import threading
from dataclasses import dataclass, field
from typing import Callable

import numpy as np
import pybullet as pb

from devices.sim.compensation import DOBOT_MAIN_JOINTS, DOBOT_PASSIVE_JOINTS, DOBOT_URDF, KinematicArm, dobot_passive
from devices.sim.pybullet_world import PEAK_SPEED, Interpolation, Snapshot, World, attach, body_pose, place
from devices.sim.vec import Vec
from mesh.wot.problem import Refused

REAR_ARM, FOREARM = 135.0, 147.0           # mm
SHOULDER_Z = 139.0                          # mm above the bottom of the base
TOOL_FRONT, TOOL_DOWN = 60.0, 55.0          # suction cup tip from the wrist, mm
LIMITS_DEG = {"j1_base": (-90.0, 90.0), "j2_rear_arm": (0.0, 85.0), "j3_forearm": (-10.0, 95.0)}
TRACK_LENGTH = 900.0                        # mm
HOME_L = TRACK_LENGTH / 2
HOME_JOINTS = np.radians([0.0, 30.0, 30.0, 0.0])
RAIL_SPEED = 0.1                            # m/s
JOINT_SPEED = math.radians(120.0)
PUSH_TIME = 0.6                             # s for the queue to slide one slot forward
CUBE_SIZE = 0.028                           # m

Pose2 = tuple[float, np.ndarray]            # (track position mm, arm joints rad)
Plan = tuple[Pose2, Pose2]                  # (above, at) a cube's top


class DobotRefused(Refused):
    slug, title = "dobot-refused", "Dobot cannot do this"


class EmptyWarehouse(DobotRefused):
    pass


class NoCubeAtPickup(DobotRefused):
    pass


class WarehouseFull(DobotRefused):
    pass


@dataclass
class Cube:
    name: str
    color: tuple[float, float, float]   # sRGB 0..1, what the colour sensor sees
    body: int
    size: float = CUBE_SIZE


def make_cube(client: int, name: str, color: Vec, position: Vec,
              size: float = CUBE_SIZE, mass: float = 0.02) -> Cube:
    half = [size / 2] * 3
    col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
    vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=[*color, 1.0], physicsClientId=client)
    body = pb.createMultiBody(mass, col, vis, list(position), physicsClientId=client)
    # frictionAnchor: without it a resting cube creeps (~0.7 mm and 0.7 deg per simulated minute)
    pb.changeDynamics(body, -1, lateralFriction=0.6, activationState=pb.ACTIVATION_STATE_DISABLE_SLEEPING,
                      frictionAnchor=1, physicsClientId=client)
    return Cube(name, tuple(color), body, size)


@dataclass
class Warehouse:
    """A queue of cubes in slots (world positions of the cube centres); slot 0 is where the Dobot takes."""

    slots: list[np.ndarray]
    queue: list[Cube] = field(default_factory=list)

    @property
    def capacity(self) -> int:
        return len(self.slots)

    def names(self) -> list[str]:
        return [c.name for c in self.queue]


class Slide:
    """Bodies slid kinematically from where they are to target positions (a warehouse push)."""

    def __init__(self, client: int, targets: dict[int, Vec], duration: float):
        self._client, self._targets, self._duration = client, targets, duration
        self._start: dict[int, np.ndarray] = {}
        self._t = 0.0

    def advance(self, dt: float) -> bool:
        if not self._start:
            self._start = {b: np.array(body_pose(self._client, b)[0]) for b in self._targets}
        self._t += dt
        u = min(self._t / self._duration, 1.0) if self._duration > 0 else 1.0
        for b, goal in self._targets.items():
            place(self._client, b, self._start[b] + (np.asarray(goal) - self._start[b]) * u)
        return u >= 1.0


# --- kinematics (arm frame, mm; joints in rad) --------------------------------------------------------
def dobot_fk(q: np.ndarray) -> np.ndarray:
    """(N, >=3) [j1, j2, j3, ...] -> (N, 3) suction cup tip in the arm frame (mm)."""
    q = np.atleast_2d(np.asarray(q, dtype=float))
    reach = REAR_ARM * np.sin(q[:, 1]) + FOREARM * np.cos(q[:, 2]) + TOOL_FRONT
    z = REAR_ARM * np.cos(q[:, 1]) - FOREARM * np.sin(q[:, 2]) - TOOL_DOWN
    return np.stack([reach * np.cos(q[:, 0]), reach * np.sin(q[:, 0]), z], axis=1)


def dobot_ik(x: float, y: float, z: float) -> np.ndarray:
    """[j1, j2, j3, j4] (rad) for a tip position in the arm frame, the tool square to the track (r = 0)."""
    j1 = math.atan2(y, x)
    s = math.hypot(x, y) - TOOL_FRONT
    h = z + TOOL_DOWN
    d = math.hypot(s, h)
    if not abs(REAR_ARM - FOREARM) < d < REAR_ARM + FOREARM:
        raise DobotRefused(f"({x:.0f}, {y:.0f}, {z:.0f}) mm is out of the Dobot's reach", reason="unreachable")
    up = math.atan2(h, s) + math.acos((REAR_ARM ** 2 + d * d - FOREARM ** 2) / (2 * REAR_ARM * d))
    j2 = math.pi / 2 - up
    j3 = math.atan2(REAR_ARM * math.sin(up) - h, s - REAR_ARM * math.cos(up))
    for name, v in zip(LIMITS_DEG, (j1, j2, j3)):
        lo, hi = LIMITS_DEG[name]
        if not lo - 1e-9 <= math.degrees(v) <= hi + 1e-9:
            raise DobotRefused(f"({x:.0f}, {y:.0f}, {z:.0f}) mm needs {name} at {math.degrees(v):.1f} deg, "
                               f"outside {lo:g}..{hi:g}", reason="unreachable")
    return np.array([j1, j2, j3, -j1])


class Dobot:
    """The Dobot's behaviour; one action at a time (others wait for `lock`)."""

    def __init__(self, world: World, track_start: Vec, track_axis: Vec, yaw: float,
                 warehouse: Warehouse, drop_point: Vec, pickup_point: Vec,
                 cubes: Callable[[], list[Cube]], travel_z: float, name: str = "dobot",
                 pickup_radius: float = 0.025):
        self.world, self.name = world, name
        self.track_start = np.asarray(track_start, float)
        self.track_axis = np.asarray(track_axis, float) / np.linalg.norm(track_axis)
        self.yaw = yaw
        self._orn = pb.getQuaternionFromEuler([0, 0, yaw])
        self.warehouse = warehouse
        self.drop_point = np.asarray(drop_point, float)      # centre of a cube put on the right belt
        self.pickup_point = np.asarray(pickup_point, float)  # centre of a cube waiting on the left belt
        self.pickup_radius = pickup_radius                  # m, horizontally
        self._cubes = cubes
        self.travel_z = travel_z
        self.lock = threading.RLock()
        self.arm = KinematicArm(world.client, str(DOBOT_URDF), self._base(HOME_L), self._orn,
                                DOBOT_MAIN_JOINTS, DOBOT_PASSIVE_JOINTS, dobot_passive, world)
        self.l = HOME_L
        self._held: Cube | None = None
        self._constraint: int | None = None
        self.arm.apply(HOME_JOINTS)
        world.add_snapshot_source(self._fill)

    # --- properties -----------------------------------------------------------------------------
    @property
    def position(self) -> dict[str, float]:
        x, y, z = dobot_fk(self.arm.q)[0]
        q = self.arm.q
        return {"l": round(self.l, 2), "x": round(float(x), 2), "y": round(float(y), 2), "z": round(float(z), 2),
                "r": round(math.degrees(q[0] + q[3]), 2)}

    @property
    def holding(self) -> Cube | None:
        return self._held

    # --- actions --------------------------------------------------------------------------------
    def check_get_cube(self) -> None:
        """What `get_cube` refuses, without moving: an empty warehouse, a cube already on the belt."""
        if not self.warehouse.queue:
            raise EmptyWarehouse("The warehouse is empty: there is no cube to get. Return a cube first "
                                 "(returnCube) or reset the platform.", reason="empty-warehouse")
        if self.world.run(lambda: self._cube_near(self.drop_point)) is not None:
            raise DobotRefused("There is already a cube at the start of conveyor belt 2: run the belt "
                               "forward first.", reason="belt-occupied")

    def get_cube(self) -> Cube:
        """The first cube of the queue onto the start of the right belt; the queue moves up."""
        with self.lock:
            self.check_get_cube()
            cube = self.warehouse.queue[0]
            pick, put = self._plan(cube, self.warehouse.slots[0]), self._plan(cube, self.drop_point, 0.001)
            self._pick(cube, pick)
            self.warehouse.queue.pop(0)
            queue: dict[int, Vec] = {c.body: self.warehouse.slots[i] for i, c in enumerate(self.warehouse.queue)}
            self.world.play(Slide(self.world.client, queue, PUSH_TIME)).result()
            self._put(put)
            return cube

    def check_return_cube(self) -> Cube:
        """What `return_cube` refuses, without moving: no cube at the pickup, a full warehouse; else the cube."""
        cube = self.world.run(lambda: self._cube_near(self.pickup_point))
        if cube is None:
            raise NoCubeAtPickup("There is no cube at the end of conveyor belt 1 to return: run the belt "
                                 "backward until infrared sensor 1 detects the cube, then call returnCube.",
                                 reason="no-cube")
        if len(self.warehouse.queue) >= self.warehouse.capacity:
            raise WarehouseFull(f"The warehouse is full ({self.warehouse.capacity} cubes).",
                                reason="warehouse-full")
        return cube

    def return_cube(self) -> Cube:
        """The cube waiting at the end of the left belt back to the end of the warehouse queue."""
        with self.lock:
            cube = self.check_return_cube()
            centre = np.asarray(self.world.run(lambda: body_pose(self.world.client, cube.body)[0]))
            pick = self._plan(cube, centre)
            put = self._plan(cube, self.warehouse.slots[len(self.warehouse.queue)], 0.001)
            self._pick(cube, pick)
            self._put(put)
            self.warehouse.queue.append(cube)
            return cube

    def calibrate(self) -> None:
        """Back to the middle of the track, arm in its home pose."""
        with self.lock:
            self._move(HOME_L, HOME_JOINTS)

    # --- motion ---------------------------------------------------------------------------------
    def _base(self, l_mm: float) -> np.ndarray:
        return self.track_start + self.track_axis * (l_mm / 1000.0)

    def _solve(self, tip: Vec) -> tuple[float, np.ndarray]:
        """Track position (mm) that puts a world point straight ahead, and the arm joints to reach it."""
        tip = np.asarray(tip, float)
        l_mm = float(np.clip(np.dot(tip - self.track_start, self.track_axis) * 1000.0, 0.0, TRACK_LENGTH))
        rel = tip - self._base(l_mm)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        local = np.array([cy * rel[0] + sy * rel[1], -sy * rel[0] + cy * rel[1], rel[2]]) * 1000.0
        return l_mm, dobot_ik(local[0], local[1], local[2] - SHOULDER_Z)

    def _move(self, l_mm: float, joints: np.ndarray) -> None:
        start = np.concatenate([[self.l / 1000.0], self.arm.q])
        goal = np.concatenate([[l_mm / 1000.0], joints])
        d = np.abs(goal - start)
        duration = PEAK_SPEED * max(d[0] / RAIL_SPEED, float(d[1:].max()) / JOINT_SPEED, 0.02 / PEAK_SPEED)
        self.world.play(Interpolation(lambda: np.concatenate([[self.l / 1000.0], self.arm.q]), goal,
                                      duration, self._apply)).result()

    def _apply(self, v: np.ndarray) -> None:
        self.l = float(v[0]) * 1000.0
        pb.resetBasePositionAndOrientation(self.arm.body, list(self._base(self.l)), self._orn,
                                           physicsClientId=self.world.client)
        self.arm.apply(v[1:])

    def _plan(self, cube: Cube, centre: Vec, gap: float = 0.0) -> Plan:
        """(above, at) poses for the suction cup on top of a cube centred at `centre` (`gap` above that).

        Solved before anything moves, so an unreachable point is refused up front.
        """
        top = np.asarray(centre, float) + [0, 0, cube.size / 2 + gap]
        return self._solve([top[0], top[1], self.travel_z]), self._solve(top)

    def _pick(self, cube: Cube, plan: Plan) -> None:
        above, at = plan
        self._move(*above)
        self._move(*at)
        self.world.run(lambda: self._hold(cube))
        self._move(*above)

    def _put(self, plan: Plan) -> None:
        above, at = plan
        self._move(*above)
        self._move(*at)
        self.world.run(self._release)
        self._move(*above)

    # --- stepping thread ------------------------------------------------------------------------
    def _cube_near(self, point: np.ndarray) -> Cube | None:
        """A free cube whose centre is within `pickup_radius` of `point` (horizontally) at its height."""
        for cube in self._cubes():
            if cube.body in self.world.held:
                continue
            off = np.asarray(body_pose(self.world.client, cube.body)[0]) - point
            if math.hypot(off[0], off[1]) <= self.pickup_radius and abs(off[2]) <= 0.01:
                return cube
        return None

    def _hold(self, cube: Cube) -> None:
        self._constraint = attach(self.world.client, self.arm.body, self.arm.link_index["tcp"], cube.body)
        self._held = cube
        self.world.held.add(cube.body)

    def _release(self) -> None:
        if self._constraint is not None:
            pb.removeConstraint(self._constraint, physicsClientId=self.world.client)
        if self._held is not None:
            self.world.held.discard(self._held.body)
        self._constraint, self._held = None, None

    def reset_state(self, cubes: list[Cube]) -> None:
        """Home, nothing held, `cubes` back in the warehouse in this order (scene reset; stepping thread only)."""
        self._release()
        self._apply(np.concatenate([[HOME_L / 1000.0], HOME_JOINTS]))
        self.warehouse.queue = list(cubes[: self.warehouse.capacity])
        for cube, slot in zip(self.warehouse.queue, self.warehouse.slots):
            place(self.world.client, cube.body, slot)

    def _fill(self, snap: Snapshot) -> None:
        snap.joints[self.name] = self.arm.joint_values()
        snap.bodies[self.name] = body_pose(self.world.client, self.arm.body)
        snap.states[self.name] = {"position": self.position, "queue": self.warehouse.names()}
