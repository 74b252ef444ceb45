"""The fast collision model answers as pybullet's exact test does, for every arm of the zoo and the lab.

What a user would notice if it did not: a sample (a target the robot is later allowed to reach) called
free that collides, or a workspace that differs with the model. The figures (time, how much is left to
the exact test) are in tests/bench/bench_collision_model.py.
"""
from __future__ import annotations

import msgspec
import numpy as np
import pybullet as pb
import pytest
from click.testing import CliRunner
from zoo import ROBOTS, ZOO

from devices.sim import compensation as c
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import COLLIDES, FREE, UNSURE, FastCollision
from tdgen.robot.link_frames import LinkFrames
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import BoxBody, default_scene, load_scene
from tdgen.sampling import random_configurations, sample_workspace

SAMPLES = 1500

pytestmark = pytest.mark.usefixtures("compiled_code")  # the session's one compile, not one of its own beside it


def _tilted_boxes():
    """table-and-wall with boxes turned about two axes on the table: their corners poke into links at every
    angle (the test of a sure collision that looks for an element's corner deep inside a link)."""
    base = load_scene("table-and-wall")
    boxes = [BoxBody(name=f"box{i}", size=(0.1 + 0.05 * i, 0.2, 0.15 + 0.03 * i),
                     position=(0.3 + 0.05 * i, 0.2 - 0.15 * i, 0.725), rpy=(0.0, 10.0 * i + 5.0, 25.0 * i))
             for i in range(4)]
    return msgspec.structs.replace(base, bodies=[*base.bodies, *boxes])


def _lab_arms() -> dict[str, tuple[Robot, object]]:
    uarm = Robot.load(c.UARM_URDF, ee=c.UARM_EE, passive_joints=c.UARM_PASSIVE_JOINTS, passive=c.uarm_passive)
    dobot = Robot.load(c.DOBOT_URDF, ee=c.DOBOT_EE, passive_joints=c.DOBOT_PASSIVE_JOINTS, passive=c.dobot_passive)
    ur10 = Robot.load("ur10.urdf")
    return {"ur10 table-and-wall": (ur10, load_scene("table-and-wall")),
            "ur10 cluttered-lab": (ur10, load_scene("cluttered-lab")),
            "ur10 beside tilted boxes": (ur10, _tilted_boxes()),
            "uarm iot-platform": (uarm, load_scene("iot-platform", "uarm")),
            "dobot iot-platform": (dobot, load_scene("iot-platform", "dobot")),
            "panda (pybullet_data)": (Robot.load("franka_panda/panda.urdf"), None)}


def _agreement(robot: Robot, scene) -> tuple[np.ndarray, np.ndarray, FastCollision]:
    scene = scene if scene is not None else default_scene(reach=robot.reach())
    world = CollisionWorld(robot, scene)
    try:
        fast = FastCollision(world)
        q = random_configurations(robot, SAMPLES, 11)
        return fast.spheres.verdicts(q), world.colliding(q), fast
    finally:
        world.close()


@pytest.mark.lab  # the whole zoo, meshes of thousands of triangles: minutes, the lab layer
@pytest.mark.slow
@pytest.mark.parametrize("name", sorted(ZOO))
def test_every_zoo_arm_gets_the_exact_tests_answers(name):
    urdf, options, _, _ = ZOO[name]
    robot = Robot.load(ROBOTS / urdf, **options)
    verdict, exact, fast = _agreement(robot, None)
    called_free_colliding = int(np.sum((verdict == FREE) & exact))
    called_sure_free = int(np.sum((verdict == COLLIDES) & ~exact))
    print(f"\n{name:10s} free {np.mean(verdict == FREE):.3f} sure {np.mean(verdict == COLLIDES):.3f} "
          f"unsure {np.mean(verdict == UNSURE):.3f} (exact: {exact.mean():.3f} colliding); "
          f"links on pybullet's box: {sorted(fast.spheres.fallback)}")
    assert called_free_colliding == 0, f"{called_free_colliding} samples called free collide"
    assert called_sure_free == 0, f"{called_sure_free} samples called colliding are free"


@pytest.mark.parametrize("name", ["ur10 beside tilted boxes", "uarm iot-platform"])
def test_a_planners_checks_on_the_packed_tables_get_the_sampling_loops_verdicts(name):
    """A planner's loop (one thread, the tables packed in three arrays and unpacked by name) and the sampling
    loop (all cores, the tables as they are) give every state the same verdict, a passive linkage's too."""
    robot, scene = _lab_arms()[name]
    world = CollisionWorld(robot, scene)
    try:
        fast = FastCollision(world)
        q = random_configurations(robot, SAMPLES, 12)
        everywhere = fast.spheres.verdicts(q)
        assert np.array_equal(fast.spheres.verdicts_here(q), everywhere)
        assert [fast.spheres.verdict(state) for state in q[:50]] == list(everywhere[:50])
        assert set(np.unique(everywhere)) == {FREE, COLLIDES, UNSURE}
    finally:
        world.close()


