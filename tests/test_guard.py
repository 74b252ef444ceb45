"""`twinmesh up iot-platform --real ...`: the twins guard the real lab's devices (a mock of them: node-wot
servients with the real lab's TDs and a log of every request, tests/interop/real-lab.mjs).

What reached the "real" devices is read from the mock's log: a move the twin refuses never arrives,
an accepted one arrives in the real frame (through a calibration here, so the test can tell), the
real devices down is 503 at once with the twin standing still, and back is business as usual. The
thesis's cube workflow runs unchanged through the guarded twins.
"""
from __future__ import annotations

import subprocess
import time
from pathlib import Path

import httpx
import numpy as np
import pytest
from interop import npm
from labs import free_port, start_lab, twinmesh_cmd

from devices.things.guard import MIRROR_EVERY

pytestmark = [pytest.mark.lab, pytest.mark.interop, pytest.mark.timeout(900)]

CREDENTIALS = {"username": "lab", "password": "guarded"}
AUTH = f"basic:{CREDENTIALS['username']}:{CREDENTIALS['password']}"
OFFSET = np.array([-2.3, 1.6, 0.4])  # mm: the real uArm's frame is the twin's, shifted (a calibration)
REAL = {"uarm": "Uarm", "dobot": "WarehouseDobot", "conveyor-belt-1": "ConveyorBelt1",
        "conveyor-belt-2": "ConveyorBelt2"}


@pytest.fixture(scope="module")
def real_lab():
    with npm.RealLab(CREDENTIALS) as lab:
        yield lab


@pytest.fixture(scope="module")
def lab(tmp_path_factory, real_lab):
    tmp = tmp_path_factory.mktemp("guard")
    calibration = tmp / "uarm-calibration.csv"
    twin = np.array([[120, -150, 60], [200, -150, 60], [120, 150, 60], [200, 150, 100], [160, 0, 80]], float)
    calibration.write_text("twin_x,twin_y,twin_z,real_x,real_y,real_z\n" + "".join(
        ",".join(f"{v:g}" for v in (*t, *(t + OFFSET))) + "\n" for t in twin))
    args = ["--speed", "max", "--real-auth", AUTH, "--real-calibration", f"uarm={calibration}"]
    for slug, td in REAL.items():
        args += ["--real", f"{slug}={real_lab.url(td)}"]
    lab = start_lab(tmp, "iot-platform", things={"uarm", "uarm-real", "dobot-real"}, extra_args=tuple(args))
    yield lab
    lab.stop()


def location(lab, thing: str = "uarm") -> np.ndarray:
    value = httpx.get(f"{lab.http}/{thing}/properties/location", timeout=30).json()
    return np.array([value["x"], value["y"], value["z"]], float)


