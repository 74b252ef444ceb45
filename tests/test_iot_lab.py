"""The iot-lab scene end to end: `twinmesh up` with no scene, every device listed and served, the UR10
behind its safety wall, box obstacles that regenerate the UR10's workspace, the pan-tilts' colour
sensors and the lamps, over HTTP as a WoT client sees them.

The session's iot-lab (`twinmesh up --speed max --samples 4000`, conftest.py's `iot_lab`), its room reset for
the module: the UR10's twin may have changed before (its version counts every change of its scene), so each
test counts from the version it finds.
"""
from __future__ import annotations

import json
import math
import queue
import threading
import time

import httpx
import numpy as np
import pytest
from tdschema import assert_valid_td
from waiting import always

from devices.sim.robot_twin import workspace_from_csv
from mesh.messages.relations import POINTS, SCENE
from tdgen.robot.workspace_check import DEFAULT_K, DEFAULT_RADIUS_MM

pytestmark = pytest.mark.lab  # on the session's iot-lab, with the others conftest.SHARED_LAB names

PROBLEM = "application/problem+json"
LISTED = {"dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2", "color-sensor",
          "uarm", "ur10", "light-left", "light-right", "pan-tilt-1", "pan-tilt-2"}
CRATE = {"name": "crate", "size": [0.3, 0.3, 0.3], "position": [2.3, -0.42, 0.9]}  # on the UR10's table, beside it


@pytest.fixture(scope="module")
def lab(iot_lab):
    return iot_lab  # the session's iot-lab, its room reset, lent to this module (conftest.py)


@pytest.fixture
def http(lab):
    with httpx.Client(base_url=lab.http, timeout=120) as h:
        yield h


def ur10_td(http: httpx.Client, version: int, timeout: float = 120.0) -> dict:
    """The UR10's TD once the generated one for twin `version` is served."""
    deadline = time.monotonic() + timeout
    td: dict = {}
    while time.monotonic() < deadline:
        td = http.get("/ur10").json()
        if td.get("version", {}).get("instance") == str(version) and _links(td).get(POINTS):
            return td
        time.sleep(0.05)
    raise AssertionError(f"no generated ur10 TD for version {version} within {timeout} s; last: {td.get('version')}")


def twin_version(http: httpx.Client) -> int:
    """The UR10 twin's version now (bumped by every change of its scene; twin.json leaves out its default, 0)."""
    return http.get("/ur10/files/twin.json").json().get("version", 0)


def _links(td: dict) -> dict[str, str]:
    return {link["rel"]: link["href"] for link in td.get("links", [])}


def _points(http: httpx.Client, td: dict):
    return workspace_from_csv(http.get(_links(td)[POINTS]).content)


def long_poll(url: str) -> queue.Queue:
    """GET `url` (a long-poll observe or event form) in a thread; the response lands in the queue."""
    out: queue.Queue = queue.Queue()

    def get() -> None:
        try:
            out.put(httpx.get(url, timeout=120))
        except httpx.HTTPError as e:
            out.put(e)

    threading.Thread(target=get, daemon=True).start()
    time.sleep(0.3)  # the request is registered before what it waits for happens
    return out


def sse(url: str) -> queue.Queue:
    """Every event of an SSE form (`.../sse`), decoded, into a queue, from a thread (for the module's life)."""
    out: queue.Queue = queue.Queue()
    opened = threading.Event()  # at the stream's first line: the adapter registers it before it answers

    def read() -> None:
        with httpx.stream("GET", url, timeout=None) as r:
            for line in r.iter_lines():
                opened.set()
                if line.startswith("data:"):
                    out.put(json.loads(line[5:]))

    threading.Thread(target=read, daemon=True).start()
    assert opened.wait(60), f"{url}: the stream did not open"
    return out


def wait_for(events: queue.Queue, accept, timeout: float = 30.0):
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        try:
            item = events.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            break
        seen.append(item)
        if accept(item):
            return item
    raise AssertionError(f"nothing accepted within {timeout} s; seen {seen}")


