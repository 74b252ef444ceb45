"""The twin in front of the real device (`twinmesh up ... --real uarm=URL`): the twin is the only way to it.

Every action asked of the twin is first checked on the twin (what the twin would refuse, it refuses
as always, 422 with the reason, and nothing is sent); an accepted one is sent to the real device
through its own TD's forms, in its frame and units (a calibration, identity when none; the real
uArm wants integer mm, so coordinates are rounded, at most 0.5 mm); only once the real device has
answered does the twin do the same, so that it shows what the real one did. The real device not
answering is 503 at once and the twin does not move; once it answers again, so does the guard. An
action the real device has and the twin does not (the uArm's beep) is only forwarded; one the twin
has and the real device lacks runs on the twin alone. Written properties (a belt's speed, the
uArm's homeLoc) go the same way: checked by the twin's schema, written to the real device, then kept.

The mirror: the twin follows what the real device reports. The uArm twin's arm stands where the real
arm says it is (its `location`, read every `MIRROR_EVERY` s while no guarded move runs), so its
checks start from there; values outside the real TD's own goTo box (after a homeLoc) are kept.
Everything else of the twin stays simulated: its sensors see the simulated cubes.
"""
from __future__ import annotations

import logging
import threading
from dataclasses import dataclass
from functools import partial
from typing import Any, Callable

import numpy as np

from devices.sim.dobot import Dobot
from devices.sim.uarm import Uarm
from mesh.bridge.remote import RemoteThing
from mesh.fabric.server import ExposedThing
from mesh.wot.consumed import NOTHING
from mesh.wot.problem import BadInput, Problem, Refused
from mesh.wot.validate import validate

log = logging.getLogger(__name__)

MIRROR_EVERY = 0.5   # s between reads of the real arm's position
MIRROR_TOLERANCE = 2.0  # mm: closer than this, the twin is where the real arm is
Check = Callable[[Any], object]  # raises the refusal; what it returns is ignored
ToReal = Callable[[Any], Any]


@dataclass(frozen=True)
class RealDevice:
    """A real device the twin `slug` guards, as `up` took it in: its TD's URL and the TD itself."""

    slug: str
    url: str
    td: dict[str, Any]
    calibration: str | None = None  # a CSV of twin/real pairs (tdgen/robot/calibration.py), None: identity


class Frame:
    """Twin real-frame mm to the real device's mm and back, through a calibration (identity when none)."""

    def __init__(self, calibration: str | None):
        self._a, self._t = np.eye(3), np.zeros(3)
        if calibration is not None:
            from tdgen.robot.calibration import load_calibration

            fitted = load_calibration(calibration)
            m = np.array(fitted.fit(fitted.used).matrix)
            self._a, self._t = m[:, :3], m[:, 3]
        self._a_inv = np.linalg.inv(self._a)

    def to_real(self, p: Any) -> np.ndarray:
        return np.asarray(p, dtype=float) @ self._a.T + self._t

    def to_twin(self, p: Any) -> np.ndarray:
        return (np.asarray(p, dtype=float) - self._t) @ self._a_inv.T


class Guard:
    """Puts the real device behind the twin's handlers (install before `expose()`)."""

    def __init__(self, thing: ExposedThing, remote: RemoteThing, checks: dict[str, Check],
                 to_real: dict[str, ToReal] | None = None):
        self.thing, self.remote, self.checks = thing, remote, checks
        self.to_real = to_real or {}
        self.busy = threading.Lock()  # held while a guarded action runs: the mirror waits

    def install(self, twin_actions: set[str]) -> None:
        for action, a in self.thing.td.actions.items():
            forwarded = self.remote.can("actions", action, "invokeaction")
            takes_input = a.input is not None
            if action not in twin_actions:
                self.thing.on_action(action, self._forward_only(action, takes_input))
            elif forwarded:
                self.thing.wrap_action(action, partial(self._guarded, action, takes_input))
        for prop, p in self.thing.td.properties.items():
            if not p.readOnly and self.remote.can("properties", prop, "writeproperty"):
                self.thing.wrap_write(prop, partial(self._guarded_write, prop))

    def _forward_only(self, action: str, takes_input: bool) -> Callable[[Any], Any]:
        def forward(value: Any) -> Any:
            return self.remote.invoke(action, value if takes_input else NOTHING)
        return forward

    def _guarded(self, action: str, takes_input: bool, own: Callable[[Any], Any]) -> Callable[[Any], Any]:
        check = self.checks.get(action)
        convert = self.to_real.get(action, lambda v: v)

        schema = self.remote.td.actions[action].input

        def guarded(value: Any) -> Any:
            with self.busy:
                if check is not None:
                    check(value)  # the twin's refusal (422), before anything leaves
                real_input = convert(value) if takes_input else NOTHING
                if schema is not None and real_input is not NOTHING:
                    self._fits_the_real_device(action, value, real_input, schema)
                self.remote.invoke(action, real_input)  # 503 when it is down
                return own(value)  # the twin does what the real device did
        return guarded

    def _fits_the_real_device(self, action: str, value: Any, real_input: Any, schema: Any) -> None:
        """A valid input whose calibrated form the real device's TD refuses is a refusal (422), not a bad input."""
        try:
            validate(real_input, schema, path="input")
        except BadInput as e:
            raise Refused(f"{action} {value}: in the real device's frame this is {real_input}, which its TD "
                          f"refuses ({e.detail})", reason="outside-real-range") from None

    def _guarded_write(self, prop: str, own: Callable[[Any], object]) -> Callable[[Any], object]:
        def write(value: Any) -> object:
            with self.busy:
                self.remote.write(prop, value)
                return own(value)
        return write