@pytest.mark.parametrize("name", sorted(_lab_arms()))
def test_the_lab_arms_get_the_exact_tests_answers_and_most_need_no_exact_test(name):
    robot, scene = _lab_arms()[name]
    verdict, exact, fast = _agreement(robot, scene)
    assert not fast.spheres.fallback, "the lab's own arms are read whole, none on pybullet's box"
    assert int(np.sum((verdict == FREE) & exact)) == 0
    assert int(np.sum((verdict == COLLIDES) & ~exact)) == 0
    assert np.mean(verdict == UNSURE) < 0.4, "the spheres decide most samples themselves"


@pytest.mark.parametrize("name", ["ur10 table-and-wall", "uarm iot-platform", "panda table-and-wall"])
def test_a_state_found_free_with_its_links_grown_vouches_for_the_stretch_around_it(name):
    """A path's first pass (`devices.planning.paths`) judges states 40 mm apart with every link and pair of
    links grown by how far it moves in half that stretch; a state found free then stands for every state
    around it, which the exact test never sees. Not one of those may collide; without the growth some do."""
    robot, scene = _lab_arms()[name] if name in _lab_arms() else (Robot.load("franka_panda/panda.urdf"),
                                                                   load_scene("table-and-wall"))
    world = CollisionWorld(robot, scene)
    try:
        fast = FastCollision(world)
        radii = fast.grow_radii()
        q = random_configurations(robot, 600, 12)
        free = q[~world.colliding(q)]
        rng = np.random.default_rng(5)
        vouched, colliding, colliding_ungrown = 0, 0, 0
        for _ in range(30):
            a, b = free[rng.choice(len(free), 2, replace=False)]
            per = np.abs(b - a) @ radii
            m = max(1, int(np.ceil(per.max() / 0.04)))
            t = np.arange(m + 1) / m
            states = a + (b - a) * t[:, None]
            for grow, counts in ((per / (2 * m), True), (None, False)):
                for k in np.flatnonzero(fast.spheres.verdicts_here(states, grow) == FREE):
                    around = np.clip(t[k] + np.linspace(-0.5, 0.5, 11) / m, 0.0, 1.0)
                    hit = bool(world.colliding(a + (b - a) * around[:, None]).any())
                    if counts:
                        vouched, colliding = vouched + 1, colliding + hit
                    else:
                        colliding_ungrown += hit
        print(f"\n{name}: {vouched} states vouched for their stretch; {colliding_ungrown} stretches collide "
              "around states free but not grown")
        assert vouched >= 100
        assert colliding == 0, f"{colliding} stretches around states found free with their links grown collide"
        assert colliding_ungrown > 0, "the segments pass close enough to things for the growth to matter"
    finally:
        world.close()


def test_link_frames_are_pybullets_own():
    robot = Robot.load(c.UARM_URDF, ee=c.UARM_EE, passive_joints=c.UARM_PASSIVE_JOINTS, passive=c.uarm_passive)
    scene = load_scene("iot-platform", "uarm")
    world = CollisionWorld(robot, scene)
    try:
        links = list(range(-1, pb.getNumJoints(world.body, physicsClientId=world.client)))
        frames = LinkFrames(robot, scene.robot.position, scene.robot.quaternion(), [world._link_name(i) for i in links])
        q = random_configurations(robot, 5, 2)
        _, pos = frames.frames(q)
        for k, row in enumerate(q):
            world._set(world._values(row[None])[0])
            for slot, i in enumerate(links[1:], start=1):
                theirs = pb.getLinkState(world.body, i, computeForwardKinematics=True, physicsClientId=world.client)[4]
                assert np.allclose(pos[k, slot], theirs, atol=1e-6)
    finally:
        world.close()


def test_a_seed_gives_the_same_workspace_with_either_model_and_any_number_of_workers():
    robot = Robot.load("ur10.urdf")
    scene = load_scene("table-and-wall")
    fast_one = sample_workspace(robot, scene, 3000, seed=4, workers=1)
    fast_two = sample_workspace(robot, scene, 3000, seed=4, workers=2)
    exact = sample_workspace(robot, scene, 3000, seed=4, workers=1, collision_model="exact")
    assert np.array_equal(fast_one.collision, exact.collision)
    assert np.array_equal(fast_one.collision, fast_two.collision)
    assert np.array_equal(fast_one.positions, exact.positions)
    with pytest.raises(ValueError, match="collision model must be one of fast, exact"):
        sample_workspace(robot, scene, 10, collision_model="spheres")