def test_up_without_a_scene_starts_the_iot_lab_with_every_device(lab, http):
    assert "twinmesh lab 'iot-lab'" in lab.log.read_text()
    listed = set(lab.cli("things", check=True).stdout.split())
    assert LISTED <= listed, sorted(LISTED - listed)
    for name in sorted(LISTED | {"world"}):
        assert_valid_td(http.get(f"/{name}").json())
    scene = http.get("/world/files/scene.json").json()
    assert {r["name"] for r in scene["robots"]} == {"uarm", "dobot", "ur10", "pan-tilt-1", "pan-tilt-2"}
    bodies = {b["name"]: b for b in scene["bodies"]}
    assert bodies["safety-wall"]["opacity"] < 1 and "top-table" in bodies and "ur10-table" in bodies
    for robot in scene["robots"]:  # each robot's URDF is a file of the world
        assert http.get(f"/world/files/{robot['urdf']}").text.lstrip().startswith("<")


def test_the_ur10_cannot_reach_past_its_safety_wall(lab, http):
    td = ur10_td(http, twin_version(http))
    # the UR10 stands at x = 2.3 m facing -x; the wall is at x = 1.45 m: 850 mm ahead in the TD frame
    assert td["properties"]["getCartesianposition"]["properties"]["x"]["maximum"] < 850
    before = http.get("/ur10/properties/getJointposition").json()
    # past the wall is past the TD's bounds: the adapter refuses it against the input schema
    r = http.post("/ur10/actions/moveToCartesianPosition", json={"x": 1000, "y": 0, "z": 300})
    assert r.status_code == 400 and r.headers["content-type"].startswith(PROBLEM)
    assert "maximum" in r.json()["detail"]
    assert http.get("/ur10/properties/getJointposition").json() == before


def test_an_obstacle_shrinks_the_ur10s_workspace_and_observers_notice(lab, http):
    version = twin_version(http)
    td0 = ur10_td(http, version)
    points0 = _points(http, td0)
    obstacles = long_poll(f"{lab.http}/world/properties/obstacles/observable")
    twin_changed = long_poll(f"{lab.http}/ur10/events/twinChanged")
    world_version = http.get("/world").json()["version"]["instance"]

    r = http.post("/world/actions/addObstacle", json=CRATE)
    assert r.status_code in (200, 204), r.text
    assert [o["name"] for o in obstacles.get(timeout=30).json()] == ["crate"]
    assert twin_changed.get(timeout=30).json() == {"robot": "ur10", "version": version + 1}
    assert http.get("/world").json()["version"]["instance"] != world_version  # the recorder reloads the scene
    assert "obstacle-crate" in {b["name"] for b in http.get("/world/files/scene.json").json()["bodies"]}

    td1 = ur10_td(http, version + 1)
    points1 = _points(http, td1)
    free0, free1 = ~points0.collision, ~points1.collision
    assert len(points1.positions) == len(points0.positions)  # the same sampled configurations...
    assert free1.sum() < free0.sum()                           # ...fewer of them collision-free now
    assert not (free1 & ~free0).any()                          # and none freed by adding a box
    assert "obstacle-crate" in http.get(_links(td1)[SCENE]).text

    # a target that was free before and lies in the crate now is refused, and the robot stays put
    centre = ur10_frame(CRATE["position"])
    inside = points0.positions[free0 & (np.abs(points0.positions - centre).max(axis=1) < 120)]
    assert len(inside), "no sampled point inside the crate"
    target = dict(zip("xyz", map(float, inside[0])))
    before = http.get("/ur10/properties/getJointposition").json()
    r = http.post("/ur10/actions/moveToCartesianPosition", json=target)
    assert r.status_code == 422 and r.json()["reason"] in ("collision", "no-path", "outside-workspace"), r.text
    assert http.get("/ur10/properties/getJointposition").json() == before

    r = http.post("/world/actions/removeObstacle", json={"name": "crate"})
    assert r.status_code == 200 and r.json()["name"] == "crate"
    td2 = ur10_td(http, version + 2)
    assert np.array_equal(_points(http, td2).collision, points0.collision)  # the same surroundings again
    assert http.get("/world/properties/obstacles").json() == []


