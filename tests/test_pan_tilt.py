"""The pan-tilt unit twin: its moves, its continuous pan, its colour-sensor camera, its TD and its Thing.

Real pybullet worlds at speed max (simulated time as fast as the CPU allows): a test waits on
motions and on simulated time (`world.wait`), never on the wall clock.
"""
from __future__ import annotations

import json
import math
import queue
import time
from contextlib import ExitStack

import msgspec
import numpy as np
import pytest
from labs import free_port
from tdschema import assert_valid_td
from waiting import eventually, subscribed

from devices.sim.pan_tilt import NOTHING, PanTilt
from devices.sim.pybullet_world import World, static_box
from devices.sim.sensors import reading_of
from devices.things.binding import serve
from devices.things.pan_tilt import bind_pan_tilt, pan_tilt_td
from mesh.wot.problem import BadInput, Problem
from mesh.wot.thing_description import thing_id, zenoh_forms

BASE = (0.0, 0.0, 0.75)        # the unit stands on a table, looking along +x at home
CAMERA_Z = BASE[2] + 0.09      # the tilt axis, 9 cm above the mount
RED, BLUE = (1.0, 0.125, 0.125), (0.125, 0.25, 1.0)  # exact in float32, as pybullet keeps colours
RED_AT, BLUE_AT = 30.0, -40.0  # pan angles (deg) where the boxes stand


@pytest.fixture
def world():
    w = World(speed=None)
    yield w
    w.close()


@pytest.fixture
def names() -> dict[int, str]:
    return {}


@pytest.fixture
def unit(world, names) -> PanTilt:
    u = PanTilt(world, "pan-tilt-1", BASE, names=lambda: names)
    world.start()
    return u


def add_box(world: World, names: dict[int, str], name: str, pan_deg: float, rgb, distance: float = 1.0) -> int:
    """A static 20 cm box `distance` m away in the direction the unit looks at pan `pan_deg`, tilt 0,
    a face towards the unit."""
    a = math.radians(pan_deg)
    pos = (BASE[0] + distance * math.cos(a), BASE[1] + distance * math.sin(a), CAMERA_Z)
    orn = (0.0, 0.0, math.sin(a / 2), math.cos(a / 2))
    body = world.run(lambda: static_box(world.client, (0.1, 0.1, 0.1), pos, orn, rgba=(*rgb, 1)))
    names[body] = name
    return body


def look_axis(unit: PanTilt) -> np.ndarray:
    import pybullet as pb

    _, orn = unit.world.run(lambda: unit.arm.link_pose("camera"))
    return np.array(pb.getMatrixFromQuaternion(orn)).reshape(3, 3)[:, 0]


# --- moves -------------------------------------------------------------------------------------------
def test_move_to_reaches_both_angles_and_the_snapshot_joints_agree(unit, world):
    unit.move_to(37.5, -12.25)
    assert unit.pan == pytest.approx(37.5, abs=0.01) and unit.tilt == pytest.approx(-12.25, abs=0.01)
    snap = world.snapshot()
    assert set(snap.joints["pan-tilt-1"]) == {"pan", "tilt"}  # the URDF's joint names
    assert snap.joints["pan-tilt-1"]["pan"] == pytest.approx(math.radians(unit.pan), abs=1e-9)
    assert snap.joints["pan-tilt-1"]["tilt"] == pytest.approx(math.radians(unit.tilt), abs=1e-9)
    state = snap.states["pan-tilt-1"]
    assert state["pan"] == unit.pan and state["tilt"] == unit.tilt and state["panning"] == 0
    unit.pan_to(-20)
    assert unit.angles() == pytest.approx((-20, -12.25), abs=0.01)
    unit.tilt_to(80)
    assert unit.angles() == pytest.approx((-20, 80), abs=0.01)
    unit.go_home()
    assert unit.angles() == (0.0, 0.0)


def test_a_move_takes_simulated_time_at_a_bounded_speed(unit, world):
    t0 = world.time
    unit.move_to(60, 0)
    assert world.time - t0 >= 1.0  # 60 deg at no more than 60 deg/s


def test_positive_tilt_looks_down_and_positive_pan_looks_left(unit):
    assert look_axis(unit) == pytest.approx([1, 0, 0], abs=1e-6)
    unit.tilt_to(30)
    assert look_axis(unit)[2] == pytest.approx(-math.sin(math.radians(30)), abs=1e-6)
    unit.move_to(30, 0)
    assert look_axis(unit)[1] == pytest.approx(math.sin(math.radians(30)), abs=1e-6)  # +y: left of +x


