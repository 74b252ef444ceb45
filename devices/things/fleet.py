"""A fleet of virtual devices for load tests: `twinmesh up fleet --fleet N`.

Devices come in stations of five, `belt-<n>`, `infrared-<n>`, `color-<n>`, `light-<n>` and
`climate-<n>` (station n): the belt, beam and colour sensor are the iot-platform's (their TDs, their
bindings, their events: a running belt's parcels pass the beam, `detectedObject` fires), the light
is the lab's light, and the climate sensor publishes a noisy temperature and humidity every second
(`interval`, writable). Models come from `devices.sim.stations`, without a physics world.

Each device is its own Zenoh session (a client of the host's router) with its own liveliness
token; a process's devices share one ticker thread and the process's query and action workers.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

from devices.things.binding import Cleanup, nothing_to_undo
from mesh.fabric.server import ExposedThing
from mesh.wot import units
from mesh.wot.thing_description import ThingDescription, decode_td, thing_id

KINDS = ("belt", "infrared", "color", "light", "climate")
DEFAULT_FLEET = 100
REFERENCE = {"belt": "conveyor-belt-1", "infrared": "infrared-sensor-1", "color": "color-sensor"}


@dataclass(frozen=True)
class FleetDevice:
    """The `index`-th device of a fleet whose first station is `first`: its kind, station and name."""

    index: int
    first: int = 1

    @property
    def kind(self) -> str:
        return KINDS[self.index % len(KINDS)]

    @property
    def station(self) -> int:
        return self.first + self.index // len(KINDS)

    @property
    def name(self) -> str:
        return f"{self.kind}-{self.station}"


def fleet_names(count: int, first: int = 1) -> list[str]:
    """The names of a fleet of `count` devices, stations numbered from `first`."""
    return [FleetDevice(i, first).name for i in range(count)]


def split(count: int, parts: int) -> list[tuple[int, int]]:
    """Device index ranges [start, end) for `parts` processes, cut between stations (a beam stays with its belt)."""
    stations = -(-count // len(KINDS))
    parts = max(1, min(parts, stations))
    cuts = [round(stations * p / parts) * len(KINDS) for p in range(parts + 1)]
    return [(lo, min(hi, count)) for lo, hi in zip(cuts, cuts[1:]) if lo < min(hi, count)]


@lru_cache(maxsize=None)
def _reference_td(kind: str) -> str:
    from devices.things.platform_things import twin_td_json

    return twin_td_json(REFERENCE[kind]).decode()


_DESCRIPTIONS = {
    "belt": "Conveyor belt of fleet station {n}: while it runs, parcels (30 mm, one every 150 mm) pass "
            "infrared-{n} and color-{n}.",
    "infrared": "Infrared beam at the end of belt-{n} (fleet station {n}): objectPresence is true while a parcel "
                "cuts it.",
    "color": "Colour sensor under the beam of belt-{n} (fleet station {n}): the colour of the parcel at the beam.",
    "light": "Virtual light of fleet station {n}.",
    "climate": "Temperature and relative humidity sensor of fleet station {n}: a reading (with noise) every "
               "`interval` seconds, published to observers.",
}
FLEET_NOTE = "(twinmesh virtual device of a fleet)"


def _description(device: FleetDevice) -> str:
    return f"{_DESCRIPTIONS[device.kind].format(n=device.station)} {FLEET_NOTE}"


def device_td(device: FleetDevice) -> ThingDescription:
    """The TD a fleet device serves: the lab's device's, with its own id, title and description."""
    name, description = device.name, _description(device)
    if device.kind == "light":
        from devices.things.lights import light_td

        return light_td(name, description)
    if device.kind == "climate":
        return climate_td(name, description)
    td = json.loads(_reference_td(device.kind))
    td.update(id=thing_id(name), title=name,
              description=f"{description} As the lab's {REFERENCE[device.kind]}: {td['description']}")
    return decode_td(td)


def climate_td(name: str, description: str) -> ThingDescription:
    return decode_td({
        "title": name, "id": thing_id(name), "description": description,
        "properties": {
            "temperature": {"title": "Temperature", "type": "number", "unit": units.CELSIUS,
                            "minimum": -40, "maximum": 85, "readOnly": True, "writeOnly": False, "observable": True},
            "humidity": {"title": "Relative humidity", "type": "number", "unit": units.PERCENT,
                         "minimum": 0, "maximum": 100, "readOnly": True, "writeOnly": False, "observable": True},
            "interval": {"title": "Reading interval", "description": "Seconds between two published readings.",
                         "type": "number", "unit": units.SECOND, "minimum": 0.1, "maximum": 3600,
                         "readOnly": False, "writeOnly": False, "observable": False},
        },
    })


def bind_fleet_device(thing: ExposedThing, device: FleetDevice, ticker, stations: dict[int, Any]) -> Cleanup:
    """`device`'s behaviour on `thing` (its TD is `device_td`'s). A station's belt, beam and colour sensor
    share one model (`stations`, by station number)."""
    from devices.sim.stations import Station
    from devices.things.platform_things import bind_belt, bind_color_sensor, bind_infrared

    kind, n = device.kind, device.station
    if kind == "light":
        from devices.things.lights import bind_light

        return bind_light(thing)
    if kind == "climate":
        return bind_climate(thing, device, ticker)
    station = stations.get(n)
    if station is None:
        station = stations[n] = Station(f"station-{n}", ticker, offset_mm=n * 37.0)
    if kind == "belt":
        return bind_belt(thing, station.belt)
    if kind == "infrared":
        return bind_infrared(thing, station.infrared)
    return bind_color_sensor(thing, station.color_sensor)


def bind_climate(thing: ExposedThing, device: FleetDevice, ticker) -> Cleanup:
    """A climate sensor on `thing`: a reading every `interval` s, published to observers."""
    from devices.sim.stations import Climate

    def publish(temperature: float, humidity: float) -> None:
        thing.emit_property_change("temperature", temperature)
        thing.emit_property_change("humidity", humidity)

    climate = Climate(device.name, ticker, publish, seed=device.station)

    def write_interval(value: float) -> None:
        climate.interval = value

    thing.on_read("temperature", lambda: climate.temperature).on_read("humidity", lambda: climate.humidity)
    thing.on_read("interval", lambda: climate.interval).on_write("interval", write_interval)
    return nothing_to_undo
