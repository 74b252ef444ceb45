"""The iot-platform on the mesh: devices as Zenoh peers acting on one world, refusals, the `world` Thing.

One lab (`twinmesh up iot-platform --speed max`, with the HTTP adapter) for the module; every test
starts from a reset scene (the world Thing's `reset`).
"""
from __future__ import annotations

import queue
import time

import httpx
import msgspec
import numpy as np
import psutil
import pytest
from labs import mesh_client
from waiting import always

pytestmark = pytest.mark.lab

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def lab(platform):
    return platform  # the session's iot-platform lab, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def client(lab):
    with mesh_client(lab.endpoint) as c:
        yield c


@pytest.fixture
def http(lab):
    with httpx.Client(base_url=lab.http, timeout=60) as h:
        assert h.post("/world/actions/reset").status_code == 204
        yield h


def test_go_to_outside_the_real_ranges_is_a_400_problem_and_the_arm_stays_put(http, client):
    before = http.get("/uarm/properties/location").json()
    for bad in ({"x": 250, "y": 0, "z": 80}, {"x": 150, "y": -201, "z": 80}, {"x": 150, "y": 0, "z": 51},
                {"x": 150, "y": 0}):
        r = http.post("/uarm/actions/goTo", json=bad)
        assert r.status_code == 400 and r.headers["content-type"].startswith(PROBLEM), r.text
        assert r.json()["status"] == 400
    with pytest.raises(Exception) as err:  # over Zenoh: the Thing itself validates its input
        client.invoke("uarm", "goTo", {"x": 119, "y": 0, "z": 80})
    assert getattr(err.value, "status", None) == 400
    assert http.get("/uarm/properties/location").json() == before == {"x": 200, "y": 0, "z": 100}


def test_go_to_inside_the_box_but_beyond_the_motors_is_a_422_and_nothing_moves(http):
    before = http.get("/world/properties/poses").json()["joints"]["uarm"]
    r = http.post("/uarm/actions/goTo", json={"x": 120, "y": 0, "z": 100})
    assert r.status_code == 422 and r.headers["content-type"].startswith(PROBLEM)
    assert "lower arm" in r.json()["detail"] and r.json()["reason"] == "unreachable"
    assert http.get("/world/properties/poses").json()["joints"]["uarm"] == before


def test_moves_return_when_they_are_over_and_location_follows(http):
    assert http.post("/uarm/actions/goTo", json={"x": 150, "y": -100, "z": 60}).status_code == 204
    assert http.get("/uarm/properties/location").json() == {"x": 150, "y": -100, "z": 60}
    assert http.post("/uarm/actions/turnLeft").json() == {"y": -90}
    assert http.post("/uarm/actions/turnRight", json={"y": 0}).status_code == 204  # y is ignored: one step
    assert http.post("/uarm/actions/go", json={"x": 160, "y": 0, "z": 90, "speed": 5000}).status_code == 204
    assert http.get("/uarm/properties/location").json() == {"x": 160, "y": 0, "z": 90}
    assert http.put("/uarm/properties/homeLoc", json={"x": 250, "y": 0, "z": 100}).status_code == 204
    assert http.post("/uarm/actions/goHome").status_code == 204
    assert http.get("/uarm/properties/location").json() == {"x": 250, "y": 0, "z": 100}  # beyond the goTo box
    r = http.put("/uarm/properties/homeLoc", json={"x": 50, "y": 0, "z": 100})  # in the schema, out of reach
    assert r.status_code == 422 and r.headers["content-type"].startswith(PROBLEM)
    assert http.post("/uarm/actions/reset").status_code == 204
    assert http.get("/uarm/properties/location").json() == {"x": 250, "y": 0, "z": 100}


def test_stop_belt_on_a_stopped_belt_is_harmless_and_the_outputs_are_the_real_ones(http, client):
    for _ in range(2):
        r = http.post("/conveyor-belt-1/actions/stopBelt")
        assert r.status_code == 200 and r.json() == "Conveyor belt stopped"
    assert http.post("/conveyor-belt-1/actions/startBeltForward").json() == "Conveyor belt started forwards"
    assert http.post("/conveyor-belt-2/actions/startBeltBackward").json() == "Conveyor belt started"
    states = client.read("world", "poses")["states"]  # (the adapter may serve the last publication, 50 ms old)
    assert states["conveyor-belt-1"]["direction"] == "forward" and states["conveyor-belt-2"]["direction"] == "backward"
    for belt in ("conveyor-belt-1", "conveyor-belt-2"):
        assert http.post(f"/{belt}/actions/stopBelt").status_code == 200