def mirrored_location(lab) -> np.ndarray:
    """The uArm twin's location once it stands where the real arm says: the mirror reads the real arm
    every MIRROR_EVERY s, and right after the lab starts it may not have yet (the mock's arm is at
    (150, 0, 100), the twin's home at (200, 0, 100); the calibration between them moves a few mm)."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        twin, real = location(lab), location(lab, "uarm-real")
        if np.allclose(twin, real, atol=10):
            return twin
        time.sleep(MIRROR_EVERY)
    raise AssertionError(f"the uArm twin at {twin} never followed its real arm at {real}")


def go_to(lab, x: int, y: int, z: int) -> httpx.Response:
    return httpx.post(f"{lab.http}/uarm/actions/goTo", json={"x": x, "y": y, "z": z}, timeout=120)


def test_the_real_devices_are_on_the_mesh_beside_their_twins(lab):
    listed = set(lab.cli("things").stdout.split())
    assert {"uarm", "uarm-real", "dobot", "dobot-real", "conveyor-belt-1-real", "conveyor-belt-2-real"} <= listed
    real = httpx.get(f"{lab.http}/uarm-real", timeout=30).json()
    assert "beep" in real["actions"] and real["id"] == "urn:dev:ops:32473-UArm-001"


def test_a_move_the_twin_refuses_never_reaches_the_real_robot(lab, real_lab):
    real_lab.clear_log()
    before = mirrored_location(lab)
    r = go_to(lab, 120, 0, 100)  # inside the TD's box, beyond the arm's motors
    assert r.status_code == 422 and r.json()["reason"] == "unreachable", r.text
    r = httpx.post(f"{lab.http}/dobot/actions/returnCube", timeout=120)  # no cube waits at the pickup
    assert r.status_code == 422 and r.json()["reason"] == "no-cube", r.text
    assert real_lab.calls("Uarm", "goTo") == [] and real_lab.calls("Warehouse Dobot") == []
    assert not any(q["path"] in ("/uarm/actions/goto", "/DobotMagician/actions/returnCube")
                   for q in real_lab.requests())
    assert np.allclose(location(lab), before, atol=1)


def test_an_accepted_move_reaches_the_real_robot_in_its_frame(lab, real_lab):
    real_lab.clear_log()
    target = np.array([180, 50, 80], float)
    r = go_to(lab, 180, 50, 80)
    assert r.status_code == 204, r.text
    sent = real_lab.calls("Uarm", "goTo")
    assert len(sent) == 1
    arrived = np.array([sent[0]["input"][k] for k in "xyz"], float)
    assert np.all(np.abs(arrived - (target + OFFSET)) <= 0.5), (arrived, target + OFFSET)  # integer mm, rounded
    assert np.allclose(location(lab), target, atol=1)  # the twin did the same
    assert np.allclose(location(lab, "uarm-real"), arrived)


def test_what_only_the_real_device_has_and_non_moves_are_forwarded(lab, real_lab):
    real_lab.clear_log()
    assert httpx.post(f"{lab.http}/uarm/actions/beep", timeout=30).status_code == 204  # the twin has no beep
    assert httpx.post(f"{lab.http}/uarm/actions/gripOpen", timeout=60).status_code == 204
    assert httpx.put(f"{lab.http}/conveyor-belt-1/properties/speed", json=40, timeout=30).status_code == 204
    assert {(c["thing"], c["affordance"]) for c in real_lab.calls()} >= {("Uarm", "beep"), ("Uarm", "gripOpen")}
    assert any(q["path"] == "/ConveyorBelt1/properties/speed" and q["method"] == "PUT" for q in real_lab.requests())
    assert httpx.get(f"{lab.http}/conveyor-belt-1/properties/speed", timeout=30).json() == 40
    assert httpx.get(f"{lab.http}/conveyor-belt-1-real/properties/speed", timeout=30).json() == 40
    assert all(q["authorized"] for q in real_lab.requests())


def test_the_twin_stands_where_the_real_arm_is(lab, real_lab):
    httpx.post(f"{real_lab.base}/uarm/actions/goto", json={"x": 150, "y": -80, "z": 70},
               auth=(CREDENTIALS["username"], CREDENTIALS["password"]), timeout=30).raise_for_status()
    expected = np.array([150, -80, 70], float) - OFFSET
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and not np.allclose(location(lab), expected, atol=1.5):
        time.sleep(0.25)
    assert np.allclose(location(lab), expected, atol=1.5), (location(lab), expected)


def test_the_real_robot_down_is_503_at_once_and_the_twin_stands_still(lab, real_lab):
    before = location(lab)
    real_lab.kill()
    try:
        started = time.monotonic()
        r = go_to(lab, 160, 40, 70)
        assert r.status_code == 503 and r.json()["reason"] == "remote-unavailable", r.text
        assert time.monotonic() - started < 30  # not after a long timeout (the figure is in the closing note)
        assert np.allclose(location(lab), before, atol=1)
        assert httpx.post(f"{lab.http}/dobot/actions/calibrateDevice", timeout=30).status_code == 503
    finally:
        real_lab.start()
    real_lab.clear_log()
    assert go_to(lab, 160, 40, 70).status_code == 204  # back: moves work again, nothing restarted
    assert [c["input"] for c in real_lab.calls("Uarm", "goTo")] == [
        {k: round(v) for k, v in zip("xyz", np.array([160, 40, 70]) + OFFSET)}]


def test_the_cube_workflow_runs_unchanged_through_the_guarded_twins(lab, real_lab):
    httpx.post(f"{lab.http}/world/actions/reset", timeout=60).raise_for_status()
    real_lab.clear_log()
    done = lab.cli("workflow", "cube", "--via", lab.http, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    called = [(c["thing"], c["affordance"]) for c in real_lab.calls()]
    for needed in [("Warehouse Dobot", "getCube"), ("ConveyorBelt2", "startBeltForward"), ("Uarm", "goTo"),
                   ("Uarm", "gripClose"), ("ConveyorBelt1", "startBeltBackward"), ("Warehouse Dobot", "returnCube")]:
        assert needed in called, (needed, called)
    assert called.index(("Warehouse Dobot", "getCube")) < called.index(("Warehouse Dobot", "returnCube"))


def test_bad_real_options_start_nothing_and_say_why(tmp_path, real_lab):
    endpoint = f"tcp/127.0.0.1:{free_port()}"

    def up(*args: str) -> subprocess.CompletedProcess:
        return subprocess.run(twinmesh_cmd(endpoint, "up", *args, "--no-view", "--http", f"127.0.0.1:{free_port()}"),
                              capture_output=True, text=True, timeout=120)

    lights = up("lights", "--real", f"uarm={real_lab.url('Uarm')}")
    assert lights.returncode == 2 and "iot-platform" in lights.stderr, lights.stderr
    robot = up("iot-platform", "--real", f"ur10={real_lab.url('Uarm')}")
    assert robot.returncode == 2 and "ur10" in robot.stderr, robot.stderr
    down = up("iot-platform", "--real", "uarm=http://127.0.0.1:9/td/Uarm")
    assert down.returncode == 3 and "cannot connect" in down.stderr, down.stderr
    refused = up("iot-platform", "--real", f"uarm={real_lab.url('Uarm')}", "--real-auth", "basic:lab:wrong")
    assert refused.returncode == 2 and "credentials" in refused.stderr, refused.stderr
    lonely = up("iot-platform", "--real-calibration", "uarm=x.csv")
    assert lonely.returncode == 2 and "--real" in lonely.stderr, lonely.stderr


# --- a robot Thing guarding a real arm --------------------------------------------------------------

HOME = {"shoulder_pan_joint": 0, "shoulder_lift_joint": -90, "elbow_joint": 0, "wrist_1_joint": -90,
        "wrist_2_joint": 0, "wrist_3_joint": 0}


@pytest.fixture(scope="module")
def real_ur10(tmp_path_factory):
    extra = tmp_path_factory.mktemp("real-ur10")
    (extra / "UR10.json").write_text((Path(__file__).parent / "data" / "mock-real-ur10.json").read_text())
    with npm.RealLab(CREDENTIALS, extra_tds=extra) as lab:
        yield lab


@pytest.fixture(scope="module")
def ur10_lab(tmp_path_factory, real_ur10):
    tmp = tmp_path_factory.mktemp("guard-ur10")
    lab = start_lab(tmp, "ur10", things={"ur10", "ur10-real"}, extra_args=(
        "--speed", "max", "--samples", "4000", "--tdgen-cache", str(tmp / "cache"),
        "--real", f"ur10={real_ur10.url('UR10')}", "--real-auth", AUTH))
    yield lab
    lab.stop()


def joints(lab, thing: str = "ur10") -> dict:
    return httpx.get(f"{lab.http}/{thing}/properties/getJointposition", timeout=30).json()


def test_a_robot_twin_guards_a_real_arm(ur10_lab, real_ur10):
    lab = ur10_lab
    deadline = time.monotonic() + 60  # the twin stands where the real arm said it stands
    while time.monotonic() < deadline and not all(abs(joints(lab)[k] - v) < 0.01 for k, v in HOME.items()):
        time.sleep(0.5)
    real_ur10.clear_log()
    refused = None
    for lift, elbow in ((0, 0), (45, 0), (90, 0), (30, 120), (60, 150)):  # arm down through the table
        target = {**HOME, "shoulder_lift_joint": lift, "elbow_joint": elbow}
        if httpx.post(f"{lab.http}/ur10/actions/planMove", json={"joints": target}, timeout=120).status_code == 422:
            refused = target
            break
    assert refused is not None, "no joint target the twin refuses among the candidates"
    r = httpx.post(f"{lab.http}/ur10/actions/moveToJointPosition", json=refused, timeout=120)
    assert r.status_code == 422, r.text
    assert real_ur10.calls("UR10") == []  # neither the dry runs nor the refused move reached the real arm

    accepted = {**HOME, "shoulder_pan_joint": 20}
    r = httpx.post(f"{lab.http}/ur10/actions/moveToJointPosition", json=accepted, timeout=120)
    assert r.status_code == 200, r.text
    assert [c["input"] for c in real_ur10.calls("UR10", "moveToJointPosition")] == [accepted]
    assert abs(joints(lab)["shoulder_pan_joint"] - 20) < 0.01

    # the real arm moved by someone else: the twin follows
    moved = {**HOME, "shoulder_pan_joint": -30}
    httpx.post(f"{real_ur10.base}/ur10/actions/movejoints", json=moved,
               auth=(CREDENTIALS["username"], CREDENTIALS["password"]), timeout=30).raise_for_status()
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and abs(joints(lab)["shoulder_pan_joint"] + 30) > 0.01:
        time.sleep(0.25)
    assert abs(joints(lab)["shoulder_pan_joint"] + 30) < 0.01
    assert joints(lab, "ur10-real")["shoulder_pan_joint"] == -30

    real_ur10.kill()
    try:
        r = httpx.post(f"{lab.http}/ur10/actions/moveToJointPosition", json=HOME, timeout=120)
        assert r.status_code == 503, r.text
        assert abs(joints(lab)["shoulder_pan_joint"] + 30) < 0.01  # the twin stood still
    finally:
        real_ur10.start()
    assert httpx.post(f"{lab.http}/ur10/actions/moveToJointPosition", json=HOME, timeout=120).status_code == 200


def test_the_recorder_has_the_real_device_beside_its_twin_on_one_timeline(lab, tmp_path):
    from labs import stop_process
    from waiting import eventually

    from recordings import field_scalars, wait_for_line

    path, log = tmp_path / "guarded.rrd", tmp_path / "recorder.log"
    recorder = lab.spawn("record", str(path), log=log)
    wait_for_line(log, "recording to", recorder)
    assert go_to(lab, 170, -60, 75).status_code == 204
    # the real uArm's location is read every second (it offers no http observation): until it is published
    eventually(lambda: location(lab, "uarm-real")[0] == round(170 + OFFSET[0]), timeout=30,
               what="the real uArm's new location on the mesh")
    assert stop_process(recorder), log.read_text()
    twin_x = field_scalars(path, "/things/uarm/properties/location", "x")
    real_x = field_scalars(path, "/things/uarm-real/properties/location", "x")
    assert twin_x and real_x, log.read_text()
    assert abs(twin_x[-1] - 170) <= 1 and real_x[-1] == round(170 + OFFSET[0])
