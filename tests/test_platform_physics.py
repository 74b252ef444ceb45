"""The iot-platform scene's physics and device behaviours, driven through their Python API (real pybullet).

Every test builds its own world; all but the two speed-1 tests run at speed max (simulated time runs as
fast as the CPU allows), so a client never sleeps: it waits on motions and sensor callbacks.
"""
from __future__ import annotations

import csv
import math
import threading
import time
from dataclasses import dataclass

import numpy as np
import pybullet as pb
import pytest

from devices.sim.belt import STOPPED, Belt
from devices.sim.compensation import (
    DOBOT_EE,
    DOBOT_MAIN_JOINTS,
    DOBOT_PASSIVE_JOINTS,
    DOBOT_URDF,
    MODELS,
    UARM_EE,
    UARM_MAIN_JOINTS,
    UARM_PASSIVE_JOINTS,
    UARM_URDF,
    KinematicArm,
    dobot_passive,
    uarm_passive,
)
from devices.sim.dobot import Cube, EmptyWarehouse, NoCubeAtPickup
from devices.sim.layouts.platform_layout import CUBE_COLORS, UARM_BASE, IotPlatform, build_platform
from devices.sim.pybullet_world import MotionCancelled
from devices.sim.sensors import InfraredSensor
from devices.sim.uarm import GOTO_RANGE, OutOfRange, Unreachable, calibration_pairs, real_fk, real_ik
from mesh.wot.problem import BadInput, Refused


@pytest.fixture
def platform():
    p = build_platform(speed=None)
    yield p
    p.close()


def cube_real(p: IotPlatform, cube: Cube) -> np.ndarray:
    """A cube's centre in the real uArm frame (mm), read on the stepping thread."""
    pos = p.world.run(lambda: pb.getBasePositionAndOrientation(cube.body, physicsClientId=p.world.client)[0])
    return p.uarm.to_real(pos)


def run_until_seen(belt: Belt, sensor: InfraredSensor, start) -> None:
    """Start the belt, wait for the sensor's change callback (no polling, no sleep), stop the belt."""
    seen = threading.Event()
    unsubscribe = sensor.on_change(lambda present: present and seen.set())
    try:
        start()
        assert seen.wait(120), f"{sensor.name} never saw the cube"
    finally:
        assert belt.stop() == STOPPED
        unsubscribe()


@dataclass
class Run:
    cube: Cube
    color: list[int]
    at_ir2: np.ndarray
    at_ir1: np.ndarray


def cube_workflow(p: IotPlatform) -> Run:
    """SPEC §3's cube workflow, by affordance, as the lab's client script runs it."""
    belt1, belt2 = p.belts["conveyor-belt-1"], p.belts["conveyor-belt-2"]
    ir1, ir2 = p.infrared["infrared-sensor-1"], p.infrared["infrared-sensor-2"]
    uarm = p.uarm
    cube = p.dobot.get_cube()
    run_until_seen(belt2, ir2, belt2.start_forward)
    at_ir2 = cube_real(p, cube)
    uarm.grip_open()
    uarm.go_to(192, 192, 87)
    uarm.go_to(192, 192, 52)
    uarm.grip_close()
    assert uarm.holding == cube.body
    uarm.go_to(192, 192, 87)
    uarm.go_to(180, 0, 60)
    color = p.color_sensor.color
    uarm.go_to(200, -200, 90)
    uarm.go_to(200, -200, 70)
    uarm.grip_open()
    uarm.go_to(200, -200, 90)
    run_until_seen(belt1, ir1, belt1.start_backward)
    at_ir1 = cube_real(p, cube)
    assert p.dobot.return_cube() is cube
    return Run(cube, color, at_ir2, at_ir1)


