"""Scenes: which processes make up a lab. `twinmesh up SCENE` starts exactly these."""
from __future__ import annotations

from mesh.processes import ProcessSpec

SCENES: dict[str, list[ProcessSpec]] = {
    "lights": [ProcessSpec("lights", "devices.lights:run")],
    # one process: the pybullet world and every device of the table, each device its own Zenoh peer
    "iot-platform": [ProcessSpec("iot-platform", "devices.platform_process:run", {"speed": 1.0})],
    # a generic robot arm (`twinmesh robot`) on a table beside a wall; its TD comes from the tdgen service
    "ur10": [ProcessSpec("ur10", "devices.robot_thing:run",
                         {"urdf": "ur10.urdf", "name": "ur10", "scene": "table-and-wall", "speed": 1.0})],
}
DEFAULT_SCENE = "lights"


def scene_specs(name: str, speed: float | None = 1.0) -> list[ProcessSpec]:
    """The processes of a scene; `speed` (None = as fast as possible) goes to every simulated world."""
    if name not in SCENES:
        raise KeyError(f"unknown scene {name!r}; known scenes: {', '.join(sorted(SCENES))}")
    return [ProcessSpec(s.name, s.target, {**s.kwargs, "speed": speed}) if "speed" in s.kwargs else s
            for s in SCENES[name]]