def test_a_box_reaches_the_ur10s_td_by_a_live_update_and_the_next_plan_is_checked_against_it(lab, http):
    """The tdgen service follows the box by a live update (only the samples it can touch checked), and a
    plan asked right after `addObstacle` returns, before anyone has seen the new TD, is answered from the
    new scene's workspace: the collision probability of the target's sampled neighbours is the new one."""
    version = twin_version(http)
    points0 = _points(http, ur10_td(http, version))
    crate = {**CRATE, "name": "live-crate"}
    free0 = ~points0.collision
    inside = points0.positions[free0 & (np.abs(points0.positions - ur10_frame(crate["position"])).max(axis=1) < 120)]
    target = inside[0]
    before = points0.check(target, DEFAULT_K, DEFAULT_RADIUS_MM, 1.0).collision_probability

    assert http.post("/world/actions/addObstacle", json=crate).status_code in (200, 204)
    answer = http.post("/ur10/actions/planMove", json=dict(zip("xyz", map(float, target)))).json()
    answer = answer.get("extra", answer)  # refused (422: the box is there) or planned
    points1 = _points(http, ur10_td(http, version + 1))
    after = points1.check(target, DEFAULT_K, DEFAULT_RADIUS_MM, 1.0).collision_probability
    assert after != before, "the box changed no neighbour of the target"
    assert answer["collision_probability"] == pytest.approx(after), answer
    status = http.get("/tdgen/properties/robots").json()["ur10"]
    assert status["version"] == version + 1 and status.get("live") is True, status
    assert http.post("/world/actions/removeObstacle", json={"name": "live-crate"}).status_code == 200
    assert np.array_equal(_points(http, ur10_td(http, version + 2)).collision, points0.collision)


def ur10_frame(scene_xyz: list[float]) -> np.ndarray:
    """A scene point (m) in the UR10's TD frame (mm): base at (2.3, 0, 0.75), turned 180 deg."""
    x, y, z = scene_xyz
    return np.array([2.3 - x, -y, z - 0.75]) * 1000


def test_bad_obstacles_are_refused_and_nothing_changes(lab, http):
    version = twin_version(http)
    through_the_robot = {"name": "pillar", "size": [0.2, 0.2, 0.4], "position": [2.3, 0.0, 0.9]}
    r = http.post("/world/actions/addObstacle", json=through_the_robot)
    assert r.status_code == 422 and r.headers["content-type"].startswith(PROBLEM)
    assert r.json()["reason"] == "obstacle-hits-robot"
    r = http.post("/world/actions/removeObstacle", json={"name": "nothing-here"})
    assert r.status_code == 422 and r.json()["reason"] == "no-such-obstacle"
    assert twin_version(http) == version  # the refusals changed nothing
    for bad in ({**CRATE, "size": [0.3, -0.3, 0.3]}, {**CRATE, "name": "Not A Slug"}, {"name": "x"}):
        r = http.post("/world/actions/addObstacle", json=bad)
        assert r.status_code == 400 and r.headers["content-type"].startswith(PROBLEM), bad
    assert http.post("/world/actions/addObstacle", json=CRATE).status_code in (200, 204)
    r = http.post("/world/actions/addObstacle", json=CRATE)
    assert r.status_code == 422 and r.json()["reason"] == "obstacle-exists"
    assert [o["name"] for o in http.get("/world/properties/obstacles").json()] == ["crate"]
    assert http.post("/world/actions/removeObstacle", json={"name": "crate"}).status_code == 200
    assert http.get("/world/properties/obstacles").json() == []
    assert twin_version(http) == version + 2  # one add, one remove


def test_a_light_switched_on_lights_its_lamp_in_the_world(lab, http):
    assert http.post("/light-left/actions/setColor", json={"r": 0, "g": 1, "b": 0}).status_code == 200
    assert http.post("/light-left/actions/switchOn").status_code in (200, 204)
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline:
        state = http.get("/world/properties/poses").json()["states"].get("light-left")
        if state == {"on": True, "color": [0.0, 1.0, 0.0]}:
            break
        time.sleep(0.05)
    assert state == {"on": True, "color": [0.0, 1.0, 0.0]}
    assert http.get("/world/properties/poses").json()["states"]["light-right"]["on"] is False
    http.post("/light-left/actions/switchOff")


def aim(unit: dict, target: list[float]) -> tuple[float, float]:
    """(pan, tilt) deg that point a pan-tilt standing at `unit` (scene.json robot) at a scene point;
    the lens is 9 cm above the mount (positive pan: left, positive tilt: down)."""
    (x, y, z), (_, _, qz, qw) = unit["base"]
    yaw = 2 * math.atan2(qz, qw)
    dx, dy, dz = target[0] - x, target[1] - y, target[2] - (z + 0.09)
    pan = math.degrees(math.atan2(dy, dx) - yaw)
    return (pan + 180) % 360 - 180, -math.degrees(math.atan2(dz, math.hypot(dx, dy)))


