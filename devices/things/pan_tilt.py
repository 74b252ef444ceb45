"""A `PanTilt` as a Thing: the reference pan-tilt TD (`tds/pan-tilt.json`) plus the `detectColor` event.

Same property and action names and input schemas as the reference; the twin's deviations, each said
in the TD's description: the moves are `synchronous` (they answer when the motion is over) while
`panContinuously` answers as soon as the pan has started; panPosition and tiltPosition are
observable (published while moving, at most 20 times per wall second, and with the final value
before a move's reply), which costs a client that only reads nothing; and the colour sensor that
stands in for the camera emits `detectColor` whenever what it sees changes.
"""
from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Callable

from devices.sim.pan_tilt import MAX_PAN_SPEED, REACH, ColorSeen, PanTilt
from devices.things.binding import Cleanup
from mesh.fabric.server import ExposedThing
from mesh.fabric.state_publisher import StatePublisher
from mesh.wot import units
from mesh.wot.thing_description import ThingDescription, decode_td, thing_id

TD = Path(__file__).parent / "tds" / "pan-tilt.json"
MOVES = ("moveTo", "panTo", "tiltTo", "goHome", "stopMovement")  # answer when the motion is over
POSITIONS = ("panPosition", "tiltPosition")

DETECT_COLOR: dict[str, Any] = {
    "title": "Detect Color",
    "description": f"What the colour sensor on the tilt head (standing in for the camera) sees, at each change "
                   f"of the colour or of the body seen: color (R, G, B 0..255, like the lab's colour sensor's "
                   f"`color`; [0, 0, 0] when nothing is within {REACH:g} m), object (the name of the body seen, "
                   f"\"\" for nothing) and distance (m, left out when nothing is seen).",
    "data": {"type": "object", "required": ["color", "object"], "properties": {
        "color": {"type": "array", "minItems": 3, "maxItems": 3,
                  "items": {"type": "number", "minimum": 0, "maximum": 255, "unit": units.UNITLESS}},
        "object": {"type": "string", "description": "The body seen; \"\" when nothing is seen"},
        "distance": {"type": "number", "minimum": 0, "maximum": REACH, "unit": units.METRE}}},
}


def pan_tilt_td(name: str) -> ThingDescription:
    """The TD `name` (pan-tilt-1, pan-tilt-2) serves on the mesh."""
    td = json.loads(TD.read_text())
    td.update(title=name, id=thing_id(name), description=(
        f"{name}: the twinmesh twin of the lab's pan-tilt unit (reference: {td.get('description', 'pan-tilt')}). "
        "Positive pan turns left, positive tilt looks down. A colour sensor on the tilt head stands in for the "
        "camera: detectColor says what it sees (twin addition). Twin: moveTo, panTo, tiltTo, goHome and "
        "stopMovement are synchronous (they answer when the motion is over); panContinuously answers as soon "
        f"as the pan has started (|speed| <= {MAX_PAN_SPEED:g} deg/s), which runs until stopMovement, another "
        "move or the limit. panPosition and tiltPosition are observable here (the reference says not): the "
        "twin publishes their changes while moving, which costs a client that only reads them nothing."))
    for prop in POSITIONS:
        td["properties"][prop]["observable"] = True
    for action in MOVES:
        td["actions"][action]["synchronous"] = True
    td["actions"]["panContinuously"]["synchronous"] = False
    td["events"] = {"detectColor": DETECT_COLOR}
    return decode_td(td)


def bind_pan_tilt(thing: ExposedThing, unit: PanTilt) -> Cleanup:
    """The unit's behaviour on `thing` (its TD is `pan_tilt_td`'s); the cleanup stops its publishing."""
    publisher = StatePublisher(thing, lambda: dict(zip(POSITIONS, unit.angles())))

    def moving(fn: Callable[[Any], None]) -> Callable[[Any], None]:
        def handler(value: Any) -> None:
            try:
                fn(value)
            finally:
                publisher.flush()  # the final angles go out before the reply
        return handler

    def detected(seen: ColorSeen) -> None:  # the world's notifier thread, in order
        thing.emit_event("detectColor", seen.to_json())

    thing.on_read("panPosition", lambda: unit.pan).on_read("tiltPosition", lambda: unit.tilt)
    thing.on_action("moveTo", moving(lambda v: unit.move_to(v["panAngle"], v["tiltAngle"])))
    thing.on_action("panTo", moving(unit.pan_to))
    thing.on_action("tiltTo", moving(unit.tilt_to))
    thing.on_action("goHome", moving(lambda _: unit.go_home()))
    thing.on_action("panContinuously", unit.pan_continuously)
    thing.on_action("stopMovement", moving(lambda _: unit.stop_movement()))
    unsubscribe = [unit.on_move(publisher.changed), unit.on_color(detected)]
    publisher.start()

    def cleanup() -> None:
        for undo in unsubscribe:
            undo()
        publisher.close()

    return cleanup
