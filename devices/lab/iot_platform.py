"""Process entry of the iot-platform scene: one pybullet world, each device its own Zenoh peer.

`run(settings, stop, speed)` builds the platform (the world steps in its own thread), then opens
one Zenoh session per device (like `devices/things/lights.py`) and exposes each device's Thing, whose
handlers call the thread-safe behaviour objects directly (a motion blocks its handler until it is
over); one more session serves the `world` Thing (poses, scene, speed, reset). On stop, the world
closes first, so that handlers still waiting on a motion answer (503) before the sessions close.
"""
from __future__ import annotations

import logging
import threading
from contextlib import ExitStack
from typing import TYPE_CHECKING, Sequence

from devices.lab.serving import serve_platform
from devices.sim.layouts.platform_layout import build_platform
from devices.things.world_thing import WorldThing
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings

if TYPE_CHECKING:
    from devices.things.guard import RealDevice
    from mesh.bridge.run import Access

log = logging.getLogger(__name__)


def run(settings: MeshSettings, stop: threading.Event, speed: float | None = 1.0,
        real: Sequence[RealDevice] = (), access: Access | None = None) -> None:
    """Serve the iot-platform's devices and its world until `stop` is set (speed None: as fast as possible);
    the devices in `real` guard their real devices (`devices.things.guard`), reached with `access`."""
    platform = build_platform(speed=speed)
    with ExitStack() as stack:
        stack.callback(platform.close)  # runs last if anything below fails
        serve_platform(stack, settings, platform, list(real), access, stop)
        session = stack.enter_context(open_session(settings, thing="world"))
        stack.enter_context(WorldThing(session, platform, settings.keys))
        stack.callback(platform.close)  # runs first on the way out: pending motions fail, handlers answer
        log.info("iot-platform: %d devices and the world on the mesh (speed %s)", len(platform.devices),
                 "max" if speed is None else f"{speed:g}")
        platform.world.on_death(stop.set)  # a dead simulation ends the process: the supervisor sees it
        stop.wait()
        if not platform.world.stepping:
            raise SystemExit("the simulation stopped stepping; see the log above")
