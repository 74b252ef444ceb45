"""tdgen end to end for the four common-structure robots, in the table-and-wall scene."""
from __future__ import annotations

import json
import math
import xml.etree.ElementTree as ET

import numpy as np
import pybullet as pb
import pytest
import trimesh
from tdschema import assert_valid_td, assert_valid_tm

from mesh.messages.relations import POINTS, SCENE, TWIN, WORKSPACE
from tdgen.generate import generate
from tdgen.robot.model import Robot
from tdgen.robot.points_csv import read as read_points_csv
from tdgen.robot.surroundings import load_scene
from tdgen.robot.workspace_check import Workspace

ROBOTS = ["franka_panda/panda.urdf", "kuka_iiwa/model.urdf", "xarm/xarm6_robot.urdf", "ur10.urdf"]
SAMPLES = 4000
BASE_URL = "http://lab.example:8080/robot/"  # the Thing "robot" on the adapter at http://lab.example:8080


@pytest.fixture(scope="module", params=ROBOTS, ids=lambda u: u.split("/")[0].replace(".urdf", ""))
def generated(request, tmp_path_factory):
    out = tmp_path_factory.mktemp("td")
    result = generate(request.param, "table-and-wall", SAMPLES, seed=7, out_dir=out, base_url=BASE_URL, workers=1)
    td = json.loads(result.files["td"].read_text())
    positions, collision = read_points_csv(result.files["points"])
    return request.param, result, td, positions, collision


def test_td_is_valid_against_the_official_schema(generated):
    _, _, td, _, _ = generated
    assert_valid_td(td)
    assert td["@context"] == ["https://www.w3.org/2019/wot/td/v1", "https://www.w3.org/2022/wot/td/v1.1",
                              {"@language": "en", "qudt": "http://qudt.org/vocab/unit/"}]
    assert td["id"] == "urn:twinmesh:robot:robot" and td["title"] == "robot"  # the base URL names the Thing
    assert td["securityDefinitions"] == {"nosec_sc": {"scheme": "nosec"}}


def test_td_has_the_affordances_forms_and_links_the_adapter_serves(generated):
    _, _, td, _, _ = generated
    url = BASE_URL.rstrip("/")
    assert "base" not in td, "every href is absolute, as the adapter serves them"
    assert set(td["properties"]) == {"getJointposition", "getCartesianposition"}
    assert set(td["actions"]) == {"moveToJointPosition", "moveToCartesianPosition", "moveToPose", "planMove", "stop"}
    for name, prop in td["properties"].items():
        assert prop["readOnly"] and prop["observable"]
        forms = {(f["href"], f.get("subprotocol")): f["op"] for f in prop["forms"]}
        assert forms == {(f"{url}/properties/{name}", None): ["readproperty"],  # long-poll has its own href
                         (f"{url}/properties/{name}/observable", "longpoll"): ["observeproperty", "unobserveproperty"],
                         (f"{url}/properties/{name}/sse", "sse"): ["observeproperty", "unobserveproperty"]}
    for name, action in td["actions"].items():
        assert action["synchronous"] is True
        at = f"{url}/actions/{name}"  # synchronous first, then asynchronous with its status resource
        assert [(f["op"], f["href"]) for f in action["forms"]] == [
            ("invokeaction", at), ("invokeaction", f"{at}?async=true"), ("queryaction", f"{at}/{{id}}"),
            ("cancelaction", f"{at}/{{id}}")]
    for name in ("moveToJointPosition", "moveToCartesianPosition"):
        action = td["actions"][name]
        assert action["input"]["required"] == list(action["input"]["properties"])
        assert action["output"] == td["actions"]["planMove"]["output"]  # a dry run answers like the move
    assert td["actions"]["planMove"]["safe"] is True and "input" not in td["actions"]["stop"]
    assert td["actions"]["moveToJointPosition"]["input"]["properties"] == td["properties"]["getJointposition"]["properties"]
    assert td["actions"]["moveToCartesianPosition"]["input"]["properties"] == \
        td["properties"]["getCartesianposition"]["properties"]
    assert "twinChanged" in td["events"] and {f["op"] if isinstance(f["op"], str) else f["op"][0]
                                              for f in td["forms"]} >= {"readallproperties", "observeallproperties"}
    assert {(link["rel"], link["href"], link["type"]) for link in td["links"]} >= {
        (WORKSPACE, f"{url}/files/workspace.stl", "model/stl"), (POINTS, f"{url}/files/points.csv", "text/csv"),
        (SCENE, f"{url}/files/scene.json", "application/json"), (TWIN, f"{url}/files/twin.json", "application/json")}


