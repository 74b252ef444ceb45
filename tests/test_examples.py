"""Every example in examples/ runs as its README says, against real labs.

The session's shared `lights` lab (with its tdgen service; conftest.py) serves the Python script, the
thermostat TD under `twinmesh virtual` and the Panda on the workbench scene; the shared `iot-platform`
lab the node-wot cube workflow; two network-namespace hosts the two-host recipe, with a lab of their
own. Each example is run as a user runs it (`python FILE`, `node FILE`, `sh FILE`), with the lab's
address given the way the example says it takes one.
"""
from __future__ import annotations

import importlib.metadata
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

import httpx
import pytest
from labs import REPO, stop_process
from waiting import eventually

from mesh.wot.consumed import Inbox, NothingArrived

pytestmark = [pytest.mark.lab, pytest.mark.timeout(1800)]

EXAMPLES = REPO / "examples"
BIN = str(Path(sys.executable).parent)  # `twinmesh` and `python3` of this environment, as after `. .venv/bin/activate`


def _env(**extra: str) -> dict[str, str]:
    return {**os.environ, "PATH": f"{BIN}{os.pathsep}{os.environ.get('PATH', '')}", "PYTHONUNBUFFERED": "1", **extra}


def _run(args: list[str], timeout: float = 120, **env: str) -> subprocess.CompletedProcess:
    return subprocess.run(args, capture_output=True, text=True, timeout=timeout, cwd=REPO, env=_env(**env))


# --- examples/python ------------------------------------------------------------------------------


def _lamp(lab, *args: str) -> subprocess.CompletedProcess:
    return _run([sys.executable, str(EXAMPLES / "python" / "lamp.py"), lab.http, *args])


def test_the_python_example_switches_the_lamp_on_whatever_state_it_is_in(lights):
    assert lights.cli("invoke", "light-right", "switchOff").returncode == 0
    off = _lamp(lights, "light-right")
    assert off.returncode == 0, off.stderr
    assert json.loads(off.stdout) | {"color": None} == \
        {"thing": "light-right", "before": False, "after": True, "color": None}
    already_on = _lamp(lights, "light-right")  # the README's example raised a bare _queue.Empty here
    assert already_on.returncode == 0, already_on.stderr
    assert json.loads(already_on.stdout)["before"] is True and json.loads(already_on.stdout)["after"] is True
    assert lights.cli("read", "light-right", "lightState").stdout.strip() == "true"


def test_the_python_example_says_in_one_line_what_is_wrong(lights):
    missing = _lamp(lights, "no-such-lamp")
    assert missing.returncode == 1 and missing.stdout == ""
    assert missing.stderr.startswith("lamp.py: ") and "no-such-lamp" in missing.stderr
    assert "Traceback" not in missing.stderr and len(missing.stderr.strip().splitlines()) == 1


def test_waiting_for_a_change_that_never_comes_says_why(lights):
    """The README's first consume() example with the lamp already on: no change comes, and the wait says
    so in words a user can act on, as a mesh.Problem (it was a bare `_queue.Empty`)."""
    import mesh

    assert lights.cli("invoke", "light-left", "switchOn").returncode == 0
    with mesh.consume(f"{lights.http}/light-left") as light:
        changes = Inbox()
        watching = light.observe_property("lightState", changes)
        try:
            light.invoke_action("switchOn")
            with pytest.raises(NothingArrived, match="an observation brings changes only") as caught:
                changes.get(timeout=2)
        finally:
            watching.stop()
    assert isinstance(caught.value, mesh.Problem)


# --- examples/tds ---------------------------------------------------------------------------------