@pytest.mark.parametrize("call", [lambda u: u.move_to(90.5, 0), lambda u: u.move_to(0, -80.01),
                                  lambda u: u.pan_to(-91), lambda u: u.tilt_to(100),
                                  lambda u: u.move_to(float("nan"), 0), lambda u: u.pan_to("10"),
                                  lambda u: u.pan_continuously(15.5), lambda u: u.pan_continuously(-16)])
def test_out_of_range_input_is_bad_input_and_nothing_moves(unit, world, call):
    unit.move_to(10, 5)
    before = world.snapshot().joints["pan-tilt-1"]
    with pytest.raises(BadInput) as err:
        call(unit)
    assert "pan-tilt-1" in str(err.value) and "must be" in str(err.value)
    world.wait(0.5)
    assert world.snapshot().joints["pan-tilt-1"] == before
    assert unit.angles() == pytest.approx((10, 5), abs=1e-9) and unit.panning == 0


# --- continuous pan ----------------------------------------------------------------------------------
def test_pan_continuously_then_stop_movement_stops_between_start_and_the_limit_and_stays(unit, world):
    unit.pan_continuously(15)
    assert unit.panning == 15
    world.wait(2.0)
    unit.stop_movement()
    stopped = unit.pan
    assert 0 < stopped < 90 and unit.panning == 0
    world.wait(1.0)
    assert unit.pan == stopped
    unit.stop_movement()  # nothing to stop: harmless
    assert unit.pan == stopped


def test_pan_continuously_stops_exactly_at_the_limit(unit, world):
    unit.pan_to(80)
    unit.pan_continuously(15)
    world.wait(1.0)  # 10 deg at 15 deg/s take 0.67 s
    assert abs(unit.degrees()[0] - 90) <= 1e-6 and unit.panning == 0
    unit.pan_continuously(-15)  # and back the other way, to the other limit
    world.wait(13.0)
    assert abs(unit.degrees()[0] + 90) <= 1e-6 and unit.panning == 0
    assert unit.tilt == 0


def test_a_second_pan_replaces_the_speed_and_a_move_stops_the_pan(unit, world):
    unit.pan_continuously(15)
    world.wait(1.0)
    unit.pan_continuously(-10)
    assert unit.panning == -10
    before = unit.pan
    world.wait(1.0)
    assert unit.pan < before
    unit.move_to(-10, 20)
    assert unit.panning == 0
    world.wait(1.0)
    assert unit.angles() == pytest.approx((-10, 20), abs=1e-6)


# --- the camera's colour sensor ----------------------------------------------------------------------
def test_nothing_in_sight_is_the_dark_room(unit):
    assert unit.color() == NOTHING
    assert NOTHING.color == [0, 0, 0] and NOTHING.object is None and NOTHING.distance is None


def test_the_colour_sensor_reports_the_box_in_sight_and_tells_each_change_in_order(unit, world, names):
    red = add_box(world, names, "red-box", RED_AT, RED)
    add_box(world, names, "blue-box", BLUE_AT, BLUE, distance=1.5)
    anonymous = world.run(lambda: static_box(world.client, (0.1, 0.1, 0.1), (-1.0, 0, CAMERA_Z)))  # behind
    seen: queue.Queue = queue.Queue()
    unsubscribe = unit.on_color(seen.put)

    unit.pan_to(RED_AT)
    red_seen = unit.color()
    assert red_seen.color == reading_of(RED).color and red_seen.object == "red-box"
    assert red_seen.distance == pytest.approx(0.9 - 0.04, abs=0.01)  # box face 0.9 m out, lens 4 cm out
    unit.pan_to(BLUE_AT)
    blue_seen = unit.color()
    assert blue_seen.color == reading_of(BLUE).color and blue_seen.object == "blue-box"

    events = []
    deadline = time.monotonic() + 10
    while not any(e.object == "blue-box" for e in events) and time.monotonic() < deadline:
        try:
            events.append(seen.get(timeout=0.5))
        except queue.Empty:
            pass
    assert [e.object for e in events if e.object] == ["red-box", "blue-box"]
    assert [e.color for e in events if e.object] == [reading_of(RED).color, reading_of(BLUE).color]
    assert NOTHING in events  # the sky between the two boxes
    assert world.snapshot().states["pan-tilt-1"]["object"] == "blue-box"

    unsubscribe()
    unit.pan_to(RED_AT)
    world.wait(0.2)
    assert seen.empty()  # unsubscribed
    del names[red]  # a body the scene does not name goes by its pybullet name, else body-<id>
    assert unit.color().object == f"body-{red}"
    assert anonymous not in names