def test_without_a_base_url_tdgen_writes_a_thing_model_valid_against_the_official_schema(tmp_path):
    result = generate("ur10.urdf", None, 500, seed=1, out_dir=tmp_path, workers=1)
    assert "td" not in result.files and not (tmp_path / "td.json").exists()
    tm = json.loads(result.files["tm"].read_text())
    assert_valid_tm(tm)
    assert tm["@type"] == "tm:ThingModel" and "id" not in tm and tm["title"] == "ur10"
    hrefs = [f["href"] for kind in ("properties", "actions", "events") for a in tm[kind].values() for f in a["forms"]]
    assert hrefs and all(h.startswith("{{BASE_URL}}/ur10/") for h in hrefs)


def test_a_base_url_that_names_no_thing_is_refused_before_sampling(tmp_path):
    for bad in ("http://lab.example:8080", "http://lab.example:8080/", "lab.example/ur10"):
        with pytest.raises(ValueError, match="base-url"):
            generate("ur10.urdf", None, 500, out_dir=tmp_path / "x", base_url=bad)
    assert not (tmp_path / "x").exists()


def test_workspace_stl_is_a_watertight_hull_of_the_reported_volume(generated):
    _, result, _, _, _ = generated
    mesh = trimesh.load_mesh(result.files["workspace"])
    assert mesh.is_watertight and mesh.is_winding_consistent
    assert mesh.volume == pytest.approx(result.volume_mm3, rel=1e-4)  # float32 vertices in STL


def test_every_collision_free_point_is_inside_the_hull(generated):
    _, _, _, positions, collision = generated
    workspace = Workspace(positions, collision)
    assert workspace.contains(positions[~collision]).all()
    assert 0 < (~collision).sum() < len(collision)  # the scene and self-collision both matter


def test_cartesian_limits_are_the_collision_free_bounds(generated):
    _, result, td, positions, collision = generated
    fields = td["properties"]["getCartesianposition"]["properties"]
    free = positions[~collision]
    for i, axis in enumerate("xyz"):
        assert fields[axis]["unit"] == "qudt:MilliM"  # QUDT, prefix declared in @context
        assert fields[axis]["minimum"] == pytest.approx(free[:, i].min(), abs=1e-6)
        assert fields[axis]["maximum"] == pytest.approx(free[:, i].max(), abs=1e-6)
        assert result.low_mm[i] == pytest.approx(free[:, i].min(), abs=1e-6)


def _urdf_limits(path) -> dict[str, tuple[str, float, float]]:
    """Joint limits in deg / mm (QUDT units) straight from the URDF XML."""
    out = {}
    for j in ET.parse(path).getroot().findall("joint"):
        kind, limit = j.get("type"), j.find("limit")
        if kind == "continuous":
            out[j.get("name")] = ("qudt:DEG", -180.0, 180.0)
        elif kind in ("revolute", "prismatic"):
            scale = 1000.0 if kind == "prismatic" else 180 / math.pi
            out[j.get("name")] = ("qudt:MilliM" if kind == "prismatic" else "qudt:DEG",
                                  float(limit.get("lower")) * scale, float(limit.get("upper")) * scale)
    return out