def test_the_thermostat_td_runs_as_a_virtual_thing(lights):
    td = EXAMPLES / "tds" / "thermostat.td.json"
    log = lights.log.parent / "thermostat.log"
    process = lights.spawn("virtual", f"thermostat={td}", "--seed", "1", "--drift", "--events-every", "2", log=log)
    try:
        lights.wait_things({"thermostat"})
        temperature = json.loads(lights.cli("read", "thermostat", "temperature").stdout)
        assert 5 <= temperature <= 35
        assert lights.cli("write", "thermostat", "targetTemperature", "22.5").returncode == 0
        assert json.loads(lights.cli("read", "thermostat", "targetTemperature").stdout) == 22.5
        refused = lights.cli("write", "thermostat", "targetTemperature", "40")  # above the TD's maximum
        assert refused.returncode == 1 and "targetTemperature" in refused.stderr
        boost = lights.cli("invoke", "thermostat", "boost", '{"minutes": 10}')
        assert boost.returncode == 0 and "until" in json.loads(boost.stdout)
        event = lights.cli("subscribe", "thermostat", "overheating", "--count", "1", timeout=60)
        assert event.returncode == 0 and "temperature" in json.loads(event.stdout)
        assert httpx.get(f"{lights.http}/thermostat/properties/targetTemperature", timeout=10).json() == 22.5
        served = httpx.get(f"{lights.http}/thermostat", timeout=10).json()
        assert served["title"] == "Thermostat" and set(served["properties"]) == {"temperature", "targetTemperature",
                                                                                   "mode"}
        listed = lights.cli("things").stdout.split()  # `things` is sorted (it printed in arrival order)
        assert "thermostat" in listed and listed == sorted(listed)
    finally:
        assert stop_process(process), log.read_text()[-3000:]
        lights.extra.remove(process)


# --- examples/scenes, offline ----------------------------------------------------------------------


def test_the_workbench_scene_gives_a_td_offline_and_check_judges_targets_on_it(tmp_path):
    """The README's offline line for the scene: `twinmesh tdgen` with it, then `twinmesh check`, one verdict
    line each (few samples and the exact model here: no compile on first use)."""
    out = tmp_path / "ur10"
    made = _run(["twinmesh", "tdgen", "ur10.urdf", "--scene", str(EXAMPLES / "scenes" / "workbench.json"),
                 "--samples", "1000", "--collision-model", "exact", "--out", str(out)], timeout=900)
    assert made.returncode == 0, made.stderr
    scene = json.loads((out / "scene.json").read_text())
    assert {"bench", "crate", "bin", "wall"} <= {body.get("name") for body in scene["bodies"]}
    behind = _run(["twinmesh", "check", str(out), "-800", "0", "200"])  # through the wall behind the robot
    assert behind.returncode == 1 and behind.stderr == ""
    assert behind.stdout.startswith("REFUSED: ") and len(behind.stdout.splitlines()) == 1


# --- examples/robots and examples/scenes ----------------------------------------------------------


def _generated_td(lab, proc: subprocess.Popen, log: Path) -> dict:
    """The Panda's TD once the lab's tdgen service has generated its workspace (no fixed time: as long as
    the robot runs; the failure shows its log)."""
    def generated() -> dict | None:
        assert proc.poll() is None, f"the robot exited {proc.returncode}:\n{log.read_text()[-3000:]}"
        r = httpx.get(f"{lab.http}/panda", timeout=10)
        if r.status_code == 200 and any(link["rel"].endswith("workspace") for link in r.json().get("links", [])):
            return r.json()
        return None

    return eventually(generated, timeout=1500, what="the Panda's TD with its workspace")


def test_the_foreign_panda_stands_on_the_workbench_scene(lights):
    try:
        importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError:
        pytest.skip("example-robot-data (a test extra) is not installed")
    log = lights.log.parent / "panda.log"
    # the example's own command line; the test asks for few samples, the exact collision model (no
    # compile on first use) and the fastest simulation
    proc = subprocess.Popen(["sh", str(EXAMPLES / "robots" / "panda.sh"), "--collision-model", "exact",
                             "--speed", "max"], stdout=open(log, "wb"), stderr=subprocess.STDOUT, cwd=REPO,
                            start_new_session=True, env=_env(LAB=lights.endpoint, SAMPLES="3000"))
    lights.extra.append(proc)
    try:
        td = _generated_td(lights, proc, log)
        assert "panda_link0" in td["properties"]["getJointposition"]["description"]
        scene_link = next(link["href"] for link in td["links"] if link["rel"].endswith("scene"))
        scene = httpx.get(scene_link, timeout=10).json()
        assert {"bench", "crate", "bin", "wall"} <= {body.get("name") for body in scene["bodies"]}

        free = lights.cli("invoke", "panda", "moveToCartesianPosition", '{"x": 400, "y": 0, "z": 400}', timeout=180)
        assert free.returncode == 0, free.stderr
        assert abs(json.loads(free.stdout)["reached"]["z"] - 400) < 1
        crate = lights.cli("plan", "panda", "450", "-300", "100", timeout=180)  # inside the crate on the bench
        assert crate.returncode == 1, crate.stdout
        assert "refused" in crate.stderr and "/ crate" in crate.stderr, crate.stderr  # the scene's crate is in the way
    finally:
        assert stop_process(proc), log.read_text()[-3000:]
        lights.extra.remove(proc)


