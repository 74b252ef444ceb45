"""The cube workflow (SPEC §3) against `twinmesh up iot-platform --speed max`, by affordance name only:
with node-wot over HTTP (tests/interop/cube-workflow.mjs), with `twinmesh workflow cube` over Zenoh
and over HTTP (`--via`), and as a function. Runs follow each other on one lab without a restart.
"""
from __future__ import annotations

import json
import queue
import subprocess

import numpy as np
import pytest
from interop import npm
from labs import mesh_client

pytestmark = pytest.mark.lab

QUEUE = ["cube-red", "cube-green", "cube-blue", "cube-yellow"]
RGB = {"cube-red": [219, 31, 26], "cube-green": [31, 168, 56], "cube-blue": [31, 71, 219]}


@pytest.fixture(scope="module")
def lab(platform):
    return platform  # the session's iot-platform lab, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def client(lab):
    with mesh_client(lab.endpoint) as c:
        yield c


@pytest.fixture
def fresh(client):
    """A reset scene: every cube in the warehouse, robots home, belts stopped."""
    client.invoke("world", "reset")
    return client


def slot_position(i: int) -> np.ndarray:
    from devices.sim.layouts.platform_layout import LAYOUT, UARM_BASE

    real = [LAYOUT.warehouse_x, LAYOUT.warehouse_slots_y[i], LAYOUT.warehouse_floor + LAYOUT.cube / 2]
    return np.asarray(UARM_BASE) + np.asarray(real) / 1000.0


def assert_in_the_warehouse(client, expected_queue: list[str]) -> None:
    poses = client.read("world", "poses")
    assert poses["states"]["dobot"]["queue"] == expected_queue
    for i, cube in enumerate(expected_queue):
        position = np.asarray(poses["bodies"][cube][0])
        assert np.linalg.norm(position - slot_position(i)) < 0.003, (cube, position, slot_position(i))
    assert all(poses["states"][b]["direction"] == "stopped" for b in ("conveyor-belt-1", "conveyor-belt-2"))


def assert_color(color: list, cube: str) -> None:
    assert np.all(np.abs(np.array(color) - RGB[cube]) <= 3), (color, cube)


def test_node_wot_runs_the_cube_workflow_over_http(lab, fresh):
    npm.ensure_node_modules()
    done = subprocess.run(["node", "cube-workflow.mjs", lab.http, "--timeout-ms", "60000"], cwd=npm.INTEROP_DIR,
                          capture_output=True, text=True, timeout=180)
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    assert done.returncode == 0, f"{done.stdout}\n{done.stderr[-3000:]}"
    steps, result = lines[:-1], lines[-1]
    assert [s["step"] for s in steps] == list(range(1, 9)) and all(s["ms"] >= 0 for s in steps)
    assert result["done"] is True
    assert_color(result["color"], "cube-red")
    assert True in result["events"]["infrared-sensor-2"] and True in result["events"]["infrared-sensor-1"]
    assert_in_the_warehouse(fresh, QUEUE[1:] + QUEUE[:1])


def test_twinmesh_workflow_cube_runs_twice_over_zenoh_then_reset_restores_the_scene(lab, fresh):
    events: dict[str, queue.Queue] = {s: queue.Queue() for s in ("infrared-sensor-1", "infrared-sensor-2")}
    subs = [fresh.subscribe(s, "detectedObject", q.put) for s, q in events.items()]
    try:
        first = lab.cli("workflow", "cube", timeout=180)
        second = lab.cli("workflow", "cube", timeout=180)
        for run in (first, second):
            assert run.returncode == 0, run.stdout + run.stderr
        got = {sensor: [q.get(timeout=5) for _ in range(4)] for sensor, q in events.items()}
    finally:
        for sub in subs:
            sub.undeclare()
    for run, cube in ((first, "red"), (second, "green")):
        lines = run.stdout.splitlines()
        assert [line.split(".")[0].strip() for line in lines[:8]] == [str(n) for n in range(1, 9)]
        assert all(line.rstrip().split(" -- ")[0].endswith(" s") for line in lines[:8])
        assert f"the cube is {cube} [" in lines[-1]
    for sensor, q in events.items():  # on every change: the cube arrives (true), then is taken away
        assert got[sensor] == [True, False, True, False] and q.empty(), sensor
    assert_in_the_warehouse(fresh, QUEUE[2:] + QUEUE[:2])
    fresh.invoke("world", "reset")
    assert_in_the_warehouse(fresh, QUEUE)
    assert fresh.read("uarm", "location") == {"x": 200, "y": 0, "z": 100}
    assert fresh.read("dobot", "position")["l"] == 450


def test_twinmesh_workflow_cube_via_the_http_adapter(lab, fresh):
    run = lab.cli("workflow", "cube", "--via", lab.http, timeout=180)
    assert run.returncode == 0, run.stdout + run.stderr
    assert "colour sensor reads the cube" in run.stdout and "the cube is red [" in run.stdout
    assert_in_the_warehouse(fresh, QUEUE[1:] + QUEUE[:1])


@pytest.mark.parametrize("via", [False, True], ids=["zenoh", "http"])
def test_a_failing_step_makes_the_workflow_exit_non_zero_naming_it(lab, fresh, via):
    fresh.invoke("world", "resetWarehouse", {"cubes": 0})
    run = lab.cli("workflow", "cube", *(["--via", lab.http] if via else []), timeout=60)
    assert run.returncode == 1
    assert "step 1 (dobot getCube" in run.stderr and "warehouse is empty" in run.stderr


def test_the_workflow_function_reports_eight_timed_steps_and_the_colour(fresh):
    import mesh
    from devices.apps.cube_workflow import cube_workflow

    heard = []
    with mesh.consumer(session=fresh.session, settings=fresh.settings) as things:
        run = cube_workflow(things, heard.append, sensor_timeout=60)
    assert [s.number for s in run.steps] == list(range(1, 9)) and heard == run.steps
    assert all(s.seconds > 0 for s in run.steps) and run.seconds >= sum(s.seconds for s in run.steps)
    assert_color(run.color, "cube-red")
    assert run.color_name == "red"
    assert_in_the_warehouse(fresh, QUEUE[1:] + QUEUE[:1])


def test_colour_names():
    from devices.apps.cube_workflow import color_name

    assert [color_name(c) for c in ([219, 31, 26], [31, 168, 56], [31, 71, 219], [242, 209, 26], [0, 0, 0],
                                    [128, 128, 128], [250, 250, 250])] == \
        ["red", "green", "blue", "yellow", "black", "grey", "white"]