def test_joint_limits_in_the_td_are_the_urdfs(generated):
    urdf, result, td, _, _ = generated
    limits = _urdf_limits(Robot.load(urdf).urdf_path)
    fields = td["properties"]["getJointposition"]["properties"]
    info = json.loads(result.files["robot-info"].read_text())
    assert list(fields) == info["jointNames"] and info["jointAmount"] == len(fields) >= 6
    for k, (name, schema) in enumerate(fields.items()):
        unit, low, high = limits[name]
        assert (schema["unit"], schema["minimum"], schema["maximum"]) == (unit, pytest.approx(low, abs=1e-5),
                                                                           pytest.approx(high, abs=1e-5))
        assert (info["jointLimitLows"][k], info["jointLimitHighs"][k]) == (pytest.approx(low), pytest.approx(high))


def test_points_are_end_effector_positions_in_the_robot_base_frame(generated):
    """The CSV's xyz is where pybullet puts the ee link, seen from the robot's base, for the CSV's joints."""
    urdf, result, _, positions, _ = generated
    robot, scene = Robot.load(urdf), load_scene("table-and-wall")
    joints = np.loadtxt(result.files["points"], delimiter=",", skiprows=1, max_rows=200)[:, 4:]
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client, scene.robot.position, math.radians(scene.robot.yaw))
        for row, expected in zip(robot.from_user_units(joints), positions):
            for index, value in robot.full_joint_values(row).items():
                pb.resetJointState(body, index, value, physicsClientId=client)
            world = pb.getLinkState(body, robot.ee_index, computeForwardKinematics=True, physicsClientId=client)[4]
            local = (np.array(world) - scene.robot.position) * 1000.0  # yaw 0 in this scene
            np.testing.assert_allclose(local, expected, atol=0.01)
    finally:
        pb.disconnect(client)


def test_outputs_carry_the_scene_with_the_robot_pose(generated):
    _, result, _, _, _ = generated
    assert set(result.files) == {"td", "robot-info", "points", "workspace", "scene"}
    scene = json.loads(result.files["scene"].read_text())
    assert scene["robot"] == {"position": [0.0, 0.0, 0.625], "yaw": 0.0, "roll": 0.0, "pitch": 0.0}
    assert [b["name"] for b in scene["bodies"]] == ["floor", "table", "wall"]
    assert result.samples == SAMPLES and result.collision_free == (~generated[4]).sum()


def test_same_seed_gives_the_same_csv_whatever_the_worker_count(tmp_path):
    one = generate("ur10.urdf", "table-and-wall", 2500, seed=3, out_dir=tmp_path / "one", workers=1)
    two = generate("ur10.urdf", "table-and-wall", 2500, seed=3, out_dir=tmp_path / "two", workers=2)
    other = generate("ur10.urdf", "table-and-wall", 2500, seed=4, out_dir=tmp_path / "other", workers=1)
    assert one.files["points"].read_bytes() == two.files["points"].read_bytes()
    assert one.files["points"].read_bytes() != other.files["points"].read_bytes()


def _decimal(value: float, places: int) -> str:
    """A value as points.csv writes it, by Python: rounded half to even at its last decimal."""
    n = int(np.rint(value * 10**places))
    digits = str(abs(n)).rjust(places + 1, "0")
    return ("-" if n < 0 else "") + (f"{digits[:-places]}.{digits[-places:]}" if places else digits)


