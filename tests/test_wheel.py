"""A normal install works: the wheel holds every file the code reads at run time, and the `iot-lab`
starts from it, in a fresh virtual environment, run from a folder outside the repository.

The wheel goes into a new venv with `pip install --no-deps`; its dependencies are this environment's
already-installed ones, seen through a `.pth` line, and the wheel's declared requirements are checked
against them (what `pip check` would say). Downloading or unpacking numpy, pybullet, scipy, numba and
rerun again would prove pip works, not twinmesh. `TWINMESH_WHEEL_FULL_INSTALL=1` runs the whole
install, dependencies and all, as a user's first `pip install` does (minutes). The installed lab runs
uncompiled, as a first start does before its compile is done (tests/compiling.py): its modules' new
paths would have numba compile every loop again in every process.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import sysconfig
import zipfile
from pathlib import Path

import httpx
import pytest
from compiling import compiling_elsewhere
from labs import REPO, free_port, stop_process

pytestmark = [pytest.mark.lab, pytest.mark.slow]  # a wheel, a fresh venv, an install

FULL_INSTALL = os.environ.get("TWINMESH_WHEEL_FULL_INSTALL") == "1"
# what the code reads beside its modules
DATA = ["tdgen/robot/models/ur10.urdf", "tdgen/robot/models/uarm_swift_pro.urdf",
        "tdgen/robot/models/dobot_magician.urdf", "tdgen/robot/models/pan-tilt.urdf",
        "tdgen/robot/models/uarm-calibration.csv", "tdgen/robot/scenes/table-and-wall.json",
        "tdgen/robot/scenes/cluttered-lab.json", "devices/things/tds/pan-tilt.json",
        "devices/things/tds/uarm.json", "devices/things/tds/dobot.json", "mesh/http/ui/index.html",
        "mesh/http/ui/app.js", "mesh/http/ui/style.css"]
# run by the new venv's python: where twinmesh comes from, and each requirement of the wheel's metadata
# (no extra) that what the venv can import does not meet
REQUIREMENTS_MET = """
import importlib.metadata as md, json, mesh, tdgen, devices
from packaging.requirements import Requirement
dist = md.distribution("twinmesh")  # the first on sys.path: the venv's own
unmet = []
for line in dist.requires or []:
    req = Requirement(line)
    if req.marker is not None and not req.marker.evaluate({"extra": ""}):
        continue
    try:
        found = md.version(req.name)
    except md.PackageNotFoundError:
        unmet.append(f"{req}: not installed")
        continue
    if not req.specifier.contains(found, prereleases=True):
        unmet.append(f"{req}: {found} installed")
print(json.dumps({"version": dist.version, "modules": [m.__file__ for m in (mesh, tdgen, devices)], "unmet": unmet}))
"""


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


def _run(args: list[str], env: dict[str, str], cwd: Path, timeout: float = 600) -> subprocess.CompletedProcess:
    done = subprocess.run(args, capture_output=True, text=True, timeout=timeout, env=env, cwd=cwd)
    assert done.returncode == 0, f"{' '.join(args)}\n{done.stderr[-2000:]}"
    return done


def _install(wheel: Path, venv: Path, env: dict[str, str], cwd: Path) -> None:
    """The wheel in a fresh `venv`: alone, its dependencies this environment's (a `.pth` line adds a folder to
    sys.path without processing that folder's own .pth files, so the checkout's editable install stays out);
    with TWINMESH_WHEEL_FULL_INSTALL=1, with every dependency installed by pip."""
    if FULL_INSTALL:
        _run([sys.executable, "-m", "venv", str(venv)], env, cwd, timeout=120)
        _run([str(venv / "bin" / "python"), "-m", "pip", "install", "-q", str(wheel)], env, cwd, timeout=1200)
        return
    _run([sys.executable, "-m", "venv", "--without-pip", str(venv)], env, cwd, timeout=120)
    python = str(venv / "bin" / "python")
    # installed before the dependencies are visible: pip sees no other twinmesh, so it replaces nothing outside
    _run([sys.executable, "-m", "pip", "--python", python, "install", "-q", "--no-deps", str(wheel)], env, cwd)
    site = Path(_run([python, "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"], env, cwd).stdout.strip())
    ours = dict.fromkeys(sysconfig.get_paths()[k] for k in ("purelib", "platlib"))
    (site / "test-dependencies.pth").write_text("".join(f"{folder}\n" for folder in ours))


def test_the_iot_lab_starts_from_an_installed_wheel(wheel, tmp_path):
    venv = tmp_path / "venv"
    # nothing of the checkout or the test's own environment may leak in (a PYTHONPATH would show pip the
    # checkout's egg-info as twinmesh already installed)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    elsewhere = tmp_path / "elsewhere"  # not the repository: nothing can be read from the checkout
    elsewhere.mkdir()
    _install(wheel, venv, env, tmp_path)
    found = json.loads(_run([str(venv / "bin" / "python"), "-c", REQUIREMENTS_MET], env, elsewhere,
                            timeout=120).stdout.strip().splitlines()[-1])
    assert found["version"] == wheel.name.split("-")[1], found  # the wheel's metadata, not the checkout's
    assert all(module.startswith(str(venv)) for module in found["modules"]), found["modules"]
    assert found["unmet"] == [], "the wheel's requirements that the environment does not meet"
    twinmesh = str(venv / "bin" / "twinmesh")
    with compiling_elsewhere(tmp_path / "numba") as uncompiled:
        _serve_the_iot_lab(twinmesh, {**env, **uncompiled}, elsewhere, tmp_path)


def _serve_the_iot_lab(twinmesh: str, env: dict[str, str], elsewhere: Path, tmp_path: Path) -> None:
    """`twinmesh up iot-lab` from the installed command: every Thing, the control page and the live view."""
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
