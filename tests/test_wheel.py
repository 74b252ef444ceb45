"""A normal install works: the wheel holds every file the code reads at run time, and the `iot-lab`
starts from it, in a fresh virtual environment, run from a folder outside the repository."""
from __future__ import annotations

import os
import subprocess
import sys
import zipfile
from pathlib import Path

import httpx
import pytest
from labs import REPO, free_port, stop_process

pytestmark = [pytest.mark.lab, pytest.mark.slow]  # a wheel, a fresh venv, an install

# what the code reads beside its modules
DATA = ["tdgen/robot/models/ur10.urdf", "tdgen/robot/models/uarm_swift_pro.urdf",
        "tdgen/robot/models/dobot_magician.urdf", "tdgen/robot/models/pan-tilt.urdf",
        "tdgen/robot/models/uarm-calibration.csv", "tdgen/robot/scenes/table-and-wall.json",
        "tdgen/robot/scenes/cluttered-lab.json", "devices/things/tds/pan-tilt.json",
        "devices/things/tds/uarm.json", "devices/things/tds/dobot.json", "mesh/http/ui/index.html",
        "mesh/http/ui/app.js", "mesh/http/ui/style.css"]


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    out = tmp_path_factory.mktemp("wheel")
    subprocess.run([sys.executable, "-m", "pip", "wheel", "-q", "--no-deps", "-w", str(out), str(REPO)],
                   check=True, capture_output=True, timeout=600)
    return next(out.glob("twinmesh-*.whl"))


def test_the_wheel_holds_every_data_file(wheel):
    names = set(zipfile.ZipFile(wheel).namelist())
    assert [d for d in DATA if d not in names] == []
    assert len([n for n in names if n.startswith("devices/things/tds/")]) == len(
        list((REPO / "devices" / "things" / "tds").glob("*.json")))


def test_the_iot_lab_starts_from_an_installed_wheel(wheel, tmp_path):
    venv = tmp_path / "venv"
    # nothing of the checkout or the test's own environment may leak in (a PYTHONPATH would show pip the
    # checkout's egg-info as twinmesh already installed)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True, timeout=120, env=env)
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q", str(wheel)]
    installed = subprocess.run(pip, capture_output=True, text=True, timeout=1200, env=env, cwd=tmp_path)
    assert installed.returncode == 0, installed.stderr[-2000:]
    twinmesh = str(venv / "bin" / "twinmesh")
    elsewhere = tmp_path / "elsewhere"  # not the repository: nothing can be read from the checkout
    elsewhere.mkdir()
    imports = subprocess.run([str(venv / "bin" / "python"), "-c", "import mesh, tdgen, devices; from mesh import consume; "
                              "print(mesh.__file__)"], cwd=elsewhere, capture_output=True, text=True, timeout=120,
                             env=env)
    assert imports.returncode == 0 and str(venv) in imports.stdout, imports.stderr[-2000:]
    endpoint, port, view = f"tcp/127.0.0.1:{free_port()}", free_port(), free_port()
    log = tmp_path / "lab.log"
    lab = subprocess.Popen([twinmesh, "--connect", endpoint, "up", "iot-lab", "--speed", "max", "--samples", "2000",
                            "--http", f"127.0.0.1:{port}", "--view", f"127.0.0.1:{view}",
                            "--tdgen-cache", str(tmp_path / "cache")],
                           cwd=elsewhere, env=env, stdout=open(log, "wb"), stderr=subprocess.STDOUT,
                           start_new_session=True)
    try:
        ready = subprocess.run([twinmesh, "--connect", endpoint, "wait", "--timeout", "240"], cwd=elsewhere, env=env,
                               capture_output=True, text=True, timeout=300)
        assert ready.returncode == 0, f"{ready.stderr}\n{log.read_text()[-3000:]}"
        things = httpx.get(f"http://127.0.0.1:{port}/things").json()
        assert {td["title"] for td in things} >= {"uarm", "dobot", "ur10", "pan-tilt-1", "world", "tdgen"}
        assert httpx.get(f"http://127.0.0.1:{port}/pan-tilt-1/properties/panPosition").status_code == 200
        page = httpx.get(f"http://127.0.0.1:{port}/", headers={"Accept": "text/html"})  # the control page's files
        assert page.status_code == 200 and "/_ui/app.js" in page.text
        assert "every Thing the adapter lists" in httpx.get(f"http://127.0.0.1:{port}/_ui/app.js").text
        assert "Rerun" in httpx.get(f"http://127.0.0.1:{view}/").text  # the live view's viewer, from rerun-sdk
    finally:
        stopped_alone = stop_process(lab, timeout=60)
    assert stopped_alone and lab.returncode == 0, f"the installed lab did not stop on Ctrl-C\n{log.read_text()[-3000:]}"
