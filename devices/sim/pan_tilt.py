"""A pan-tilt unit (`pan-tilt-1`, `-2` on the iot-lab's top table) whose camera is a colour sensor.

The unit is `models/pan-tilt.urdf` moved kinematically, like the arms (`KinematicArm`: joints set,
links out of collision, so rays and cubes pass through it). Angles at this surface are in degrees:
pan about the base's z within ±90 (positive pans LEFT, counter-clockwise seen from above, as the
reference TD says), tilt about the head's y within ±80 (positive tilts DOWN: the look axis turns
towards the floor). At zero the camera looks along the base's +x, level, 9 cm above the mounting
surface (the tilt axis), 4 cm in front of the tilt axis (the URDF link `camera`).

Moves (`move_to`, `pan_to`, `tilt_to`, `go_home`) interpolate both joints together (smoothstep,
peak 60 deg/s) and return when the motion is over; an angle out of range is refused (BadInput)
before anything moves. `pan_continuously(speed)` (|speed| <= 15 deg/s, positive = left) returns
at once; the pan runs until `stop_movement()`, a move, or the limit, where it stops exactly at
±90. One motion at a time: a lock, like the other devices.

The colour sensor stands in for the camera, since the twin renders nothing: every 50 ms of
simulated time a ray from the lens along the look axis (5 m: the lab's far wall is 4.5 m away)
finds the first body it meets and reports its visual colour as 0..255 RGB (as the platform's
colour sensor does), the body's name and its distance. Nothing within reach: the dark room,
`[0, 0, 0]`, no object, no distance. `on_color` listeners hear each change (of the colour or of
the body seen), on the world's notifier thread.
"""
from __future__ import annotations

import math
import threading
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any, Callable, Mapping

import numpy as np
import pybullet as pb

from devices.sim.compensation import KinematicArm
from devices.sim.pybullet_world import PEAK_SPEED, Interpolation, MotionCancelled, Snapshot, World
from devices.sim.sensors import reading_of
from devices.sim.vec import Vec
from mesh.wot.problem import BadInput
from tdgen.robot.model import ROBOTS_DIR

PAN_TILT_URDF = ROBOTS_DIR / "pan-tilt.urdf"
JOINTS = ("pan", "tilt")              # the URDF's joint names, also the snapshot's
CAMERA_LINK = "camera"                # its +x is the look axis
LIMITS_DEG = {"pan": 90.0, "tilt": 80.0}
SPEED_DEG_S = 60.0                    # peak joint speed of a move
MAX_PAN_SPEED = 15.0                  # deg/s, panContinuously
SENSE_PERIOD = 0.05                   # s of simulated time between two looks (20 Hz)
REACH = 5.0                           # m
RAY_MASK = -1                         # static bodies too; robot links are in no group, rays pass them

Names = Callable[[], Mapping[int, str]] | Mapping[int, str]


@dataclass(frozen=True)
class ColorSeen:
    """What the camera's colour sensor sees: colour (r, g, b 0..255), the body's name, its distance (m)."""

    color: list[int] = field(default_factory=lambda: [0, 0, 0])
    object: str | None = None
    distance: float | None = None

    def same_as(self, other: "ColorSeen") -> bool:
        """Same colour and same body (a distance change alone is no change)."""
        return self.color == other.color and self.object == other.object

    def to_json(self) -> dict[str, Any]:
        """The `detectColor` event's data: `object` is "" when nothing is seen, `distance` left out."""
        out: dict[str, Any] = {"color": list(self.color), "object": self.object or ""}
        if self.distance is not None:
            out["distance"] = self.distance
        return out


NOTHING = ColorSeen()


class _ContinuousPan:
    """Pans at `speed` deg/s until stopped or at the limit (a Motion of the world)."""

    def __init__(self, unit: "PanTilt", speed: float):
        self.unit, self.speed, self.stopped = unit, speed, False

    def advance(self, dt: float) -> bool:
        if self.stopped:
            return True
        pan, tilt = self.unit.degrees()
        limit = LIMITS_DEG["pan"]
        goal = min(max(pan + self.speed * dt, -limit), limit)
        self.unit._apply(np.array([goal, tilt]))
        return goal == (limit if self.speed > 0 else -limit)


