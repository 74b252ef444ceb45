"""The iot-platform's devices as Things: each behaviour object of `IotPlatform` bound to an ExposedThing.

TDs are the real lab's (`devices/things/tds/<slug>.json`: same affordance names and schemas, forms
stripped, `type` added where it was missing, the uArm without beep/beepWithTime). `twin_td` gives
each its mesh `id` and applies the twin's few deviations, all here and each one said in the TD's
description (the real TD's quirks, decided once):

- every action is `synchronous: true` (SPEC §5): the real Dobot's actions and `stopBelt` say
  `false` ("response is sent as soon as the request is received"), but every twin action answers
  when its motion is over, so a client needs no sleeps;
- IR `objectPresence` is `readOnly: true` (the real TD says writable, yet a reading comes from the
  beam and cannot be set): the twin registers no write, so its TD offers none and a PUT gets 405
  with `Allow` (mesh.fabric.server.ExposedThing._truthful). `detectedObject` fires on every
  change, with the new presence as data (the real TD says "rising edge"; SPEC §3 and the issue
  say every change);
- uArm `location`: the real TD declares the goTo box (x 120..200, y -200..200, z 52..100), but the
  arm can be elsewhere: at a `homeLoc` (x 50..250, y -330..330) and on the way between two points
  (moves are joint-space arcs: (200,-200,90) -> (200,200,90) passes x = 283). node-wot checks every
  value it reads against the schema, so the twin declares the arm's whole reach instead
  (`LOCATION_RANGE`, from the firmware's motor limits); everything else of `location` is the real one;
- uArm `turnRight` takes the real TD's required input `{y}` and ignores its value: one step (10 mm)
  to the right, like `turnLeft` to the left (which returns the new y as its real output says);
- uArm `reset` ("reestablish the connection to correct for loss of location"): a twin neither loses
  its connection nor its location, so it answers at once and moves nothing.

Observable properties publish every change (IR `objectPresence`); written properties (belt
`speed`, uArm `homeLoc`) publish the new value too, for the recorder.
"""
from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any, Callable, Protocol

import msgspec

from devices.sim.belt import Belt
from devices.sim.dobot import Dobot
from devices.sim.sensors import ColorSensor, InfraredSensor
from devices.sim.uarm import Uarm
from devices.things.binding import Cleanup, nothing_to_undo
from devices.things.platform_devices import PLATFORM_DEVICES as PLATFORM_DEVICES  # bound here
from mesh.fabric.keys import Keys
from mesh.fabric.server import ExposedThing
from mesh.wot.thing_description import ThingDescription, decode_td, thing_id

TDS = Path(__file__).parent / "tds"
# the uArm tool point can be anywhere the firmware's motor limits allow (mm, rounded outwards;
# tests/test_platform_tds.py samples the whole joint space against it)
LOCATION_RANGE = {"x": (0, 370), "y": (-370, 370), "z": (-140, 190)}

_NOTES = {
    "synchronous": "Every action answers when it is over (synchronous), also where the real TD says otherwise.",
    "infrared": "Twin: objectPresence is a beam reading, read-only (the real TD says writable). detectedObject fires on "
                "every change of objectPresence (true: an object arrived, false: it left), with the new "
                "value as data.",
    "uarm": "Twin: location is read-only (use goTo; the real TD says writable, but no write moves the arm). "
            "Location ranges are the arm's whole reach (the arm can stand at a homeLoc outside the "
            "goTo box and passes outside it between two points). turnRight ignores its input's y and turns "
            "one step (10 mm) right. reset moves nothing (a twin never loses its location).",
    "dobot": "Twin: one action at a time; further invocations wait for it (not limited to 3).",
}


def _reference(slug: str) -> dict[str, Any]:
    return json.loads((TDS / f"{slug}.json").read_text())


@lru_cache(maxsize=None)
def twin_td_json(slug: str) -> bytes:
    td = _reference(slug)
    td["id"] = thing_id(slug)
    td["title"] = slug
    notes = []
    if td.get("actions"):
        for action in td["actions"].values():
            action["synchronous"] = True
        notes.append(_NOTES["synchronous"])
    if slug.startswith("infrared-sensor"):
        td["properties"]["objectPresence"]["readOnly"] = True  # a beam reading: no write is registered
        notes.append(_NOTES["infrared"])
    elif slug == "uarm":
        for axis, (lo, hi) in LOCATION_RANGE.items():
            td["properties"]["location"]["properties"][axis].update(minimum=lo, maximum=hi)
        td["properties"]["location"]["readOnly"] = True  # where the joints put it: goTo moves it, no write
        notes.append(_NOTES["uarm"])
    elif slug == "dobot":
        notes.append(_NOTES["dobot"])
    td["description"] = " ".join([td.get("description", "").rstrip(". ") + ".", "(twinmesh twin)", *notes])
    return json.dumps(td).encode()


def twin_td(slug: str) -> ThingDescription:
    """The TD a platform device serves on the mesh (see the module docstring for the deviations)."""
    if slug not in PLATFORM_DEVICES:
        raise KeyError(f"no iot-platform device {slug!r}")
    return decode_td(twin_td_json(slug))


def platform_thing(session, slug: str, keys: Keys | None = None,
                   real_td: dict[str, Any] | None = None) -> ExposedThing:
    """The ExposedThing (not exposed yet) of the platform's device `slug`. `real_td`: the real device's
    TD, for a twin that guards it (`devices.things.guard`): its TD also offers the real device's
    actions it lacks (their handlers are the guard's)."""
    if real_td is None:
        return ExposedThing(session, twin_td(slug), slug, keys)
    return ExposedThing(session, with_real_actions(json.loads(twin_td_json(slug)), real_td), slug, keys)


