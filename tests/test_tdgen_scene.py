"""Scene files: the format decodes strictly, bodies land where the file says, and they make robots collide."""
from __future__ import annotations

import math
import shutil

import msgspec
import numpy as np
import pybullet as pb
import pybullet_data
import pytest

from tdgen.robot.collision import CollisionWorld
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import (
    SCENES_DIR,
    BoxBody,
    CylinderBody,
    RobotPlacement,
    SceneError,
    Surroundings,
    UrdfBody,
    build_into,
    cluttered_lab,
    empty_scene,
    encode_scene,
    load_scene,
)


def test_shipped_scenes_load_by_name():
    table = load_scene("table-and-wall")
    assert table.robot == RobotPlacement(position=(0.0, 0.0, 0.625), yaw=0.0)
    assert [type(b) for b in table.bodies] == [UrdfBody, UrdfBody, BoxBody]


def test_the_benchmark_scene_has_many_bodies_and_is_what_the_function_builds():
    lab = load_scene("cluttered-lab")
    assert len(lab.bodies) >= 60
    assert lab == cluttered_lab()
    assert {type(b) for b in lab.bodies} == {UrdfBody, BoxBody, CylinderBody}


def test_encoded_scene_decodes_to_the_same_scene():
    lab = cluttered_lab()
    assert msgspec.json.decode(encode_scene(lab), type=Surroundings) == lab


def test_urdf_paths_are_relative_to_the_scene_file(tmp_path):
    (tmp_path / "models").mkdir()
    shutil.copy(f"{pybullet_data.getDataPath()}/cube.urdf", tmp_path / "models" / "crate.urdf")
    (tmp_path / "s.json").write_text('{"name": "s", "bodies": [{"type": "urdf", "urdf": "models/crate.urdf"}]}')
    scene = load_scene(tmp_path / "s.json")
    assert scene.bodies[0].urdf == str(tmp_path / "models" / "crate.urdf")
    assert scene.robot == RobotPlacement()


@pytest.mark.parametrize("text, problem", [
    ('{"name": "s", "bodies": [{"type": "sphere", "radius": 1}]}', "not a valid scene"),
    ('{"name": "s", "bodies": [{"type": "box", "size": [1, 0, 1]}]}', "box size must be positive"),
    ('{"name": "s", "bodies": [{"type": "box", "size": [1, 1, 1], "colour": "red"}]}', "not a valid scene"),
    ('{"name": "s", "bodies": [{"type": "urdf", "urdf": "nowhere.urdf"}]}', "URDF 'nowhere.urdf' not found"),
    ('{"name": "s", "robot": {"position": [0, 0]}}', "not a valid scene"),
    ('{"name": "s", ', "not a valid scene"),
])
def test_bad_scene_files_are_refused_naming_the_file_and_the_problem(tmp_path, text, problem):
    path = tmp_path / "bad.json"
    path.write_text(text)
    with pytest.raises(SceneError, match=problem) as err:
        load_scene(path)
    assert "bad.json" in str(err.value)


def test_a_missing_scene_lists_the_shipped_ones():
    with pytest.raises(SceneError, match="shipped scenes: cluttered-lab, iot-platform, table-and-wall"):
        load_scene("no-such-scene")


def test_bodies_are_built_where_the_scene_puts_them():
    scene = Surroundings(name="t", bodies=[
        BoxBody(size=(0.2, 0.4, 0.6), position=(1.0, 2.0, 3.0), rpy=(0.0, 0.0, 90.0)),
        CylinderBody(radius=0.1, length=0.5, position=(-1.0, 0.0, 0.25)),
        UrdfBody(urdf="pybullet_data:cube.urdf", position=(0.0, -2.0, 0.5), scale=0.5),
    ])
    client = pb.connect(pb.DIRECT)
    try:
        box, cylinder, cube = build_into(scene, client)
        lo, hi = pb.getAABB(box, physicsClientId=client)
        np.testing.assert_allclose(np.subtract(hi, lo), [0.4, 0.2, 0.6], atol=0.03)  # yawed 90 degrees
        np.testing.assert_allclose(np.add(hi, lo) / 2, [1.0, 2.0, 3.0], atol=1e-6)
        lo, hi = pb.getAABB(cylinder, physicsClientId=client)
        np.testing.assert_allclose(np.subtract(hi, lo), [0.2, 0.2, 0.5], atol=0.03)
        lo, hi = pb.getAABB(cube, physicsClientId=client)
        np.testing.assert_allclose(np.subtract(hi, lo), [0.5, 0.5, 0.5], atol=0.03)
        assert all(pb.getDynamicsInfo(b, -1, physicsClientId=client)[0] == 0 for b in (box, cylinder, cube))
    finally:
        pb.disconnect(client)


def _world(scene: Surroundings) -> CollisionWorld:
    return CollisionWorld(Robot.load("ur10.urdf"), scene)


def test_a_robot_bolted_to_its_table_does_not_collide_at_home_but_hits_the_table_and_the_wall():
    world = _world(load_scene("table-and-wall"))
    try:
        home = np.zeros(6)
        down = np.array([0.0, math.pi / 2, 0, 0, 0, 0])            # upper arm into the table
        to_wall = np.array([-math.pi / 2, -0.3, 0, 0, 0, 0])        # arm stretched towards +y
        away = np.array([math.pi / 2, -0.3, 0, 0, 0, 0])            # the same, towards -y (open side)
        assert world.colliding(np.array([home, down, to_wall, away])).tolist() == [False, True, True, False]
    finally:
        world.close()