# --- examples/node-wot ----------------------------------------------------------------------------


@pytest.mark.interop
def test_the_node_wot_script_runs_the_cube_workflow_by_affordance_names(platform, tmp_path):
    from interop import npm

    npm.ensure_node_modules()  # node-wot 0.9.2 as the interop tests install it, shared with them
    script = tmp_path / "cube-workflow.mjs"  # beside a node_modules, as after `npm install` in its folder
    shutil.copy(EXAMPLES / "node-wot" / "cube-workflow.mjs", script)
    (tmp_path / "node_modules").symlink_to(npm.INTEROP_DIR / "node_modules")
    deps = json.loads((EXAMPLES / "node-wot" / "package.json").read_text())["dependencies"]
    assert deps == {k: v for k, v in json.loads((npm.INTEROP_DIR / "package.json").read_text())["dependencies"].items()
                    if k.startswith("@node-wot/")}, "the example asks for the node-wot the tests run"
    done = subprocess.run(["node", str(script), platform.http], capture_output=True, text=True, timeout=900,
                          cwd=tmp_path)
    steps = [line for line in done.stdout.splitlines() if line[:1].isdigit()]
    assert done.returncode == 0, f"{done.stdout}\n--- stderr ---\n{done.stderr[-3000:]}"
    assert len(steps) == 8 and all(line.endswith(": done") for line in steps), done.stdout
    color = json.loads(done.stdout.split("colour: ", 1)[1])
    assert len(color) == 3 and all(0 <= c <= 255 for c in color)


# --- examples/hosts -------------------------------------------------------------------------------


def test_the_two_host_recipe_puts_host_b_devices_on_host_a_lab(tmp_path):
    from tests import netns

    why_not = netns.unavailable()
    if why_not:
        pytest.skip(f"network namespaces: {why_not}")
    with netns.hosts(2) as net:
        a, b = net.hosts
        endpoint, base = f"tcp/{a.address}:7447", f"http://{a.address}:8080"
        a_log, b_log = tmp_path / "host-a.log", tmp_path / "host-b.log"
        a.popen(["sh", str(EXAMPLES / "hosts" / "host-a.sh"), "--no-view"], a_log, env=_env())
        ready = _run(["twinmesh", "--connect", endpoint, "wait", "--timeout", "600"], timeout=660)
        assert ready.returncode == 0, f"{ready.stderr}\n{a_log.read_text()[-3000:]}"
        b.popen(["sh", str(EXAMPLES / "hosts" / "host-b.sh"), "--no-view"], b_log, env=_env(LAB_HOST=a.address))
        station = {"belt-1", "infrared-1", "color-1", "light-1", "climate-1"}

        def listed() -> list[str]:
            names = _run(["twinmesh", "--connect", endpoint, "things"], timeout=60).stdout.split()
            assert station | {"light-left", "light-right"} <= set(names), f"{names}\n{b_log.read_text()[-2000:]}"
            return names

        names = eventually(listed, timeout=600, what="host B's station listed by host A's lab")
        assert names == sorted(names)
        def read() -> float | None:
            r = httpx.get(f"{base}/climate-1/properties/temperature", timeout=10)
            return r.json() if r.status_code == 200 else None

        temperature = eventually(read, timeout=120, what="host B's climate sensor read through host A's adapter")
        assert isinstance(temperature, (int, float))
