"""An idle world whose bodies are still rests: simulated time, sensors and snapshots go on, the physics engine
is left alone (what an idle lab costs), and anything that changes the physics wakes it at once.

Real pybullet worlds at speed max (an idle one steps in real time); the tests wait on the world's own state,
never on the wall clock.
"""
from __future__ import annotations

import pybullet as pb
import pytest
from waiting import eventually

from devices.sim.pybullet_world import World

HALF = 0.05  # the cube's half size (m)


def _cube(client: int, z: float) -> int:
    shape = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[HALF] * 3, physicsClientId=client)
    return pb.createMultiBody(1.0, shape, basePosition=[0, 0, z], physicsClientId=client)


@pytest.fixture
def world():
    w = World(speed=None)
    ground = pb.createCollisionShape(pb.GEOM_PLANE, physicsClientId=w.client)
    pb.createMultiBody(0.0, ground, physicsClientId=w.client)
    w.cube = _cube(w.client, 0.3)  # type: ignore[attr-defined]  # dropped: it falls and settles first
    w.start()
    yield w
    w.close()


def _height(world: World, body: int) -> float:
    return world.run(lambda: pb.getBasePositionAndOrientation(body, physicsClientId=world.client)[0][2])


def test_a_still_idle_world_rests_while_its_time_goes_on(world):
    eventually(lambda: world.resting, timeout=60, what="the dropped cube settled and the world resting")
    assert abs(_height(world, world.cube) - HALF) < 0.01  # it fell and lies on the ground
    time, physics = world.time, world.physics_steps
    eventually(lambda: world.time > time + 0.5, what="simulated time going on")
    assert world.resting and world.physics_steps == physics  # the engine was left alone meanwhile


def test_reading_and_what_has_no_physics_leave_it_resting(world):
    eventually(lambda: world.resting, timeout=60, what="the world resting")
    physics = world.physics_steps
    for _ in range(20):
        _height(world, world.cube)
        world.run(lambda: pb.changeVisualShape(world.cube, -1, rgbaColor=[1, 0, 0, 1], physicsClientId=world.client))
    assert world.resting and world.physics_steps == physics


def test_a_body_moved_by_a_command_falls_at_once(world):
    eventually(lambda: world.resting, timeout=60, what="the world resting")
    world.run(lambda: pb.resetBasePositionAndOrientation(world.cube, [0, 0, 1.0], [0, 0, 0, 1],
                                                         physicsClientId=world.client))
    assert not world.resting
    eventually(lambda: _height(world, world.cube) < 0.5, what="the lifted cube falling")
    eventually(lambda: world.resting and abs(_height(world, world.cube) - HALF) < 0.01, timeout=60,
               what="the cube on the ground again and the world resting")


def test_a_body_added_in_the_air_falls(world):
    eventually(lambda: world.resting, timeout=60, what="the world resting")
    second = world.run(lambda: _cube(world.client, 0.8))
    eventually(lambda: _height(world, second) < 0.5, what="the new cube falling")


class _Watch:
    """A motion of `steps` steps that notes, at each, whether the world rested and the physics stepped."""

    def __init__(self, world: World, steps: int):
        self.world, self.left, self.seen = world, steps, []

    def advance(self, dt: float) -> bool:
        self.seen.append((self.world.resting, self.world.physics_steps))
        self.left -= 1
        return self.left <= 0


def test_a_motion_wakes_it_and_a_world_told_not_to_rest_never_does(world):
    eventually(lambda: world.resting, timeout=60, what="the world resting")
    watch = _Watch(world, 48)
    world.play(watch).result(timeout=60)
    assert not any(resting for resting, _ in watch.seen)
    assert watch.seen[-1][1] - watch.seen[0][1] == len(watch.seen) - 1  # a physics step at each of its steps
    world.rest = False
    eventually(lambda: not world.resting, what="the world awake once told not to rest")
    physics = world.physics_steps
    eventually(lambda: world.physics_steps > physics + 240, what="the physics stepping on")
    assert not world.resting
