"""Scenes: which processes make up a lab. `twinmesh up SCENE` starts exactly these.

The `fleet` scene has no fixed list: `--fleet N` virtual devices (devices.things.fleet), spread
over as many processes as the machine has cores.
"""
from __future__ import annotations

import os

from devices.lab import entries
from devices.lab.supervisor import ProcessSpec
from mesh.messages.scene_description import DEFAULT_SAMPLES

FLEET = "fleet"

SCENES: dict[str, list[ProcessSpec]] = {
    "lights": [ProcessSpec("lights", entries.lights, role="lights")],
    # one process: the pybullet world and every device of the table, each device its own Zenoh peer
    "iot-platform": [ProcessSpec("iot-platform", entries.iot_platform, {"speed": 1.0},
                                 role="world iot-platform")],
    # a generic robot arm (`twinmesh robot`) on a table beside a wall; its TD comes from the tdgen service
    "ur10": [ProcessSpec("ur10", entries.robot,
                         {"urdf": "ur10.urdf", "name": "ur10", "scene": "table-and-wall", "speed": 1.0,
                          "samples": DEFAULT_SAMPLES}, role="robot ur10")],
    # the whole room: the iot-platform table, the ur10 behind its safety wall, lights and pan-tilts
    "iot-lab": [ProcessSpec("iot-lab", entries.iot_lab, {"speed": 1.0, "samples": DEFAULT_SAMPLES},
                            role="world iot-lab")],
}
DEFAULT_SCENE = "iot-lab"

LIGHTS = ["light-left", "light-right"]
PLATFORM = ["dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2",
            "color-sensor", "uarm", "world"]
# the Things each scene serves (besides the lab's own `tdgen`): `up` is ready when all answer their TD
SCENE_THINGS: dict[str, list[str]] = {
    "lights": LIGHTS,
    "iot-platform": PLATFORM,
    "ur10": ["ur10"],
    "iot-lab": [*PLATFORM, "ur10", *LIGHTS, "pan-tilt-1", "pan-tilt-2"],
}


def scene_things(name: str, fleet: int | None = None, fleet_first: int = 1) -> list[str]:
    """The Things `twinmesh up NAME` serves, in a stable order (`fleet`: the fleet scene's size)."""
    if name == FLEET:
        from devices.things.fleet import DEFAULT_FLEET, fleet_names

        return fleet_names(fleet or DEFAULT_FLEET, fleet_first)
    if name not in SCENES:
        raise KeyError(f"unknown scene {name!r}; known scenes: {', '.join(sorted([*SCENES, FLEET]))}")
    return list(SCENE_THINGS[name])


def scene_specs(name: str, speed: float | None = 1.0, samples: int | None = None, fleet: int | None = None,
                fleet_first: int = 1, processes: int | None = None) -> list[ProcessSpec]:
    """The processes of a scene; `speed` (None = as fast as possible) goes to every simulated world,
    `samples` (None = each robot's default) to every robot's workspace sampling; the fleet scene's
    `fleet` devices (stations numbered from `fleet_first`) go to `processes` processes (default: one per core)."""
    if name == FLEET:
        from devices.things.fleet import DEFAULT_FLEET, FleetDevice, split

        parts = split(fleet or DEFAULT_FLEET, processes or os.cpu_count() or 1)
        return [ProcessSpec(f"fleet-{i + 1}", entries.fleet, {"start": lo, "end": hi, "first": fleet_first},
                            role=f"fleet {FleetDevice(lo, fleet_first).name}..{FleetDevice(hi - 1, fleet_first).name}")
                for i, (lo, hi) in enumerate(parts)]
    if name not in SCENES:
        raise KeyError(f"unknown scene {name!r}; known scenes: {', '.join(sorted([*SCENES, FLEET]))}")
    specs = []
    for s in SCENES[name]:
        kwargs = dict(s.kwargs)
        if "speed" in kwargs:
            kwargs["speed"] = speed
        if "samples" in kwargs and samples is not None:
            kwargs["samples"] = samples
        specs.append(ProcessSpec(s.name, s.target, kwargs, s.role))
    return specs