def uarm_guard(thing: ExposedThing, remote: RemoteThing, uarm: Uarm, frame: Frame) -> Guard:
    """The uArm's checks (the goTo box, the reach, the speed, the turns' range) and its moves in the real
    frame, rounded to the real TD's integer mm."""
    def go_to(v: dict) -> None:
        uarm.check_go_to(v["x"], v["y"], v["z"])

    def go(v: dict) -> None:
        uarm.check_go_to(v["x"], v["y"], v["z"], speed=v["speed"])

    def real_point(v: dict) -> dict:
        x, y, z = frame.to_real([v["x"], v["y"], v["z"]])
        return {**v, "x": round(float(x)), "y": round(float(y)), "z": round(float(z))}

    checks: dict[str, Check] = {"goTo": go_to, "go": go, "turnLeft": lambda _: uarm.check_turn(+10),
                                "turnRight": lambda _: uarm.check_turn(-10)}
    return Guard(thing, remote, checks, {"goTo": real_point, "go": real_point})


def dobot_guard(thing: ExposedThing, remote: RemoteThing, dobot: Dobot) -> Guard:
    return Guard(thing, remote, {"getCube": lambda _: dobot.check_get_cube(),
                                 "returnCube": lambda _: dobot.check_return_cube()})


def robot_guard(robot: Any, remote: RemoteThing) -> Guard:
    """A robot Thing's moves (`devices.things.robot_thing.RobotThing`) checked and planned on the twin first,
    exactly as `planMove` answers (a refusal is 422 with its reason). Inputs go as they are: they are in
    the robot's TD frame, which is the real robot's when the twin was given its calibration."""
    return Guard(robot.thing, remote, {"moveToJointPosition": lambda v: robot.plan({"joints": v}),
                                       "moveToCartesianPosition": robot.plan, "moveToPose": robot.plan})


class RobotMirror:
    """Keeps a robot twin's joints where the real robot reports them (its `getJointposition`), each time
    that report changes, while no guarded move runs."""

    def __init__(self, twin: Any, remote: RemoteThing, guard: Guard, stopping: threading.Event):
        self.twin, self.remote, self.guard = twin, remote, guard
        self._stopping = stopping
        self._last: Any = None
        self._thread = threading.Thread(target=self._run, name=f"mirror {twin.name}", daemon=True)

    def start(self) -> "RobotMirror":
        self._thread.start()
        return self

    def follow_once(self) -> None:
        try:
            real = self.remote.read("getJointposition")
        except Problem:
            return
        if real == self._last or not self.guard.busy.acquire(blocking=False):
            return
        try:
            self.twin.place_joints(real)
            self._last = real
        except Problem as p:
            log.warning("%s mirror: the twin cannot stand where the real robot says it is: %s", self.twin.name,
                        p.detail or p)
            self._last = real
        finally:
            self.guard.busy.release()

    def _run(self) -> None:
        while not self._stopping.wait(MIRROR_EVERY):
            self.follow_once()


class UarmMirror:
    """Keeps the uArm twin where the real arm reports it is (see the module docstring)."""

    def __init__(self, uarm: Uarm, remote: RemoteThing, guard: Guard, frame: Frame, stopping: threading.Event):
        self.uarm, self.remote, self.guard, self.frame = uarm, remote, guard, frame
        self._stopping = stopping
        self._said: str | None = None
        self._thread = threading.Thread(target=self._run, name="mirror uarm", daemon=True)

    def start(self) -> "UarmMirror":
        self._thread.start()
        return self

    def follow_once(self) -> None:
        try:
            real = self.remote.read("location")
        except Problem as p:
            self._say(f"the real uArm's location cannot be read: {p.detail or p}")
            return
        target = self.frame.to_twin([real["x"], real["y"], real["z"]])
        if float(np.linalg.norm(np.asarray(self.uarm.position_mm) - target)) <= MIRROR_TOLERANCE:
            return
        if not self.guard.busy.acquire(blocking=False):
            return  # a guarded move runs: the twin moves with it
        try:
            self.uarm.place(*(float(v) for v in target))
            self._say(None)
        except Problem as p:
            self._say(f"the twin cannot stand where the real uArm says it is ({real}): {p.detail or p}")
        finally:
            self.guard.busy.release()

    def _say(self, message: str | None) -> None:
        if message != self._said and message is not None:
            log.warning("uarm mirror: %s", message)
        self._said = message

    def _run(self) -> None:
        while not self._stopping.wait(MIRROR_EVERY):
            self.follow_once()