def test_cube_workflow_runs_twice_and_the_colour_sensor_reads_each_cube(platform):
    p = platform
    events: dict[str, list[bool]] = {name: [] for name in p.infrared}
    for name, sensor in p.infrared.items():
        sensor.on_change(events[name].append)
    queue_before = p.warehouse.names()
    wall0, sim0 = time.perf_counter(), p.world.time
    first = cube_workflow(p)
    second = cube_workflow(p)
    wall, sim = time.perf_counter() - wall0, p.world.time - sim0
    print(f"\ncube workflow x2 at speed max: {wall:.2f} s wall, {sim:.1f} s simulated, "
          f"{p.world.steps} steps")

    assert [first.cube.name, second.cube.name] == queue_before[:2]
    for run in (first, second):
        expected = 255 * np.array(run.cube.color)
        assert np.all(np.abs(np.array(run.color) - expected) <= 10), (run.cube.name, run.color, expected)
        assert abs(run.at_ir2[0] - 192) <= 8 and abs(run.at_ir2[1] - 192) <= 1  # stopped where the uArm grips
        assert abs(run.at_ir1[0] - 656) <= 8 and abs(run.at_ir1[1] + 200) <= 1  # where the Dobot takes it
    assert p.warehouse.names() == queue_before[2:] + queue_before[:2]
    for cube, slot in zip(p.warehouse.queue, p.warehouse.slots):
        assert np.linalg.norm(cube_real(p, cube) - p.uarm.to_real(slot)) < 3.0, cube.name
    p.world.wait(0.05)  # the notifier thread has delivered every change by now
    assert events["infrared-sensor-2"] == [True, False, True, False]
    assert events["infrared-sensor-1"] == [True, False, True, False]
    assert not any(b.direction != "stopped" for b in p.belts.values())


def test_reset_puts_cubes_back_robots_home_and_belts_stopped(platform):
    p = platform
    queue = p.warehouse.names()
    p.dobot.get_cube()
    p.belts["conveyor-belt-2"].start_forward()
    p.belts["conveyor-belt-1"].speed = 30
    p.uarm.go_to(150, 100, 90)
    p.uarm.home_loc = {"x": 180, "y": 0, "z": 90}
    p.reset()
    assert p.warehouse.names() == queue
    for cube, slot in zip(p.warehouse.queue, p.warehouse.slots):
        assert np.linalg.norm(cube_real(p, cube) - p.uarm.to_real(slot)) < 1.0
    assert all(b.direction == "stopped" and b.speed == 100 for b in p.belts.values())
    assert p.uarm.location == {"x": 200, "y": 0, "z": 100} == p.uarm.home_loc
    assert p.dobot.position["l"] == 450 and p.dobot.holding is None
    assert not any(s.object_presence for s in p.infrared.values())


def test_reset_cancels_a_motion_under_way_and_its_caller_gets_an_error():
    with build_platform(speed=1.0) as p:
        outcome: list[BaseException | None] = []

        def client() -> None:
            try:
                p.uarm.go_to(192, 192, 52)  # ~4 s at 50 mm/s
                outcome.append(None)
            except BaseException as exc:
                outcome.append(exc)

        worker = threading.Thread(target=client)
        worker.start()
        p.world.wait(0.5)
        p.reset()
        worker.join(10)
        assert isinstance(outcome[0], MotionCancelled)
        assert p.uarm.location == {"x": 200, "y": 0, "z": 100}


def test_go_to_outside_the_real_ranges_is_refused_before_anything_moves(platform):
    uarm = platform.uarm
    uarm.go_to(160, 50, 80)
    q, t = uarm.arm.q.copy(), platform.world.time
    for x, y, z in [(119, 0, 80), (201, 0, 80), (160, 201, 80), (160, -201, 80), (160, 0, 51), (160, 0, 101)]:
        with pytest.raises(OutOfRange) as err:
            uarm.go_to(x, y, z)
        assert err.value.status == 422 and "must be within" in err.value.detail
    with pytest.raises(OutOfRange):
        uarm.go(160, 0, 80, speed=50)
    with pytest.raises(Unreachable, match="lower arm"):  # inside the TD's box, beyond the motor limit
        uarm.go_to(120, 0, 100)
    with pytest.raises(OutOfRange):
        uarm.home_loc = {"x": 300, "y": 0, "z": 80}
    assert np.array_equal(uarm.arm.q, q) and uarm.location == {"x": 160, "y": 50, "z": 80}
    assert platform.world.time - t < 0.5  # no motion was played
    assert uarm.turn_left() == {"y": 60} and uarm.turn_right() == {"y": 50}