def test_the_same_colour_on_another_body_is_a_change(unit, world, names):
    add_box(world, names, "red-1", 20, RED)
    add_box(world, names, "red-2", -20, RED)
    seen: queue.Queue = queue.Queue()
    unit.on_color(seen.put)
    unit.pan_to(20)
    unit.pan_to(-20)
    objects = []
    deadline = time.monotonic() + 10
    while "red-2" not in objects and time.monotonic() < deadline:
        try:
            objects.append(seen.get(timeout=0.5).object)
        except queue.Empty:
            pass
    assert [o for o in objects if o] == ["red-1", "red-2"]


# --- the TD ------------------------------------------------------------------------------------------
def test_the_td_is_valid_and_keeps_the_reference_affordances_and_inputs():
    from pathlib import Path

    tds = Path(__file__).resolve().parents[1] / "devices" / "things" / "tds"
    reference = json.loads((tds / "pan-tilt.json").read_text())
    td = pan_tilt_td("pan-tilt-1")
    served = msgspec.to_builtins(zenoh_forms(td, "wot", "pan-tilt-1"))
    assert_valid_td(served)
    assert served["id"] == thing_id("pan-tilt-1") and served["title"] == "pan-tilt-1"
    assert set(served["properties"]) == set(reference["properties"])
    assert set(served["actions"]) == set(reference["actions"])
    assert set(served["events"]) == {"detectColor"}
    for name, action in reference["actions"].items():
        assert served["actions"][name].get("input") == action.get("input"), name
        assert served["actions"][name]["synchronous"] is (name != "panContinuously"), name
    for name in ("panPosition", "tiltPosition"):
        assert served["properties"][name]["observable"] is True
        assert {k: v for k, v in served["properties"][name].items() if k not in ("observable", "forms")} \
            == {k: v for k, v in reference["properties"][name].items() if k != "observable"}
    data = served["events"]["detectColor"]["data"]
    assert data["required"] == ["color", "object"]
    assert set(data["properties"]) == {"color", "object", "distance"}
    assert "camera" in served["description"] and "observable" in served["description"]


# --- on a mesh ---------------------------------------------------------------------------------------
@pytest.fixture
def mesh():
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    settings = MeshSettings(connect=(f"tcp/127.0.0.1:{free_port()}",))
    with open_session(settings.as_router()):
        yield settings


def test_on_the_mesh_move_to_answers_when_there_with_the_final_position_published(mesh, unit, world, names):
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.server import ExposedThing
    from mesh.fabric.session import open_session

    add_box(world, names, "red-box", RED_AT, RED)
    positions: queue.Queue = queue.Queue()
    colours: queue.Queue = queue.Queue()
    with ExitStack() as stack:
        thing = ExposedThing(stack.enter_context(open_session(mesh)), pan_tilt_td("pan-tilt-1"), "pan-tilt-1", mesh.keys)
        serve(stack, thing, bind_pan_tilt(thing, unit))
        client = MeshClient(stack.enter_context(open_session(mesh)), mesh)
        eventually(lambda: client.is_alive("pan-tilt-1"), timeout=10, what="pan-tilt-1 alive")
        client.observe("pan-tilt-1", "panPosition", positions.put)
        client.subscribe("pan-tilt-1", "detectColor", colours.put)
        subscribed(thing.session, mesh.keys.property("pan-tilt-1", "panPosition"))  # as the Thing's session sees it
        subscribed(thing.session, mesh.keys.event("pan-tilt-1", "detectColor"))

        assert client.invoke("pan-tilt-1", "moveTo", {"panAngle": RED_AT, "tiltAngle": 0}) is None
        assert client.read("pan-tilt-1", "panPosition") == RED_AT
        assert client.read("pan-tilt-1", "tiltPosition") == 0
        published = [positions.get(timeout=5)]
        while published[-1] != RED_AT:
            published.append(positions.get(timeout=5))
        assert published[-1] == RED_AT and len(published) >= 1
        detected = colours.get(timeout=5)
        assert detected["object"] == "red-box" and detected["color"] == reading_of(RED).color

        with pytest.raises(Problem) as err:
            client.invoke("pan-tilt-1", "moveTo", {"panAngle": 100, "tiltAngle": 0})
        assert err.value.status == 400
        with pytest.raises(Problem) as err:
            client.invoke("pan-tilt-1", "panContinuously", 16)
        assert err.value.status == 400
        assert client.invoke("pan-tilt-1", "panContinuously", -15) is None
        while positions.get(timeout=5) >= RED_AT:  # the head turns
            pass
        assert client.invoke("pan-tilt-1", "stopMovement") is None
        stopped = client.read("pan-tilt-1", "panPosition")
        assert -90 <= stopped < RED_AT
        assert client.read("pan-tilt-1", "panPosition") == stopped
