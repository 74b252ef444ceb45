"""Scenes: which processes make up a lab. `twinmesh up SCENE` starts exactly these."""
from __future__ import annotations

from twinmesh.lab.supervisor import ProcessSpec

SCENES: dict[str, list[ProcessSpec]] = {
    "lights": [ProcessSpec("lights", "twinmesh.things.lights:run", role="lights")],
    # one process: the pybullet world and every device of the table, each device its own Zenoh peer
    "iot-platform": [ProcessSpec("iot-platform", "twinmesh.lab.iot_platform:run", {"speed": 1.0},
                                 role="world iot-platform")],
    # a generic robot arm (`twinmesh robot`) on a table beside a wall; its TD comes from the tdgen service
    "ur10": [ProcessSpec("ur10", "twinmesh.things.robot:run",
                         {"urdf": "ur10.urdf", "name": "ur10", "scene": "table-and-wall", "speed": 1.0,
                          "samples": 80_000}, role="robot ur10")],
    # the whole room: the iot-platform table, the ur10 behind its safety wall, lights and pan-tilts
    "iot-lab": [ProcessSpec("iot-lab", "twinmesh.lab.iot_lab:run", {"speed": 1.0, "samples": 80_000},
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


def scene_things(name: str) -> list[str]:
    """The Things `twinmesh up NAME` serves, in a stable order."""
    if name not in SCENES:
        raise KeyError(f"unknown scene {name!r}; known scenes: {', '.join(sorted(SCENES))}")
    return list(SCENE_THINGS[name])


def scene_specs(name: str, speed: float | None = 1.0, samples: int | None = None) -> list[ProcessSpec]:
    """The processes of a scene; `speed` (None = as fast as possible) goes to every simulated world,
    `samples` (None = each robot's default) to every robot's workspace sampling."""
    if name not in SCENES:
        raise KeyError(f"unknown scene {name!r}; known scenes: {', '.join(sorted(SCENES))}")
    specs = []
    for s in SCENES[name]:
        kwargs = dict(s.kwargs)
        if "speed" in kwargs:
            kwargs["speed"] = speed
        if "samples" in kwargs and samples is not None:
            kwargs["samples"] = samples
        specs.append(ProcessSpec(s.name, s.target, kwargs, s.role))
    return specs
