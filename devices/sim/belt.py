"""Conveyor belts (`conveyor-belt-1`, `conveyor-belt-2`): a static body whose top carries what lies on it.

pybullet has no moving surfaces, so the belt carries kinematically: before every step, each body
touching the belt gets the belt's velocity along the belt (and none across it, no spin). The
surface has no friction of its own, so that velocity is exactly what the body keeps during the
step; a stopped belt holds its load the same way. While running, a body's centre is kept at least
`stop_margin` from either end (the end stops), so nothing falls off when a workflow forgets to
stop the belt.

Speed: `speed` is the real belt's 1..100 %, mapped linearly to 0.6..60 mm/s (100 % = 60 mm/s,
about what the lab's stepper belts do).
"""
from __future__ import annotations

import math
import threading

import numpy as np
import pybullet as pb

from devices.sim.belt_rules import DEFAULT_SPEED, MAX_SPEED_MM_S, STARTED, STOPPED, belt_speed
from devices.sim.pybullet_world import Snapshot, World, static_box
from devices.sim.vec import Vec

__all__ = ["DEFAULT_SPEED", "MAX_SPEED_MM_S", "STARTED", "STOPPED", "Belt", "belt_speed"]

_DIRECTIONS = {1: "forward", -1: "backward", 0: "stopped"}


class Belt:
    """One belt: `start_forward`, `start_backward`, `stop`, `speed` (1..100 %), thread-safe.

    Forward carries objects from `back_end` towards `front_end` (world xy, m, ends of the carrying
    surface); `top_z` is the height of the surface.
    """

    def __init__(self, world: World, name: str, back_end: Vec, front_end: Vec,
                 top_z: float, width: float = 0.06, base_z: float | None = None, stop_margin: float = 0.0145):
        self.world, self.name = world, name
        self.back_end = np.array(back_end[:2], dtype=float)
        self.front_end = np.array(front_end[:2], dtype=float)
        self.length = float(np.linalg.norm(self.front_end - self.back_end))
        self.axis = (self.front_end - self.back_end) / self.length
        self.top_z, self.width, self.stop_margin = top_z, width, stop_margin
        self._direction = 0
        self._speed = DEFAULT_SPEED
        self._lock = threading.Lock()
        self.body, self.end_stops = self._build(base_z if base_z is not None else top_z - 0.038)
        world.add_pre_step(self._carry)
        world.add_activity(lambda: self._direction != 0)  # a running belt keeps a speed-max world busy
        world.add_snapshot_source(self._fill)

    # --- affordances --------------------------------------------------------------------------
    def start_forward(self) -> str:
        with self._lock:
            self._direction = 1
        return STARTED

    def start_backward(self) -> str:
        with self._lock:
            self._direction = -1
        return STARTED

    def stop(self) -> str:
        """Stop; harmless when already stopped."""
        with self._lock:
            self._direction = 0
        return STOPPED

    @property
    def speed(self) -> int:
        return self._speed

    @speed.setter
    def speed(self, value: int) -> None:
        speed = belt_speed(self.name, value)
        with self._lock:
            self._speed = speed

    @property
    def direction(self) -> str:
        """"forward", "backward" or "stopped"."""
        return _DIRECTIONS[self._direction]

    @property
    def velocity(self) -> float:
        """Signed surface speed in m/s (positive = forward)."""
        return self._direction * self._speed / 100.0 * MAX_SPEED_MM_S / 1000.0

    def reset(self) -> None:
        with self._lock:
            self._direction, self._speed = 0, DEFAULT_SPEED

    def along(self, point: Vec) -> float:
        """Distance (m) of a world point from the back end, measured along the belt."""
        return float(np.dot(np.asarray(point[:2]) - self.back_end, self.axis))

    # --- stepping thread ----------------------------------------------------------------------
    def _carry(self, dt: float) -> None:
        c = self.world.client
        v = self.velocity
        seen = set()
        for contact in pb.getContactPoints(bodyA=self.body, physicsClientId=c):
            other = contact[2]
            if other in seen or other in self.world.held:
                continue
            seen.add(other)
            pos, _ = pb.getBasePositionAndOrientation(other, physicsClientId=c)
            u = self.along(pos)
            vu = v
            if (u >= self.length - self.stop_margin and vu > 0) or (u <= self.stop_margin and vu < 0):
                vu = 0.0
            vz = pb.getBaseVelocity(other, physicsClientId=c)[0][2]
            pb.resetBaseVelocity(other, [vu * self.axis[0], vu * self.axis[1], vz], [0, 0, 0],
                                 physicsClientId=c)

    def _fill(self, snap: Snapshot) -> None:
        snap.states[self.name] = {"direction": self.direction, "speed": self._speed,
                                  "velocity": round(self.velocity * 1000.0, 3)}

    # --- the body -----------------------------------------------------------------------------
    def _build(self, base_z: float) -> tuple[int, list[int]]:
        """Frame with a frictionless top, and an end stop plate at each end."""
        c = self.world.client
        yaw = math.atan2(self.axis[1], self.axis[0])
        orn = pb.getQuaternionFromEuler([0, 0, yaw])
        mid = (self.back_end + self.front_end) / 2
        half = [self.length / 2, self.width / 2 + 0.01, (self.top_z - base_z) / 2]
        body = static_box(c, half, [mid[0], mid[1], base_z + half[2]], orn, (0.12, 0.12, 0.13, 1))
        pb.changeDynamics(body, -1, lateralFriction=0.0, physicsClientId=c)
        stops = []
        plate = [0.0025, half[1], 0.014]
        for end, sign in ((self.front_end, 1), (self.back_end, -1)):
            centre = end + sign * (plate[0]) * self.axis
            stops.append(static_box(c, plate, [centre[0], centre[1], self.top_z + plate[2] - 0.004], orn,
                              (0.7, 0.7, 0.72, 1)))
        return body, stops