def test_a_pan_tilt_aimed_at_a_colour_card_detects_its_colour(lab, http):
    scene = http.get("/world/files/scene.json").json()
    unit = next(r for r in scene["robots"] if r["name"] == "pan-tilt-1")
    cards = {b["name"]: b for b in scene["bodies"] if b["name"].startswith("chart-")}
    assert set(cards) == {"chart-red", "chart-green", "chart-blue", "chart-yellow"}
    detected = sse(f"{lab.http}/pan-tilt-1/events/detectColor/sse")
    for card, channel in (("chart-red", 0), ("chart-blue", 2)):
        pan, tilt = aim(unit, cards[card]["pose"][0])
        r = http.post("/pan-tilt-1/actions/moveTo", json={"panAngle": round(pan, 3), "tiltAngle": round(tilt, 3)})
        assert r.status_code in (200, 204), r.text
        assert http.get("/pan-tilt-1/properties/panPosition").json() == pytest.approx(round(pan, 3), abs=1e-6)
        assert http.get("/pan-tilt-1/properties/tiltPosition").json() == pytest.approx(round(tilt, 3), abs=1e-6)
        seen = wait_for(detected, lambda e: e.get("object") == card)  # what it passed on the way came first
        assert max(range(3), key=lambda i: seen["color"][i]) == channel, seen
    # the world's poses (throttled, so a moment later) animate the unit's URDF joints for the recorder
    expected = pytest.approx(math.radians(round(pan, 3)), abs=1e-6)
    deadline = time.monotonic() + 10
    while http.get("/world/properties/poses").json()["joints"]["pan-tilt-1"]["pan"] != expected:
        assert time.monotonic() < deadline, "the world's poses never showed the pan-tilt's final pan"
        time.sleep(0.05)


def test_a_pan_tilt_refuses_angles_out_of_range_and_pans_until_stopped(lab, http):
    assert http.post("/pan-tilt-2/actions/goHome").status_code in (200, 204)
    r = http.post("/pan-tilt-2/actions/moveTo", json={"panAngle": 100, "tiltAngle": 0})
    assert r.status_code == 400 and r.headers["content-type"].startswith(PROBLEM)
    assert http.post("/pan-tilt-2/actions/panContinuously", json=16).status_code == 400
    assert http.get("/pan-tilt-2/properties/panPosition").json() == 0
    http.put("/world/properties/speed", json=1)  # real time, so that the pan can be caught half-way
    try:
        assert http.post("/pan-tilt-2/actions/panContinuously", json=-15).status_code in (200, 204)
        time.sleep(0.5)
        assert http.post("/pan-tilt-2/actions/stopMovement").status_code in (200, 204)
        stopped = http.get("/pan-tilt-2/properties/panPosition").json()
        assert -90 < stopped < 0
        always(lambda: http.get("/pan-tilt-2/properties/panPosition").json() == stopped, 0.3,
               what="the pan stays where it stopped")
    finally:
        http.put("/world/properties/speed", json=0)
    assert http.post("/pan-tilt-2/actions/panContinuously", json=15).status_code in (200, 204)
    deadline = time.monotonic() + 30
    while http.get("/pan-tilt-2/properties/panPosition").json() != 90 and time.monotonic() < deadline:
        time.sleep(0.05)
    assert http.get("/pan-tilt-2/properties/panPosition").json() == 90  # stopped at the limit


def test_the_cube_workflow_runs_unchanged_on_the_platform_table_in_the_room(lab, http):
    run = lab.cli("workflow", "cube", "--via", lab.http, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "the cube is red [" in run.stdout  # the first cube of the queue, read by the colour sensor
    (x, y, z), _ = http.get("/world/properties/poses").json()["bodies"]["cube-red"]
    # back in the warehouse tray (x = 640 mm in the uArm frame, whose origin is at x = -0.375 m), on the table
    assert abs(x - (-0.375 + 0.640)) < 0.03 and abs(y) < 0.13 and 0.75 < z < 0.8
