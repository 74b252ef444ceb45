"""Scenes: which processes make up a lab, which Things it serves, which of its devices can guard a real one.

`twinmesh up SCENE` asks the `Scene` for its processes and Things with the `LabOptions` the command line
gave; no other place knows what a scene holds. The `fleet` scene has no fixed list: `--fleet N` virtual
devices (devices.things.fleet), spread over as many processes as the machine has cores.
"""
from __future__ import annotations

import os
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

from devices.lab import entries
from devices.lab.supervisor import ProcessSpec
from devices.things.fleet import DEFAULT_FLEET, FleetDevice, fleet_names, split
from devices.things.lights import LIGHTS
from devices.things.platform_devices import PLATFORM_DEVICES
from devices.things.robot_setup import RobotSetup
from mesh.messages.scene_description import DEFAULT_SAMPLES

if TYPE_CHECKING:
    from devices.things.guard import RealDevice
    from mesh.bridge.run import Access



@dataclass(frozen=True)
class LabOptions:
    """What `up` says about a scene's processes; each scene takes what applies to it."""

    speed: float | None = 1.0       # every simulated world's speed factor (None: as fast as the CPU allows)
    samples: int | None = None      # every robot's workspace samples (None: each robot's default)
    fleet: int | None = None        # the fleet scene's size (None: DEFAULT_FLEET)
    fleet_first: int = 1            # the fleet's first station number
    processes: int | None = None    # the fleet's processes (None: one per core)
    real: tuple[RealDevice, ...] = ()  # real devices guarded by their twins (`up --real`)
    access: Access | None = None    # how the real devices are reached
    scans: str | None = None        # the folder the iot-lab's world takes obstacle files from (None: the default)


@dataclass(frozen=True)
class Scene:
    """One scene of `twinmesh up`: its processes and Things for given options, and the devices of it that
    can guard a real device (`--real DEVICE=URL`), all said once here."""

    name: str
    summary: str
    processes: Callable[[LabOptions], list[ProcessSpec]]
    things: Callable[[LabOptions], list[str]]
    guardable: frozenset[str] = field(default_factory=frozenset)


PLATFORM = (*PLATFORM_DEVICES, "world")
GUARDING = frozenset(PLATFORM_DEVICES)  # the platform's twins, each of which can guard its real device
UR10 = RobotSetup(urdf="ur10.urdf", name="ur10", scene="table-and-wall")


def _lights(o: LabOptions) -> list[ProcessSpec]:
    return [ProcessSpec("lights", entries.lights, role="lights")]


def _iot_platform(o: LabOptions) -> list[ProcessSpec]:
    # one process: the pybullet world and every device of the table, each device its own Zenoh peer
    return [ProcessSpec("iot-platform", entries.iot_platform, {"speed": o.speed, "real": o.real, "access": o.access},
                        role="world iot-platform")]


def _ur10(o: LabOptions) -> list[ProcessSpec]:
    # a generic robot arm (`twinmesh robot`) on a table beside a wall; its TD comes from the tdgen service
    setup = replace(UR10, speed=o.speed, samples=o.samples or DEFAULT_SAMPLES)
    return [ProcessSpec("ur10", entries.robot, {"setup": setup, "real": o.real, "access": o.access},
                        role="robot ur10")]


def _iot_lab(o: LabOptions) -> list[ProcessSpec]:
    # the whole room: the iot-platform table, the ur10 behind its safety wall, lights and pan-tilts
    return [ProcessSpec("iot-lab", entries.iot_lab, {"speed": o.speed, "samples": o.samples or DEFAULT_SAMPLES,
                                                     "real": o.real, "access": o.access, "scans": o.scans},
                        role="world iot-lab")]


def _fleet(o: LabOptions) -> list[ProcessSpec]:
    parts = split(o.fleet or DEFAULT_FLEET, o.processes or os.cpu_count() or 1)
    return [ProcessSpec(f"fleet-{i + 1}", entries.fleet, {"start": lo, "end": hi, "first": o.fleet_first},
                        role=f"fleet {FleetDevice(lo, o.fleet_first).name}..{FleetDevice(hi - 1, o.fleet_first).name}")
            for i, (lo, hi) in enumerate(parts)]


def _fleet_things(o: LabOptions) -> list[str]:
    return fleet_names(o.fleet or DEFAULT_FLEET, o.fleet_first)


def _fixed(*things: str) -> Callable[[LabOptions], list[str]]:
    return lambda o: list(things)


FLEET = "fleet"
SCENES: dict[str, Scene] = {s.name: s for s in [
    Scene("iot-lab", "the whole room: the IoT platform, the UR10 behind its safety wall, lights and pan-tilts",
          _iot_lab, _fixed(*PLATFORM, "ur10", *LIGHTS, "pan-tilt-1", "pan-tilt-2"),
          guardable=GUARDING | {"ur10"}),
    Scene("iot-platform", "the IoT platform's table: two belts, two light barriers, a colour sensor, a uArm "
          "and a Dobot", _iot_platform, _fixed(*PLATFORM), guardable=GUARDING),
    Scene("ur10", "a UR10 on a table beside a wall", _ur10, _fixed("ur10"), guardable=frozenset({"ur10"})),
    Scene("lights", "two lamps, no simulation", _lights, _fixed(*LIGHTS)),
    Scene(FLEET, "--fleet N virtual devices of four kinds, for load tests", _fleet, _fleet_things),
]}
DEFAULT_SCENE = "iot-lab"


def find_scene(name: str) -> Scene:
    """The scene called `name` (KeyError naming the known ones otherwise)."""
    if name not in SCENES:
        raise KeyError(f"unknown scene {name!r}; known scenes: {', '.join(sorted(SCENES))}")
    return SCENES[name]


def scene_things(name: str, options: LabOptions = LabOptions()) -> list[str]:
    """The Things `twinmesh up NAME` serves, in a stable order (besides the lab's own `tdgen`)."""
    return find_scene(name).things(options)


def scene_specs(name: str, options: LabOptions = LabOptions()) -> list[ProcessSpec]:
    """The processes of scene `name` for `options`."""
    return find_scene(name).processes(options)
