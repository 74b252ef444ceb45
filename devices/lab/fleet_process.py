"""The process of a share of the fleet scene's virtual devices, each its own Zenoh peer."""
from __future__ import annotations

import logging
import os
import threading
from contextlib import ExitStack
from typing import Any

from devices.sim.stations import Ticker
from devices.things.binding import serve
from devices.things.fleet import FleetDevice, bind_fleet_device, device_td
from mesh.fabric.server import ExposedThing
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from mesh.process import end_now

log = logging.getLogger(__name__)

# The fleet's devices yield the CPU to the lab's router, a host's gateway and the adapter: thousands of
# devices starting at once kept those from reading their links and sending keep-alives in time (links
# expired, devices reconnected and declared everything again). Raising a process's niceness needs no
# privilege.
NICENESS = 10


def run(settings: MeshSettings, stop: threading.Event, start: int, end: int, first: int = 1) -> None:
    """Process entry: serve the fleet's devices `start`..`end - 1` (stations from `first`) until `stop` is set,
    then end the process at once (`end_now`: its thousands of links close together, not one by one)."""
    os.nice(NICENESS)
    ticker = Ticker()
    stations: dict[int, Any] = {}
    with ExitStack() as stack:
        for index in range(start, end):
            if stop.is_set():
                end_now()
            device = FleetDevice(index, first)
            session = stack.enter_context(open_session(settings, thing=device.name))
            thing = ExposedThing(session, device_td(device), device.name, settings.keys)
            serve(stack, thing, bind_fleet_device(thing, device, ticker, stations))
        stack.callback(ticker.stop)  # first on the way out: no reading is published to a closed Thing
        ticker.start()
        log.info("fleet: devices %s..%s on the mesh", FleetDevice(start, first).name, FleetDevice(end - 1, first).name)
        stop.wait()
        ticker.stop()
        end_now()