def test_belt_speed_is_an_integer_from_1_to_100(http):
    assert http.put("/conveyor-belt-2/properties/speed", json=40).status_code == 204
    assert http.get("/conveyor-belt-2/properties/speed").json() == 40
    for bad in (0, 101, 2.5, "50"):
        assert http.put("/conveyor-belt-2/properties/speed", json=bad).status_code == 400
    assert http.get("/conveyor-belt-2/properties/speed").json() == 40


def test_get_cube_from_an_empty_warehouse_is_a_422_naming_it_and_the_dobot_stays_put(http):
    assert http.post("/world/actions/resetWarehouse", json={"cubes": 0}).status_code == 204
    before = http.get("/dobot/properties/position").json()
    r = http.post("/dobot/actions/getCube")
    assert r.status_code == 422 and r.headers["content-type"].startswith(PROBLEM)
    problem = r.json()
    assert "warehouse is empty" in problem["detail"] and problem["reason"] == "empty-warehouse"
    assert http.get("/dobot/properties/position").json() == before
    r = http.post("/dobot/actions/returnCube")
    assert r.status_code == 422 and "no cube at the end of conveyor belt 1" in r.json()["detail"]


def test_object_presence_is_a_reading_its_td_offers_no_write_and_a_put_gets_405(http):
    prop = http.get("/infrared-sensor-1").json()["properties"]["objectPresence"]
    assert prop["readOnly"] is True and not any("writeproperty" in f["op"] for f in prop["forms"])
    assert http.get("/infrared-sensor-1/properties/objectPresence").json() is False
    r = http.put("/infrared-sensor-1/properties/objectPresence", json=True)
    assert r.status_code == 405 and "PUT" not in r.headers["allow"] and "GET" in r.headers["allow"]
    assert r.headers["content-type"] == "application/problem+json"
    assert http.get("/infrared-sensor-1/properties/objectPresence").json() is False


def _drain(q: queue.Queue, quiet: float, limit: float = 10.0) -> list:
    """Everything queued until nothing came for `quiet` s (an error if that takes over `limit` s)."""
    got, deadline = [], time.monotonic() + limit
    while time.monotonic() < deadline:
        try:
            got.append(q.get(timeout=quiet))
        except queue.Empty:
            return got
    raise AssertionError(f"still publishing after {limit} s ({len(got)} publications)")


def test_world_publishes_poses_of_both_robots_and_the_cubes_throttled_and_ends_on_the_final_state(http, client):
    from devices.sim.compensation import DOBOT_MAIN_JOINTS, DOBOT_PASSIVE_JOINTS, UARM_MAIN_JOINTS, UARM_PASSIVE_JOINTS
    from mesh.messages.scene_description import Poses

    q: queue.Queue = queue.Queue()
    sub = client.observe("world", "poses", q.put)
    try:
        _drain(q, 0.3)
        assert http.put("/world/properties/speed", json=2).status_code == 204  # a motion of ~1.4 s wall
        assert http.get("/world/properties/speed").json() == 2
        t0 = time.monotonic()
        assert http.post("/uarm/actions/goTo", json={"x": 150, "y": -150, "z": 60}).status_code == 204
        wall = time.monotonic() - t0
        got = [msgspec.convert(p, Poses) for p in _drain(q, 0.5)]
    finally:
        sub.undeclare()
        http.put("/world/properties/speed", json=0)
    assert http.get("/world/properties/speed").json() == 0
    assert wall > 1.0 and 10 <= len(got) <= 20 * wall + 3, (len(got), wall)
    assert all(a.time < b.time for a, b in zip(got, got[1:]))
    last = got[-1]
    assert set(UARM_MAIN_JOINTS + UARM_PASSIVE_JOINTS) <= set(last.joints["uarm"])
    assert set(DOBOT_MAIN_JOINTS + DOBOT_PASSIVE_JOINTS) <= set(last.joints["dobot"])
    assert {"cube-red", "cube-green", "cube-blue", "cube-yellow", "dobot", "uarm"} <= set(last.bodies)
    now = msgspec.convert(client.read("world", "poses"), Poses)
    assert now.time >= last.time
    for joint, value in now.joints["uarm"].items():  # the last publication is the final state
        assert last.joints["uarm"][joint] == pytest.approx(value, abs=1e-4), joint
    assert last.states["uarm"]["location"] == {"x": 150, "y": -150, "z": 60}


