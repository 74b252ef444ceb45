"""The lab's two lights (`light-left`, `light-right`): the first Things on the mesh.

Affordances follow the thesis's virtual light TD (lightState, lightColor, both observable) plus
switchOn / switchOff / setColor actions and a `stateChanged` event.
"""
from __future__ import annotations

import threading
from typing import Callable

from mesh.fabric.keys import Keys
from mesh.wot import units
from mesh.wot.td import ThingDescription, decode_td, thing_id

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


class Light:
    """One light's behaviour on an ExposedThing: state-backed properties plus actions and an event."""

    def __init__(self, session, name: str, keys: Keys,
                 on_change: Callable[[bool, list[float]], None] | None = None, description: str | None = None):
        """`on_change(state, color)` after every change (the iot-lab's lamp shows it in the world)."""
        from mesh.fabric.server import ExposedThing

        self._on_change = on_change
        self.thing = ExposedThing(session, light_td(name, description), name, keys)
        self.thing.state("lightState", False).state("lightColor", [1.0, 1.0, 1.0])
        self.thing.on_write("lightState", self.set_state)
        self.thing.on_write("lightColor", lambda rgb: self.set_color(dict(zip("rgb", rgb))))
        self.thing.on_action("switchOn", lambda _: self.set_state(True))
        self.thing.on_action("switchOff", lambda _: self.set_state(False))
        self.thing.on_action("setColor", self.set_color)

    def set_state(self, on: bool) -> None:
        if self.thing.set_value("lightState", on):
            self.thing.emit_event("stateChanged", on)
            self._changed()

    def set_color(self, rgb: dict) -> list[float]:
        color = [float(rgb[c]) for c in "rgb"]
        if self.thing.set_value("lightColor", color):
            self._changed()
        return color

    def _changed(self) -> None:
        if self._on_change is not None:
            self._on_change(self.thing.value("lightState"), self.thing.value("lightColor"))


def run(settings, stop: threading.Event, names: tuple[str, ...] = LIGHTS) -> None:
    """Process entry: serve the lights, each on its own session, until `stop` is set."""
    from contextlib import ExitStack

    from mesh.fabric.session import open_session

    with ExitStack() as stack:
        for name in names:
            session = stack.enter_context(open_session(settings, thing=name))
            stack.enter_context(Light(session, name, settings.keys).thing)
        stop.wait()