def test_belt_stop_when_stopped_is_harmless_and_speed_is_checked(platform):
    belt = platform.belts["conveyor-belt-1"]
    assert belt.stop() == STOPPED and belt.stop() == STOPPED and belt.direction == "stopped"
    for bad in (0, 101, 2.5, "50", True):
        with pytest.raises(BadInput):
            belt.speed = bad
    belt.speed = 50
    belt.start_backward()
    assert belt.velocity == pytest.approx(-0.030)  # 50 % of 60 mm/s, towards the Dobot
    belt.stop()


def test_get_cube_refuses_an_empty_warehouse_or_a_taken_belt_and_return_needs_a_cube():
    with build_platform(speed=None, colors={k: CUBE_COLORS[k] for k in ("red", "green")}) as p:
        with pytest.raises(NoCubeAtPickup, match="no cube at the end of conveyor belt 1") as err:
            p.dobot.return_cube()
        assert isinstance(err.value, Refused) and err.value.reason == "no-cube"
        assert p.dobot.get_cube().name == "cube-red"
        with pytest.raises(Refused, match="already a cube") as err:  # the belt's start is still taken
            p.dobot.get_cube()
        assert err.value.reason == "belt-occupied" and p.warehouse.names() == ["cube-green"]
        belt = p.belts["conveyor-belt-2"]
        belt.start_forward()
        p.world.wait(1.0)
        belt.stop()
        assert p.dobot.get_cube().name == "cube-green"
        position = p.dobot.position
        with pytest.raises(EmptyWarehouse, match="warehouse is empty") as err:
            p.dobot.get_cube()
        assert err.value.status == 422 and err.value.reason == "empty-warehouse"
        assert p.dobot.position == position


@pytest.mark.parametrize("urdf, main, passive, fn", [
    (UARM_URDF, UARM_MAIN_JOINTS, UARM_PASSIVE_JOINTS, uarm_passive),
    (DOBOT_URDF, DOBOT_MAIN_JOINTS, DOBOT_PASSIVE_JOINTS, dobot_passive),
], ids=["uarm", "dobot"])
def test_passive_joints_keep_the_end_effector_level(urdf, main, passive, fn):
    client = pb.connect(pb.DIRECT)
    try:
        arm = KinematicArm(client, str(urdf), (0.1, -0.2, 0.3), (0, 0, 0, 1), main, passive, fn)
        limits = np.array([pb.getJointInfo(arm.body, arm.joint_index[j], physicsClientId=client)[8:10]
                           for j in main])
        qs = np.random.default_rng(3).uniform(limits[:, 0], limits[:, 1], size=(200, len(main)))
        assert fn(qs).shape == (200, len(passive))  # vectorised, as tdgen's Robot.load takes it
        for q in qs:
            q = q.copy()
            q[-1] = 0.0  # the last main joint turns the tool about z; level means no roll or pitch
            arm.apply(q)
            _, orn = arm.link_pose("tcp")
            roll, pitch, yaw = pb.getEulerFromQuaternion(orn)
            assert abs(roll) < 1e-6 and abs(pitch) < 1e-6
            assert abs(math.remainder(yaw - q[0], 2 * math.pi)) < 1e-6
    finally:
        pb.disconnect(client)


def test_uarm_ik_is_exact_in_the_real_frame_and_in_the_twin():
    rng = np.random.default_rng(11)
    targets = [(192, 192, 52), (192, 192, 87), (180, 0, 60), (200, -200, 70), (200, -200, 90), (200, 0, 80)]
    targets += [tuple(rng.uniform(*GOTO_RANGE[k]) for k in "xyz") for _ in range(300)]
    client = pb.connect(pb.DIRECT)
    try:
        arm = KinematicArm(client, str(UARM_URDF), UARM_BASE, (0, 0, 0, 1), UARM_MAIN_JOINTS,
                           UARM_PASSIVE_JOINTS, uarm_passive)
        solved = 0
        for target in targets:
            try:
                q = real_ik(*target)
            except Unreachable:
                assert target not in targets[:6]
                continue
            solved += 1
            assert np.linalg.norm(real_fk(q)[0] - target) < 0.5
            arm.apply(q)
            twin = (np.array(arm.link_pose(UARM_EE)[0]) - UARM_BASE) * 1000.0
            assert np.linalg.norm(twin - target) < 0.5
        assert solved > 0.95 * len(targets)
    finally:
        pb.disconnect(client)


