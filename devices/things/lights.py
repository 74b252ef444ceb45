"""The lab's two lights (`light-left`, `light-right`): the first Things on the mesh.

Affordances follow the thesis's virtual light TD (lightState, lightColor, both observable) plus
switchOn / switchOff / setColor actions and a `stateChanged` event.
"""
from __future__ import annotations

from typing import Callable

from devices.things.binding import Cleanup, nothing_to_undo
from mesh.fabric.server import ExposedThing
from mesh.wot import units
from mesh.wot.thing_description import ThingDescription, decode_td, thing_id

LIGHTS = ("light-left", "light-right")

_CHANNEL = {"type": "number", "minimum": 0, "maximum": 1, "unit": units.UNITLESS}
_COLOR = {"type": "array", "items": _CHANNEL, "minItems": 3, "maxItems": 3}


def light_td(name: str, description: str | None = None) -> ThingDescription:
    side = name.removeprefix("light-")
    return decode_td({
        "title": name,
        "id": thing_id(name),
        "description": description or f"Virtual light on the {side} of the lab's top table (twinmesh twin).",
        "properties": {
            "lightState": {"title": "Light state", "description": "On (true) or off (false).",
                           "type": "boolean", "observable": True, "readOnly": False, "writeOnly": False},
            "lightColor": {"title": "Light colour", "description": "RGB, each 0..1.", **_COLOR,
                           "observable": True, "readOnly": False, "writeOnly": False},
        },
        "actions": {
            "switchOn": {"title": "Switch on", "safe": False, "idempotent": True, "synchronous": True},
            "switchOff": {"title": "Switch off", "safe": False, "idempotent": True, "synchronous": True},
            "setColor": {
                "title": "Set colour", "safe": False, "idempotent": True, "synchronous": True,
                "input": {"type": "object", "required": ["r", "g", "b"], "properties": {
                    c: _CHANNEL for c in "rgb"}},
                "output": {"title": "The new colour", **_COLOR},
            },
        },
        "events": {
            "stateChanged": {"title": "State changed", "description": "Emitted when the light goes on or off.",
                             "data": {"type": "boolean"}},
        },
    })


def bind_light(thing: ExposedThing, show: Callable[[bool, list[float]], None] | None = None) -> Cleanup:
    """A light's behaviour on `thing` (its TD is `light_td`'s): state-backed properties, actions, an event.
    `show(state, color)` after every change (the iot-lab's lamp shows it in the world)."""
    def changed() -> None:
        if show is not None:
            show(thing.value("lightState"), thing.value("lightColor"))

    def set_state(on: bool) -> None:
        if thing.set_value("lightState", on):
            thing.emit_event("stateChanged", on)
            changed()

    def set_color(rgb: dict) -> list[float]:
        color = [float(rgb[c]) for c in "rgb"]
        if thing.set_value("lightColor", color):
            changed()
        return color

    thing.state("lightState", False).state("lightColor", [1.0, 1.0, 1.0])
    thing.on_write("lightState", set_state)
    thing.on_write("lightColor", lambda rgb: set_color(dict(zip("rgb", rgb))))
    thing.on_action("switchOn", lambda _: set_state(True))
    thing.on_action("switchOff", lambda _: set_state(False))
    thing.on_action("setColor", set_color)
    return nothing_to_undo