def test_points_csv_is_written_row_for_row_as_python_formats_it_across_blocks():
    """The rows are measured, then formatted, in blocks on all cores: 101,539 rows (four blocks, the last of
    3,235 rows) give the bytes Python's own formatting of each value gives, in order: zeros, signs, the
    decimals rounded half to even, numbers of one to seven digits before the point."""
    from tdgen.robot import points_csv

    robot = Robot.load("ur10.urdf")
    rng = np.random.default_rng(5)
    n = 3 * points_csv.BLOCK_ROWS + 3235
    positions = rng.uniform(-1500, 1500, (n, 3))
    positions[:5] = [[0.0, -0.0004, 0.0005], [-0.0005, 1234.5675, -999.9995], [2.5e-4, -1e-9, 1e-3],
                     [1300.0, -1300.0, 0.1], [1e6, -123456.7891, 99.9995]]
    q = rng.uniform(robot.lows(), robot.highs(), (n, len(robot.joints)))
    collision = rng.random(n) < 0.3
    data = points_csv.encode(robot, positions, collision, q)
    joints = robot.to_user_units(q)
    expected = [",".join(["x", "y", "z", "collision", *(j.name for j in robot.joints)])]
    expected += [",".join([*(_decimal(v, 3) for v in p), "1" if c else "0", *(_decimal(v, 6) for v in j)])
                 for p, c, j in zip(positions, collision, joints)]
    lines = data.decode().split("\n")
    assert lines[-1] == "" and len(lines) == n + 2
    wrong = [k for k, (got, want) in enumerate(zip(lines, expected)) if got != want]
    assert not wrong, [(lines[k], expected[k]) for k in wrong[:3]]


BIG_ARM = """<?xml version="1.0"?>
<robot name="big_arm">
  <link name="base"><collision><geometry><cylinder radius="0.3" length="0.4"/></geometry>
    <origin xyz="0 0 0.2"/></collision></link>
  <link name="turret"><collision><origin xyz="0 0 0.3"/><geometry><box size="0.5 0.5 0.6"/></geometry></collision></link>
  <link name="upper"><collision><origin xyz="0 0 0.75"/><geometry><box size="0.25 0.25 1.5"/></geometry></collision></link>
  <link name="fore"><collision><origin xyz="0 0 0.8"/><geometry><box size="0.2 0.2 1.6"/></geometry></collision></link>
  <link name="hand"><collision><origin xyz="0 0 0.15"/><geometry><box size="0.15 0.15 0.3"/></geometry></collision></link>
  <joint name="a1" type="revolute"><parent link="base"/><child link="turret"/><origin xyz="0 0 0.4"/>
    <axis xyz="0 0 1"/><limit lower="-3.1" upper="3.1" effort="1" velocity="1"/></joint>
  <joint name="a2" type="revolute"><parent link="turret"/><child link="upper"/><origin xyz="0 0 0.3"/>
    <axis xyz="0 1 0"/><limit lower="-2.6" upper="2.6" effort="1" velocity="1"/></joint>
  <joint name="a3" type="revolute"><parent link="upper"/><child link="fore"/><origin xyz="0 0 1.5"/>
    <axis xyz="0 1 0"/><limit lower="-2.6" upper="2.6" effort="1" velocity="1"/></joint>
  <joint name="a4" type="revolute"><parent link="fore"/><child link="hand"/><origin xyz="0 0 1.6"/>
    <axis xyz="0 1 0"/><limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
</robot>
"""


def test_a_big_arm_stands_on_a_surface_wider_than_it_reaches_no_free_point_under_it(tmp_path):
    """A 3 m industrial arm on the 4 m default slab had free points below the floor, past the slab's edge."""
    urdf = tmp_path / "big_arm.urdf"
    urdf.write_text(BIG_ARM)
    robot = Robot.load(urdf)
    assert robot.reach() > 3.0
    result = generate(robot, None, 6000, seed=3, out_dir=tmp_path / "out", workers=1)
    positions, collision = read_points_csv(result.files["points"])
    free = positions[~collision]
    assert len(free) > 500 and np.linalg.norm(free[:, :2], axis=1).max() > 2500  # it does reach past 2.5 m
    assert free[:, 2].min() >= -1.0, free[:, 2].min()  # mm: nothing free under the surface it stands on
    slab = next(b for b in json.loads(result.files["scene"].read_text())["bodies"] if b["name"] == "mounting-surface")
    assert slab["size"][0] >= 2 * robot.reach()
