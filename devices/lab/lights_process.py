"""The process of the lights scene: two lamps, each its own Zenoh peer."""
from __future__ import annotations

import threading
from contextlib import ExitStack

from devices.things.binding import serve
from devices.things.lights import LIGHTS, bind_light, light_td
from mesh.fabric.server import ExposedThing
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings


def run(settings: MeshSettings, stop: threading.Event, names: tuple[str, ...] = LIGHTS) -> None:
    """Process entry: serve the lights, each on its own session, until `stop` is set."""
    with ExitStack() as stack:
        for name in names:
            session = stack.enter_context(open_session(settings, thing=name))
            thing = ExposedThing(session, light_td(name), name, settings.keys)
            serve(stack, thing, bind_light(thing))
        stop.wait()