def test_calibration_csv_is_the_models_affine_map():
    with open(MODELS / "uarm-calibration.csv") as f:
        rows = [[float(v) for v in r.values()] for r in csv.DictReader(f)]
    data = np.array(rows)
    assert data.shape[1] == 6 and len(data) >= 20
    assert np.allclose(data, np.array(calibration_pairs(UARM_BASE, len(data))), atol=2e-3)  # up to date
    for axis in range(3):  # both sides mm in the base frame: the twin's model is the firmware's kinematics
        k, b = np.polyfit(data[:, axis], data[:, axis + 3], 1)
        assert k == pytest.approx(1.0, rel=1e-4) and b == pytest.approx(0.0, abs=0.05)


def test_snapshots_publish_robot_joints_cube_poses_and_belt_states(platform):
    got: list = []
    unsubscribe = platform.world.on_snapshot(got.append)
    platform.belts["conveyor-belt-2"].start_forward()
    platform.uarm.go_to(190, 100, 90)
    platform.belts["conveyor-belt-2"].stop()
    platform.world.wait(0.1)
    unsubscribe()
    assert len(got) >= 10 and all(a.time < b.time for a, b in zip(got, got[1:]))
    last = got[-1]
    assert set(UARM_MAIN_JOINTS + UARM_PASSIVE_JOINTS) <= set(last.joints["uarm"])
    assert set(DOBOT_MAIN_JOINTS) <= set(last.joints["dobot"])
    assert {c.name for c in platform.cubes} <= set(last.bodies) and "dobot" in last.bodies
    assert any(s.states["conveyor-belt-2"]["direction"] == "forward" for s in got)
    assert last.states["infrared-sensor-2"] == {"objectPresence": False}


def test_speed_one_runs_in_real_time_and_actions_come_from_any_thread():
    with build_platform(speed=1.0) as p:
        errors: list[BaseException] = []

        def client() -> None:
            try:
                p.uarm.go_to(200, 0, 60)
            except BaseException as exc:  # surfaced below
                errors.append(exc)

        sim0, wall0 = p.world.time, time.perf_counter()
        worker = threading.Thread(target=client)
        worker.start()
        worker.join(120)
        sim, wall = p.world.time - sim0, time.perf_counter() - wall0
        assert not errors and p.uarm.location == {"x": 200, "y": 0, "z": 60}
        # 40 mm at 50 mm/s; the simulation never runs ahead of the clock (a busy machine can only slow it,
        # so the test says nothing of how much later it may end: `--speed max` is the one that runs ahead)
        assert 0.7 < sim < 1.2 and wall >= 0.95 * sim, (sim, wall)


def test_tdgen_loads_both_arms_with_their_compensation():
    robot_mod = pytest.importorskip("tdgen.robot.model")
    kin = pytest.importorskip("tdgen.robot.kinematics")
    uarm = robot_mod.Robot.load(UARM_URDF, ee=UARM_EE, passive_joints=list(UARM_PASSIVE_JOINTS), passive=uarm_passive)
    dobot = robot_mod.Robot.load(DOBOT_URDF, ee=DOBOT_EE, passive_joints=list(DOBOT_PASSIVE_JOINTS),
                                 passive=dobot_passive)
    assert [j.name for j in uarm.joints] == list(UARM_MAIN_JOINTS)
    assert [j.name for j in dobot.joints] == list(DOBOT_MAIN_JOINTS)
    qs = np.array([real_ik(192, 192, 52), real_ik(180, 0, 60), real_ik(200, -200, 90)])
    assert np.allclose(kin.ForwardKinematics(uarm).positions(qs) * 1000.0, real_fk(qs), atol=0.5)
