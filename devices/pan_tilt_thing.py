"""A `PanTilt` as a Thing: the thesis's virtual pan-tilt TD (`tds/pan-tilt.json`) plus the `detectColor` event.

Same affordance names and input schemas as the reference; the twin's deviations, each said in
the TD's description: the moves are `synchronous` (they answer when the motion is over), panPosition
and tiltPosition are observable (published while moving, and once more with the final value before
a move's reply), and the colour sensor that stands in for the camera emits `detectColor` with what
it sees whenever that changes.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Callable

from devices.pan_tilt import PanTilt
from mesh.keys import Keys
from mesh.state_publisher import StatePublisher
from mesh.td import ThingDescription, decode_td, thing_id
from mesh.thing import ExposedThing

TD = Path(__file__).parent / "tds" / "pan-tilt.json"
MOVES = ("moveTo", "panTo", "tiltTo", "goHome", "stopMovement")

DETECT_COLOR = {
    "title": "Colour detected",
    "description": "What the colour sensor on the tilt head (the twin's camera) sees, on each change: the "
                   "colour (R, G, B 0..255; [0, 0, 0] when nothing is within 5 m), the name of the body seen "
                   "and its distance (m), both left out when nothing is seen.",
    "data": {"type": "object", "required": ["color"], "properties": {
        "color": {"type": "array", "minItems": 3, "maxItems": 3,
                  "items": {"type": "number", "minimum": 0, "maximum": 255}},
        "object": {"type": "string"},
        "distance": {"type": "number", "minimum": 0, "unit": "m"}}},
}


def pan_tilt_td(name: str) -> ThingDescription:
    td = json.loads(TD.read_text())
    number = name.rsplit("-", 1)[-1]
    td.update(title=name, id=thing_id(name), description=(
        f"Pan-tilt unit {number} on the lab's top table (twinmesh twin; the thesis's virtual PanTilt {number}). "
        "Positive pan turns left, positive tilt looks down. Twin: moveTo, panTo, tiltTo, goHome and stopMovement "
        "answer when the motion is over; panContinuously answers once the pan has started. panPosition and "
        "tiltPosition are observable here (published while moving). A colour sensor on the tilt head stands "
        "in for the camera: detectColor says what it sees."))
    for prop in ("panPosition", "tiltPosition"):
        td["properties"][prop]["observable"] = True
    for action in MOVES:
        td["actions"][action]["synchronous"] = True
    td["events"] = {"detectColor": DETECT_COLOR}
    return decode_td(td)


def expose_pan_tilt(session, name: str, unit: PanTilt, keys: Keys) -> tuple[ExposedThing, Callable[[], None]]:
    """The unit's Thing (enter it to expose) and a cleanup that stops its publishing."""
    thing = ExposedThing(session, pan_tilt_td(name), name, keys)
    publisher = StatePublisher(thing, lambda: dict(zip(("panPosition", "tiltPosition"), unit.angles())))
    unit.on_move(publisher.changed)

    def moving(fn: Callable[..., None]) -> Callable[..., None]:
        def handler(value=None) -> None:
            try:
                fn(value)
            finally:
                publisher.flush()  # the final angles go out before the reply
        return handler

    thing.on_read("panPosition", lambda: unit.pan).on_read("tiltPosition", lambda: unit.tilt)
    thing.on_action("moveTo", moving(lambda v: unit.move_to(v["panAngle"], v["tiltAngle"])))
    thing.on_action("panTo", moving(unit.pan_to))
    thing.on_action("tiltTo", moving(unit.tilt_to))
    thing.on_action("goHome", moving(lambda _: unit.go_home()))
    thing.on_action("panContinuously", lambda speed: unit.pan_continuously(speed))
    thing.on_action("stopMovement", moving(lambda _: unit.stop_movement()))
    unsubscribe = unit.on_color(lambda seen: thing.emit_event("detectColor", seen.to_json()))
    publisher.start()

    def cleanup() -> None:
        unsubscribe()
        publisher.close()

    return thing, cleanup