def test_the_rows_run_beside_the_exact_checks_get_the_same_answers_as_on_one_core():
    """Past 65,536 samples the compiled loop finishes on a thread, on one core fewer, while pybullet checks
    what it left unsure: the flags and points are those of a run on one core (where nothing runs beside),
    and the rows at the end (those run beside) agree with pybullet's own test."""
    import numba

    from tdgen.robot.fast_collision import CHUNK

    robot = Robot.load("ur10.urdf")
    scene = load_scene("table-and-wall")
    n = 2 * CHUNK + 20_000
    split = sample_workspace(robot, scene, n, seed=9)
    cores = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        alone = sample_workspace(robot, scene, n, seed=9)
    finally:
        numba.set_num_threads(cores)
    assert np.array_equal(split.collision, alone.collision)
    assert np.array_equal(split.positions, alone.positions)
    tail = np.arange(n - 1500, n)
    world = CollisionWorld(robot, scene)
    try:
        assert np.array_equal(split.collision[tail], world.colliding(split.q[tail]))
    finally:
        world.close()
    assert 0.3 < split.collision.mean() < 0.95  # a scene where both answers are common


def _capsule_link(name: str, xyz: str, radius: float, length: float, rpy: str = "0 0 0") -> str:
    return (f'<link name="{name}"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" '
            f'iyz="0"/></inertial><collision><origin xyz="{xyz}" rpy="{rpy}"/><geometry><capsule radius="{radius}" '
            f'length="{length}"/></geometry></collision></link>')


CAPSULE_ARM = f"""<?xml version="1.0"?>
<robot name="capsule_arm">
  <link name="base"><inertial><mass value="1"/><inertia ixx="0.01" iyy="0.01" izz="0.01" ixy="0" ixz="0" iyz="0"/>
    </inertial><collision><origin xyz="0 0 0.1"/><geometry><cylinder radius="0.12" length="0.2"/></geometry>
    </collision></link>
  {_capsule_link("turret", "0 0 0.15", 0.09, 0.12)}
  {_capsule_link("upper", "0 0 0.35", 0.07, 0.56)}
  {_capsule_link("fore", "0.2 0 0.2", 0.05, 0.5, rpy="0 0.785 0")}
  {_capsule_link("hand", "0 0 0.06", 0.04, 0.06)}
  <joint name="a1" type="revolute"><parent link="base"/><child link="turret"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 0 1"/><limit lower="-3.1" upper="3.1" effort="1" velocity="1"/></joint>
  <joint name="a2" type="revolute"><parent link="turret"/><child link="upper"/><origin xyz="0 0 0.2"/>
    <axis xyz="0 1 0"/><limit lower="-2.6" upper="2.6" effort="1" velocity="1"/></joint>
  <joint name="a3" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 0.7"/>
    <axis xyz="0 1 0"/><limit lower="-2.8" upper="2.8" effort="1" velocity="1"/></joint>
  <joint name="a4" type="revolute"><parent link="fore"/><child link="hand"/><origin xyz="0.35 0 0.35" rpy="0 0.785 0"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
</robot>
"""


def test_an_arm_of_capsules_is_read_whole_and_gets_the_exact_tests_answers(tmp_path):
    """pybullet's capsule (a URDF extension: humanoids, models converted from MuJoCo) is read as itself,
    not left to one sphere around pybullet's box (which left every sample near the table to the exact
    test): a tilted forearm too, against the table, the wall and the arm's own links."""
    urdf = tmp_path / "capsule_arm.urdf"
    urdf.write_text(CAPSULE_ARM)
    verdicts, exact, fast = _agreement(Robot.load(urdf), load_scene("table-and-wall"))
    assert not fast.spheres.fallback, f"links on pybullet's box: {sorted(fast.spheres.fallback)}"
    assert not np.any((verdicts == FREE) & exact), "called free, but the exact test finds a collision"
    assert not np.any((verdicts == COLLIDES) & ~exact), "called colliding, but the exact test finds none"
    assert 0.2 < exact.mean() < 0.8
    assert np.mean(verdicts == UNSURE) < 0.08


def test_tdgen_says_its_rate_and_takes_the_exact_model(tmp_path):
    from devices.cli.main import main

    runs = {}
    for model in ("fast", "exact"):
        result = CliRunner().invoke(main, ["tdgen", "ur10.urdf", "--scene", "table-and-wall", "--samples", "2000",
                                           "--no-progress", "--out", str(tmp_path / model), "--collision-model", model])
        assert result.exit_code == 0, result.output
        assert f"samples/s, {model} collision model" in result.output
        runs[model] = (tmp_path / model / "points.csv").read_text()
    assert runs["fast"] == runs["exact"]  # the same points, the same collision flags
    wrong = CliRunner().invoke(main, ["tdgen", "ur10.urdf", "--collision-model", "spheres"])
    assert wrong.exit_code == 2 and "'spheres' is not one of 'fast', 'exact'" in wrong.output