def with_real_actions(td: dict[str, Any], real_td: dict[str, Any]) -> dict[str, Any]:
    """The twin's TD plus the actions the real device has and the twin lacks (forwarded only), as the
    real TD declares them, forms aside."""
    out = dict(td)
    actions = dict(td.get("actions", {}))
    for name, action in real_td.get("actions", {}).items():
        if name not in actions:
            actions[name] = {k: v for k, v in action.items() if k != "forms"}
    out["actions"] = actions
    return out


def bind_device(thing: ExposedThing, device: Belt | InfraredSensor | ColorSensor | Uarm | Dobot) -> Cleanup:
    """The binding of whichever kind of platform device `device` is."""
    if isinstance(device, Belt):
        return bind_belt(thing, device)
    if isinstance(device, InfraredSensor):
        return bind_infrared(thing, device)
    if isinstance(device, ColorSensor):
        return bind_color_sensor(thing, device)
    if isinstance(device, Uarm):
        return bind_uarm(thing, device)
    if isinstance(device, Dobot):
        return bind_dobot(thing, device)
    raise TypeError(f"no binding for {type(device).__name__}")  # pragma: no cover - a new device kind


def _output_const(thing: ExposedThing, action: str) -> Any:
    """What the TD promises an action returns (`const`): node-wot checks it, and the two real belts differ."""
    out = thing.td.actions[action].output
    return None if out is None or out.const is msgspec.UNSET else out.const


class BeltLike(Protocol):
    """What a belt binding needs: the lab's `Belt`, or a fleet station's (`devices.sim.stations`)."""

    speed: int

    def start_forward(self) -> str: ...
    def start_backward(self) -> str: ...
    def stop(self) -> str: ...


class BeamLike(Protocol):
    @property
    def object_presence(self) -> bool: ...
    def on_change(self, callback: Callable[[bool], None]) -> Callable[[], None]: ...


class ColourLike(Protocol):
    @property
    def color(self) -> list[int]: ...
    @property
    def lux(self) -> float: ...
    @property
    def temperature(self) -> float: ...


def bind_belt(thing: ExposedThing, belt: BeltLike) -> Cleanup:
    def act(start: Callable[[], Any], action: str) -> Callable[[Any], Any]:
        const = _output_const(thing, action)

        def handler(_: Any) -> Any:
            said = start()
            return said if const is None else const
        return handler

    def write_speed(value: int) -> None:
        belt.speed = int(value)
        thing.emit_property_change("speed", belt.speed)

    thing.on_read("speed", lambda: belt.speed).on_write("speed", write_speed)
    thing.on_action("startBeltForward", act(belt.start_forward, "startBeltForward"))
    thing.on_action("startBeltBackward", act(belt.start_backward, "startBeltBackward"))
    thing.on_action("stopBelt", act(belt.stop, "stopBelt"))  # harmless when already stopped
    return nothing_to_undo


def bind_infrared(thing: ExposedThing, sensor: BeamLike) -> Cleanup:
    def changed(present: bool) -> None:  # the world's notifier thread, in order
        thing.emit_property_change("objectPresence", present)
        thing.emit_event("detectedObject", present)

    thing.on_read("objectPresence", lambda: sensor.object_presence)
    return sensor.on_change(changed)


def bind_color_sensor(thing: ExposedThing, sensor: ColourLike) -> Cleanup:
    thing.on_read("color", lambda: sensor.color)
    thing.on_read("lux", lambda: sensor.lux)
    thing.on_read("temperature", lambda: sensor.temperature)
    return nothing_to_undo


def bind_uarm(thing: ExposedThing, uarm: Uarm) -> Cleanup:
    def xyz(v: dict) -> tuple[float, float, float]:
        return v["x"], v["y"], v["z"]

    def write_home(value: dict) -> None:
        uarm.home_loc = value  # refuses (422) a home the arm cannot reach
        thing.emit_property_change("homeLoc", uarm.home_loc)

    def moving(act: Callable[[Any], Any]) -> Callable[[Any], Any]:
        """The move, then its new `location` published (the recorder plots it; the real TD offers no
        http observation of it, so it stays unobservable here too)."""
        def moved(v: Any) -> Any:
            try:
                return act(v)
            finally:
                thing.emit_property_change("location", uarm.location)
        return moved

    thing.on_read("location", lambda: uarm.location)
    thing.on_read("homeLoc", lambda: uarm.home_loc).on_write("homeLoc", write_home)
    thing.on_action("goTo", moving(lambda v: uarm.go_to(*xyz(v))))
    thing.on_action("go", moving(lambda v: uarm.go(*xyz(v), speed=v["speed"])))
    thing.on_action("goHome", moving(lambda _: uarm.go_home()))
    thing.on_action("gripOpen", lambda _: uarm.grip_open())
    thing.on_action("gripClose", lambda _: uarm.grip_close())
    thing.on_action("turnLeft", moving(lambda _: uarm.turn_left()))
    thing.on_action("turnRight", moving(lambda _: (uarm.turn_right(), None)[1]))  # no output in the real TD
    thing.on_action("reset", lambda _: None)
    return nothing_to_undo


def bind_dobot(thing: ExposedThing, dobot: Dobot) -> Cleanup:
    thing.on_read("position", lambda: dobot.position)
    thing.on_action("getCube", lambda _: (dobot.get_cube(), None)[1])  # no output in the real TD
    thing.on_action("returnCube", lambda _: (dobot.return_cube(), None)[1])
    thing.on_action("calibrateDevice", lambda _: dobot.calibrate())
    return nothing_to_undo
