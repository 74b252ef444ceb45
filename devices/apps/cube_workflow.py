"""The lab's cube workflow (SPEC §3), by affordance name only, over Zenoh or over WoT HTTP.

`cube_workflow(consumer)` drives the devices as `mesh.Consumer` Things (`consumer.thing(name)`:
read a property, invoke an action, subscribe to an event, through the TDs' forms), so the same
eight steps run against the mesh (a consumer on a Zenoh session) and against any WoT HTTP Things
(a consumer with a base URL: SSE to wait for events) — the twin's adapter or, unchanged, the
real lab. No sleeps: before a belt starts, the workflow
subscribes to the infrared sensor's `detectedObject`, then reads `objectPresence` (the cube may
already be there) and only then starts the belt; it stops the belt on the first `true`. Should a
notification get lost, the presence is read again every `RECHECK` s of waiting.

`twinmesh workflow cube [--via URL] [--runs N]` prints each step with its duration and the colour
read, and exits non-zero when a step fails.
"""
from __future__ import annotations

import colorsys
import queue
import time
from dataclasses import dataclass, field
from typing import Callable

from mesh import Consumer
from mesh.wot.consumed import Inbox
from mesh.wot.problem import TimedOut

RECHECK = 5.0  # s: read the sensor again if no notification came for this long
SENSOR_TIMEOUT = 120.0  # s of wall time a belt may run before the cube is declared lost

# SPEC §3's points in the real uArm frame (mm)
ABOVE_RIGHT_BELT, AT_RIGHT_BELT = (192, 192, 87), (192, 192, 52)
COLOR_CHECK = (180, 0, 60)
ABOVE_LEFT_BELT, AT_LEFT_BELT = (200, -200, 90), (200, -200, 70)


@dataclass
class Step:
    number: int
    title: str
    seconds: float = 0.0
    detail: str = ""


@dataclass
class CubeRun:
    steps: list[Step] = field(default_factory=list)
    color: list[int] | None = None
    seconds: float = 0.0

    @property
    def color_name(self) -> str:
        return color_name(self.color) if self.color is not None else "?"


class StepFailed(Exception):
    def __init__(self, step: Step, cause: BaseException):
        super().__init__(f"step {step.number} ({step.title}) failed: {cause}")
        self.step, self.cause = step, cause


def cube_workflow(c: Consumer, on_step: Callable[[Step], None] = lambda s: None,
                  sensor_timeout: float = SENSOR_TIMEOUT) -> CubeRun:
    """SPEC §3's eight steps; `on_step` hears of each finished step. Raises StepFailed."""
    run = CubeRun()
    started = time.perf_counter()

    def step(title: str, body: Callable[[], str | None]) -> None:
        s = Step(len(run.steps) + 1, title)
        t0 = time.perf_counter()
        try:
            s.detail = body() or ""
        except Exception as e:
            s.seconds = time.perf_counter() - t0
            raise StepFailed(s, e) from e
        s.seconds = time.perf_counter() - t0
        run.steps.append(s)
        on_step(s)

    uarm, dobot = c.thing("uarm"), c.thing("dobot")

    def go(x: int, y: int, z: int) -> None:
        uarm.invoke_action("goTo", {"x": x, "y": y, "z": z})

    def pick() -> None:
        uarm.invoke_action("gripOpen")
        go(*ABOVE_RIGHT_BELT)
        go(*AT_RIGHT_BELT)
        uarm.invoke_action("gripClose")
        go(*ABOVE_RIGHT_BELT)

    def read_color() -> str:
        run.color = [round(v) for v in c.thing("color-sensor").read_property("color")]
        return f"color {run.color} ({color_name(run.color)})"

    def put() -> None:
        go(*ABOVE_LEFT_BELT)
        go(*AT_LEFT_BELT)
        uarm.invoke_action("gripOpen")
        go(*ABOVE_LEFT_BELT)

    step("dobot getCube: a cube onto conveyor belt 2", lambda: dobot.invoke_action("getCube"))
    step("conveyor belt 2 forward until infrared sensor 2 sees the cube",
         lambda: belt_until_seen(c, "conveyor-belt-2", "startBeltForward", "infrared-sensor-2", sensor_timeout))
    step("uarm picks the cube up", pick)
    step("uarm carries it over the colour sensor", lambda: go(*COLOR_CHECK))
    step("colour sensor reads the cube", read_color)
    step("uarm puts it on conveyor belt 1", put)
    step("conveyor belt 1 backward until infrared sensor 1 sees the cube",
         lambda: belt_until_seen(c, "conveyor-belt-1", "startBeltBackward", "infrared-sensor-1", sensor_timeout))
    step("dobot returnCube: the cube back into the warehouse", lambda: dobot.invoke_action("returnCube"))
    run.seconds = time.perf_counter() - started
    return run


def belt_until_seen(c: Consumer, belt: str, start: str, sensor: str, timeout: float = SENSOR_TIMEOUT) -> str:
    """Subscribe, check presence, start the belt, wait for the sensor, stop the belt (always)."""
    the_belt, the_sensor = c.thing(belt), c.thing(sensor)
    events = Inbox()
    subscription = the_sensor.subscribe_event("detectedObject", events)
    try:
        if the_sensor.read_property("objectPresence") is True:
            the_belt.invoke_action("stopBelt")
            return "the cube was already there"
        try:
            the_belt.invoke_action(start)
            wait_for_presence(c, events, sensor, timeout)
        finally:
            the_belt.invoke_action("stopBelt")
    finally:
        subscription.stop()
    return ""


def wait_for_presence(c: Consumer, events: Inbox, sensor: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        try:
            if events.get(min(RECHECK, left)) is True:
                return
        except queue.Empty:
            if c.thing(sensor).read_property("objectPresence") is True:  # a lost notification must not hang it
                return
    raise TimedOut(f"{sensor} saw no object within {timeout:g} s")


def color_name(rgb: list[int] | tuple[int, ...]) -> str:
    """A plain name for an RGB 0..255 reading: black/grey/white, else the nearest of six hues."""
    r, g, b = (min(max(v / 255.0, 0.0), 1.0) for v in rgb)
    h, s, v = colorsys.rgb_to_hsv(r, g, b)
    if v < 0.15:
        return "black"
    if s < 0.25:
        return "white" if v > 0.85 else "grey"
    hues = ["red", "yellow", "green", "cyan", "blue", "magenta"]
    return hues[round(h * 6) % 6]