class PanTilt:
    """One pan-tilt unit in a World (scene frame position of the base's bottom, m; yaw about z, deg).

    `names`: pybullet body id -> name for what the camera sees (a mapping, or a function returning
    one, called on the stepping thread); bodies not in it go by their pybullet body name (a URDF's robot
    name), else `body-<id>`.
    Thread-safe: one motion at a time; reads never wait for a motion.
    """

    def __init__(self, world: World, name: str, position: Vec, yaw_deg: float = 0.0,
                 names: Names | None = None):
        self.world, self.name = world, name
        self._names = names
        self.lock = threading.RLock()
        half = math.radians(yaw_deg) / 2
        orn = (0.0, 0.0, math.sin(half), math.cos(half))

        def load() -> KinematicArm:
            arm = KinematicArm(world.client, str(PAN_TILT_URDF), position, orn, JOINTS, world=world)
            arm.apply(np.zeros(len(JOINTS)))  # held at home from the first step
            return arm
        self.arm: KinematicArm = world.run(load)  # before start() this runs here, after on the stepping thread
        self.body = self.arm.body
        self._camera = self.arm.link_index[CAMERA_LINK]
        self._pan: tuple[_ContinuousPan, Future] | None = None  # the continuous pan under way
        self._pan_lock = threading.Lock()  # its end (stepping thread) vs. a new one (caller)
        self._seen = NOTHING
        self._since = SENSE_PERIOD  # look at the first step
        self._listeners: list[Callable[[ColorSeen], None]] = []
        self._move_listeners: list[Callable[[], None]] = []
        self._listeners_lock = threading.Lock()
        world.add_post_step(self._sense)
        world.add_snapshot_source(self._fill)

    # --- state (any thread) ---------------------------------------------------------------------
    def degrees(self) -> tuple[float, float]:
        """(pan, tilt) in degrees now, unrounded."""
        pan, tilt = np.degrees(self.arm.q)  # `q` is replaced, never mutated
        return float(pan), float(tilt)

    def angles(self) -> tuple[float, float]:
        """(pan, tilt) in degrees now, to 1e-6 deg (what the Thing reports)."""
        pan, tilt = self.degrees()
        return round(pan, 6) + 0.0, round(tilt, 6) + 0.0  # + 0.0: no -0.0

    @property
    def pan(self) -> float:
        return self.angles()[0]

    @property
    def tilt(self) -> float:
        return self.angles()[1]

    @property
    def panning(self) -> float:
        """The continuous pan's speed (deg/s), 0 when none runs."""
        pan = self._pan
        return pan[0].speed if pan is not None else 0.0

    def color(self) -> ColorSeen:
        """What the camera sees now (a fresh look)."""
        return self.world.run(self._look)

    def on_color(self, listener: Callable[[ColorSeen], None]) -> Callable[[], None]:
        """`listener(seen)` at each change of what the camera sees (notifier thread); returns an unsubscribe."""
        return self._subscribe(self._listeners, listener)

    def on_move(self, listener: Callable[[], None]) -> Callable[[], None]:
        """`listener()` after each change of the angles, on the stepping thread (keep it tiny: set a flag);
        returns an unsubscribe."""
        return self._subscribe(self._move_listeners, listener)

    def _subscribe(self, listeners: list, listener: Callable) -> Callable[[], None]:
        with self._listeners_lock:
            listeners.append(listener)

        def unsubscribe() -> None:
            with self._listeners_lock:
                if listener in listeners:
                    listeners.remove(listener)
        return unsubscribe

    # --- moves ----------------------------------------------------------------------------------
    def move_to(self, pan: float, tilt: float) -> None:
        """Both joints to (pan, tilt) deg; returns when there. Out of range: BadInput, nothing moves."""
        self._move({"pan": pan, "tilt": tilt})

    def pan_to(self, pan: float) -> None:
        """Pan to `pan` deg, the tilt stays."""
        self._move({"pan": pan})

    def tilt_to(self, tilt: float) -> None:
        """Tilt to `tilt` deg, the pan stays."""
        self._move({"tilt": tilt})

    def go_home(self) -> None:
        self._move({"pan": 0.0, "tilt": 0.0})

    def pan_continuously(self, speed: float) -> None:
        """Start panning at `speed` deg/s (positive: left) and return; replaces a pan under way.

        A speed of 0 stops a pan under way. |speed| > 15: BadInput.
        """
        speed = _number(speed, f"{self.name}: the pan speed")
        if not -MAX_PAN_SPEED <= speed <= MAX_PAN_SPEED:
            raise BadInput(f"{self.name}: the pan speed must be within -{MAX_PAN_SPEED:g}..{MAX_PAN_SPEED:g} "
                           f"deg/s, got {speed:g}")
        with self.lock:
            self.stop_movement()
            if speed == 0:
                return
            motion = _ContinuousPan(self, speed)
            done = self.world.play(motion)
            with self._pan_lock:
                self._pan = (motion, done)
            done.add_done_callback(lambda _: self._ended(motion))  # at once if it is over already

    def stop_movement(self) -> None:
        """Stop a continuous pan where it is (no-op without one); returns once it stands still."""
        pan = self._pan
        if pan is None:
            return
        motion, done = pan
        motion.stopped = True
        try:
            done.result()  # the motion has seen the flag: the pan stands still
        except MotionCancelled:
            pass
        self._ended(motion)

    def reset(self) -> None:
        """Home at once, no pan (a scene reset; the world cancels the motions under way first)."""
        with self.lock:
            with self._pan_lock:  # never held while waiting on the stepping thread: it takes it too
                pan, self._pan = self._pan, None
            if pan is not None:
                pan[0].stopped = True
            self.world.run(self._home_now)

    def _move(self, targets: dict[str, float]) -> None:
        goal_of: dict[str, float] = {}
        for axis, value in targets.items():
            v = _number(value, f"{self.name}: the {axis} angle")
            limit = LIMITS_DEG[axis]
            if not -limit <= v <= limit:
                raise BadInput(f"{self.name}: the {axis} angle must be within -{limit:g}..{limit:g} deg, "
                               f"got {v:g}")
            goal_of[axis] = v
        with self.lock:
            self.stop_movement()
            start = np.array(self.degrees())
            goal = np.array([goal_of.get(axis, start[i]) for i, axis in enumerate(JOINTS)])
            duration = PEAK_SPEED * float(np.max(np.abs(goal - start))) / SPEED_DEG_S
            if duration > 0:
                self.world.play(Interpolation(lambda: np.array(self.degrees()), goal, duration,
                                              self._apply)).result()
            self.world.run(self._refresh)  # what the camera sees now, heard before the reply

    def _ended(self, motion: _ContinuousPan) -> None:
        with self._pan_lock:
            if self._pan is not None and self._pan[0] is motion:
                self._pan = None

    # --- stepping thread ------------------------------------------------------------------------
    def _apply(self, angles_deg: np.ndarray) -> None:
        self.arm.apply(np.radians(angles_deg))
        for listener in list(self._move_listeners):
            listener()

    def _home_now(self) -> None:
        self._apply(np.zeros(len(JOINTS)))
        self._refresh()

    def _look(self) -> ColorSeen:
        c = self.world.client
        pos, orn = pb.getLinkState(self.body, self._camera, computeForwardKinematics=True, physicsClientId=c)[4:6]
        axis = np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)[:, 0]
        end = np.asarray(pos) + REACH * axis
        body, link, fraction = pb.rayTest(list(pos), end.tolist(), collisionFilterMask=RAY_MASK,
                                          physicsClientId=c)[0][:3]
        if body < 0:
            return NOTHING
        shapes = pb.getVisualShapeData(body, physicsClientId=c)  # not cached: a lamp's shade changes colour
        rgba = next((s[7] for s in shapes if s[1] == link), shapes[0][7] if shapes else None)
        if rgba is None:
            return NOTHING
        return ColorSeen(reading_of(rgba[:3]).color, self._name_of(body), round(fraction * REACH, 4))

    def _name_of(self, body: int) -> str:
        names = self._names() if callable(self._names) else self._names
        if names and body in names:
            return names[body]
        return pb.getBodyInfo(body, physicsClientId=self.world.client)[1].decode() or f"body-{body}"

    def _refresh(self) -> None:
        """Look now; tell the listeners if what is seen changed."""
        seen = self._look()
        if not seen.same_as(self._seen):
            with self._listeners_lock:
                listeners = list(self._listeners)
            for listener in listeners:
                self.world.notify(listener, seen)
        self._seen = seen

    def _sense(self, dt: float) -> None:
        self._since += dt
        if self._since + 1e-9 < SENSE_PERIOD:
            return
        self._since = 0.0
        self._refresh()

    def _fill(self, snap: Snapshot) -> None:
        snap.joints[self.name] = self.arm.joint_values()
        pan, tilt = self.angles()
        seen = self._seen
        snap.states[self.name] = {"pan": pan, "tilt": tilt, "color": list(seen.color), "object": seen.object,
                                  "panning": self.panning}


def _number(value: Any, what: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise BadInput(f"{what} must be a number, got {value!r}")
    return float(value)