def test_poses_are_quiet_when_nothing_moves(http, client):
    q: queue.Queue = queue.Queue()
    sub = client.observe("world", "poses", q.put)
    try:
        _drain(q, 0.3)
        # silence for a second, the world stepping in real time meanwhile: the window is the claim
        always(lambda: q.qsize() == 0, 1.0, what="no pose published while nothing moves")
        assert http.post("/conveyor-belt-1/actions/stopBelt").status_code == 200  # no motion, no pose
        assert _drain(q, 0.3) == []
    finally:
        sub.undeclare()
    t0 = http.get("/world/properties/simTime").json()
    t1 = http.get("/world/properties/simTime").json()
    assert 0 < t0 <= t1


def test_scene_json_describes_robots_static_and_moving_bodies_and_the_urdfs_download(http):
    from mesh.messages.scene_description import SceneDescription

    r = http.get("/world/files/scene.json")
    assert r.status_code == 200 and r.headers["content-type"].startswith("application/json")
    scene = msgspec.json.decode(r.content, type=SceneDescription)
    assert scene.name == "iot-platform"
    assert {(robot.name, robot.urdf) for robot in scene.robots} == {("uarm", "uarm.urdf"), ("dobot", "dobot.urdf")}
    uarm = next(robot for robot in scene.robots if robot.name == "uarm")
    assert uarm.base.p == pytest.approx((-0.375, 0.0, 0.75))
    moving = {b.name: b for b in scene.bodies if b.moving}
    assert set(moving) == {"cube-red", "cube-green", "cube-blue", "cube-yellow"}
    assert moving["cube-red"].size == pytest.approx((0.028,) * 3) and moving["cube-red"].color[0] > 0.8
    static = {b.name for b in scene.bodies if not b.moving}
    assert {"table", "warehouse", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2",
            "color-sensor", "dobot-track"} <= static
    for robot in scene.robots:
        r = http.get(f"/world/files/{robot.urdf}")
        assert r.status_code == 200 and b"<robot name=" in r.content


def test_reset_with_fewer_cubes_sets_the_others_aside_and_reset_brings_them_back(http):
    assert http.post("/world/actions/resetWarehouse", json={"cubes": 2}).status_code == 204
    poses = http.get("/world/properties/poses").json()
    assert poses["states"]["dobot"]["queue"] == ["cube-red", "cube-green"]
    aside = np.array(poses["bodies"]["cube-blue"][0])
    assert aside[2] == pytest.approx(0.75 + 0.014, abs=0.002)  # resting on the table
    assert http.post("/world/actions/resetWarehouse", json={"cubes": 9}).status_code == 400
    assert http.post("/world/actions/reset").status_code == 204
    queue_ = http.get("/world/properties/poses").json()["states"]["dobot"]["queue"]
    assert queue_ == ["cube-red", "cube-green", "cube-blue", "cube-yellow"]


def test_an_idle_world_at_speed_max_does_not_burn_a_core(lab, http):
    procs = [psutil.Process(lab.proc.pid), *psutil.Process(lab.proc.pid).children(recursive=True)]
    for p in procs:
        p.cpu_percent(None)
    time.sleep(2.0)
    total = sum(p.cpu_percent(None) for p in procs)
    assert total < 50, f"the idle lab used {total:.0f} % of a core"


@pytest.mark.parametrize("speed, status", [(1e-13, 400), (1e-9, 400), (0.001, 400), (1e9, 400), (-1, 400)])
def test_a_speed_that_would_freeze_or_kill_the_simulation_is_refused(http, speed, status):
    """1e-13 used to kill the stepping thread ("timestamp out of range") and 1e-9 froze every motion."""
    r = http.put("/world/properties/speed", json=speed)
    assert r.status_code == status and "speed" in r.json()["detail"], r.text
    assert http.get("/world/properties/speed").json() == 0  # still `max`, as the lab was started
    assert http.get("/world/properties/stepping").json() is True
    assert http.post("/uarm/actions/goTo", json={"x": 150, "y": 0, "z": 80}).status_code == 204  # still moving
