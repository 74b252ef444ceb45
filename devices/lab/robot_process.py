"""The process of one robot arm (`twinmesh robot URDF`, the ur10 scene): its own pybullet World with its
scene's static bodies, the twin, and the robot Thing on the mesh until `stop` is set."""
from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from contextlib import ExitStack
from typing import TYPE_CHECKING

from devices.lab.serving import guard_robot
from devices.sim.pybullet_world import World
from devices.sim.robot_twin import WORKSPACE_WAIT, Base, RobotTwin
from devices.things.robot_setup import RobotSetup
from devices.things.robot_thing import RobotThing
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from tdgen.robot.calibration import load_calibration
from tdgen.robot.surroundings import build_into, default_scene, load_scene
from tdgen.robot_td import slug

if TYPE_CHECKING:
    from devices.things.guard import RealDevice
    from mesh.bridge.run import Access

log = logging.getLogger(__name__)


def run(settings: MeshSettings, stop: threading.Event, setup: RobotSetup, real: Sequence[RealDevice] = (),
        access: Access | None = None, announce: Callable[[str], None] | None = None) -> None:
    """Process entry: the robot of `setup` until `stop` is set; `real`: the real robot it guards
    (`devices.things.guard`), reached with `access`; `announce` says how the URDF was read (default: the log)."""
    robot = setup.arm.load(setup.urdf)
    for line in [robot.describe_chain(), *robot.notes()]:
        (announce or log.info)(f"{robot.name}: {line}")
    scene = (load_scene(setup.scene, setup.scene_robot) if setup.scene
             else default_scene(setup.mount, setup.surface, robot.reach()))
    placement = setup.mount or scene.robot
    where = Base(placement.position, placement.yaw, placement.roll, placement.pitch)
    calibration = load_calibration(setup.calibration) if setup.calibration else None
    world = World(speed=setup.speed)
    with ExitStack() as stack:
        stack.callback(world.close)
        build_into(scene, world.client)
        world.start()
        twin = RobotTwin(world, robot, setup.name or slug(robot.name), where, scene, calibration=calibration,
                         max_collision_probability=setup.max_collision_probability, workspace_wait=WORKSPACE_WAIT,
                         planning_budget=setup.planning_budget, collision_model=setup.collision_model)
        stack.callback(twin.close)
        session = stack.enter_context(open_session(settings, thing=twin.name))
        thing = RobotThing(session, settings, twin, samples=setup.samples, seed=setup.seed)
        for device in real:
            assert access is not None, "a guarded real robot needs the access to reach it"
            guard_robot(stack, settings, thing, device, access, stop)
        stack.enter_context(thing)
        stack.callback(world.close)  # first on the way out: pending motions fail, their handlers answer
        log.info("%s: %s on the mesh (speed %s)", twin.name, robot.name,
                 "max" if setup.speed is None else f"{setup.speed:g}")
        world.on_death(stop.set)
        stop.wait()
        if not world.stepping:
            raise SystemExit(f"{twin.name}: the simulation stopped stepping; see the log above")