def test_self_collision_counts_but_not_for_adjacent_links():
    world = _world(empty_scene())
    try:
        folded = np.array([0.0, 0.0, math.pi, 0, 0, 0])              # forearm folded onto the upper arm
        bent = np.array([0.0, -1.0, 1.5, -1.0, 1.0, 0.5])
        assert world.colliding(np.array([folded, bent, np.zeros(6)])).tolist() == [True, False, False]
    finally:
        world.close()


def test_the_robot_stands_at_the_scene_pose():
    placed = Surroundings(name="p", robot=RobotPlacement(position=(5.0, 0.0, 0.0), yaw=90.0),
                   bodies=[BoxBody(size=(0.2, 0.2, 0.2), position=(5.0, 1.2, 0.13))])
    world = _world(placed)
    try:
        stretched = np.array([[0.0, 0.0, 0, 0, 0, 0], [math.pi, 0.0, 0, 0, 0, 0]])
        # UR10 at q=0 reaches along its -x; yawed 90 degrees that is world -y, away from the box;
        # turned by 180 degrees it sweeps the box at +y
        assert world.colliding(stretched).tolist() == [False, True]
    finally:
        world.close()


def test_a_ceiling_mount_is_a_full_pose_the_collision_check_uses():
    """The same configuration (upper arm straight up from the base) is free for a UR10 standing at 1 m and
    hits the floor for one hung from the ceiling at 1 m (roll 180): the tilt is not lost on the way."""
    robot = Robot.load("ur10.urdf")
    floor = BoxBody(name="floor", size=(6.0, 6.0, 0.02), position=(0.0, 0.0, -0.01))
    up = np.radians([0.0, -90.0, 0.0, -90.0, 0.0, 0.0])
    results = {}
    for roll in (0.0, 180.0):
        scene = Surroundings(name="room", robot=RobotPlacement(position=(0.0, 0.0, 1.0), roll=roll), bodies=[floor])
        world = CollisionWorld(robot, scene)
        try:
            results[roll] = world.what_collides(up)
        finally:
            world.close()
    assert results[0.0] == [] and any(pair.endswith("/ floor") for pair in results[180.0]), results


def test_without_a_scene_the_robot_stands_on_its_mounting_surface_unless_told_otherwise(tmp_path):
    from tdgen.generate import generate

    on_floor = generate("ur10.urdf", None, 2000, seed=0, out_dir=tmp_path / "a", workers=1)
    alone = generate("ur10.urdf", None, 2000, seed=0, out_dir=tmp_path / "b", workers=1, surface=False)
    hung = generate("ur10.urdf", None, 2000, seed=0, out_dir=tmp_path / "c", workers=1,
                    mount=RobotPlacement(position=(0.0, 0.0, 2.5), roll=180.0))
    assert on_floor.low_mm[2] > -1.0 and alone.low_mm[2] < -1000.0  # nothing below the floor through the base
    assert hung.low_mm[2] > -1.0 and hung.collision_free == on_floor.collision_free  # the ceiling, seen from the base
    scene = msgspec.json.decode((tmp_path / "c" / "scene.json").read_bytes())
    assert scene["robot"]["roll"] == 180.0 and scene["bodies"][0]["name"] == "mounting-surface"
    assert scene["bodies"][0]["position"][2] > 2.5  # the slab is above the hung base


def test_a_worlds_scene_json_is_a_scene_for_one_of_its_robots():
    """The iot-platform's scene, as its world Thing serves it, places the uArm (or the Dobot) where it
    stands among the tables and belts; cubes (moving) and the other arm are not surroundings."""
    from tdgen.robot.surroundings import SceneError

    with pytest.raises(SceneError, match="robots uarm, dobot: say which one"):
        load_scene("iot-platform")
    with pytest.raises(SceneError, match="no robot 'ur10'"):
        load_scene("iot-platform", "ur10")
    uarm, dobot = load_scene("iot-platform", "uarm"), load_scene("iot-platform", "dobot")
    assert uarm.robot.position == pytest.approx((-0.375, 0.0, 0.75)) and uarm.robot.yaw == 0.0
    assert dobot.robot.yaw == pytest.approx(180.0) and {b.name for b in uarm.bodies} == {b.name for b in dobot.bodies}
    assert "floor" in {b.name for b in uarm.bodies} and not any(b.name.startswith("cube") for b in uarm.bodies)


def test_the_shipped_iot_platform_scene_is_what_the_platform_world_serves(tmp_path):
    from devices.sim.layouts.platform_layout import write_scene_json

    write_scene_json(tmp_path / "now.json")
    shipped = msgspec.json.decode((SCENES_DIR / "iot-platform.json").read_bytes())
    assert msgspec.json.decode((tmp_path / "now.json").read_bytes()) == shipped, \
        "regenerate it: python -m devices.sim.layouts.platform_layout"


def test_the_uarm_generated_where_it_stands_keeps_above_its_table(tmp_path):
    from tdgen.generate import generate

    result = generate("uarm_swift_pro.urdf", load_scene("iot-platform", "uarm"), 3000, seed=0, out_dir=tmp_path,
                      workers=1)
    assert len(result.td["properties"]["getJointposition"]["properties"]) == 4  # the parallelogram's mimics
    assert result.low_mm[2] > -1.0 and result.high_mm[2] < 190.0  # on the table top, the tool under ~186 mm
