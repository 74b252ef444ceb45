"""A scan as an obstacle while the iot-lab runs: the world serves its file beside scene.json, the UR10's TD
follows and links it too, a newer scan under the same name replaces it, a file that cannot be used is refused
in one line, and so is a file outside the lab's scans folder (which the world would otherwise serve to anyone).

Its own `twinmesh up` (the iot-lab at `--speed max`, 2000 samples, a fresh tdgen cache, `--scans` a temporary
folder); the scan is a small patch of points on the UR10's table, clear of the robot where it stands, written
as a PCD.
"""
from __future__ import annotations

import hashlib
from pathlib import Path

import httpx
import numpy as np
import pytest
from labs import start_lab
from waiting import eventually

from mesh.messages.relations import SCENE, SCENE_ASSET

pytestmark = pytest.mark.lab

LISTED = {"dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2", "color-sensor",
          "uarm", "ur10", "light-left", "light-right", "pan-tilt-1", "pan-tilt-2", "world", "tdgen"}
SENSOR = [2.3, -0.42, 0.9]  # where a crate stands in test_iot_lab: clear of the UR10 at rest


def _patch(path: Path, seed: int, n: int = 400) -> Path:
    """A scan of a 20 cm patch (sensor frame), NaN returns among its points."""
    from pypcd4 import PointCloud

    xyz = np.random.default_rng(seed).uniform([-0.1, -0.1, -0.05], [0.1, 0.1, 0.05], (n, 3)).astype(np.float32)
    xyz[::37] = np.nan
    PointCloud.from_xyz_points(xyz).save(path)
    return path


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("iot-lab-scans")
    (tmp / "scans").mkdir()
    lab = start_lab(tmp, None, http=True, things=LISTED, extra_args=(
        "--speed", "max", "--samples", "2000", "--tdgen-cache", str(tmp / "cache"), "--scans", str(tmp / "scans")))
    lab.tmp, lab.scans = tmp, tmp / "scans"
    yield lab
    assert lab.stop(), "the lab did not stop cleanly"


@pytest.fixture
def http(lab):
    with httpx.Client(base_url=lab.http, timeout=120) as client:
        yield client


def _links(td: dict, rel: str) -> list[dict]:
    return [link for link in td.get("links", []) if link.get("rel") == rel]


def _with_assets(td: dict) -> dict | None:
    return td if _links(td, SCENE_ASSET) else None


def _version(td: dict) -> int:
    return int(td.get("version", {}).get("instance", -1))


def test_a_scan_obstacle_is_served_by_the_world_and_followed_by_the_ur10(lab, http):
    scan = _patch(lab.scans / "patch.pcd", seed=1)
    ur10_before = _version(http.get("/ur10").json())
    r = http.post("/world/actions/addObstacle", json={"name": "scan", "type": "points", "file": str(scan),
                                                     "position": SENSOR, "voxel": 0.03})
    assert r.status_code in (200, 204), r.text
    world = eventually(lambda: _with_assets(http.get("/world").json()), timeout=30, what="the world's new TD")
    assets = _links(world, SCENE_ASSET)
    assert [a["type"] for a in assets] == ["application/octet-stream"]
    scene_url = _links(world, SCENE)[0]["href"]
    body = next(b for b in http.get(scene_url).json()["bodies"] if b["name"] == "obstacle-scan")
    assert body["shape"] == "points" and httpx.URL(scene_url).join(body["file"]) == httpx.URL(assets[0]["href"])
    assert hashlib.sha256(http.get(assets[0]["href"]).content).digest() == hashlib.sha256(scan.read_bytes()).digest()

    def followed() -> dict | None:
        td = http.get("/ur10").json()
        return td if _version(td) > ur10_before and _links(td, SCENE_ASSET) else None

    ur10 = eventually(followed, timeout=180, what="the UR10's TD with the scan")
    link = _links(ur10, SCENE_ASSET)[0]["href"]
    served = next(b for b in http.get(_links(ur10, SCENE)[0]["href"]).json()["bodies"] if b["name"] == "obstacle-scan")
    assert httpx.URL(_links(ur10, SCENE)[0]["href"]).join(served["file"]) == httpx.URL(link)
    assert http.get(link).content == scan.read_bytes()


def test_a_newer_scan_under_its_name_replaces_it_and_a_bad_file_is_refused(lab, http):
    newer = _patch(lab.scans / "newer.pcd", seed=2)
    r = http.post("/world/actions/addObstacle", json={"name": "scan", "type": "points", "file": "newer.pcd",
                                                     "position": SENSOR, "voxel": 0.03})
    assert r.status_code in (200, 204), r.text
    assert [o["name"] for o in http.get("/world/properties/obstacles").json()] == ["scan"]
    scene = http.get("/world/files/scene.json").json()
    (body,) = [b for b in scene["bodies"] if b["name"] == "obstacle-scan"]
    assert http.get(f"/world/files/{body['file']}").content == newer.read_bytes()

    (lab.scans / "empty.pcd").write_bytes(b"")
    r = http.post("/world/actions/addObstacle", json={"name": "empty", "type": "points",
                                                     "file": str(lab.scans / "empty.pcd"), "position": SENSOR})
    assert r.status_code == 422 and r.json()["reason"] == "unusable-file"
    assert "empty.pcd" in r.json()["detail"] and "\n" not in r.json()["detail"]
    r = http.post("/world/actions/addObstacle", json={"name": "nofile", "type": "mesh", "position": SENSOR})
    assert r.status_code == 422 and r.json()["reason"] == "file-needed"  # valid by the schema, refused
    r = http.post("/world/actions/addObstacle", json={"name": "nosize", "position": SENSOR})
    assert r.status_code == 422 and r.json()["reason"] == "size-needed"
    assert http.post("/world/actions/removeObstacle", json={"name": "scan"}).status_code == 200
    assert "obstacle-scan" not in {b["name"] for b in http.get("/world/files/scene.json").json()["bodies"]}
    eventually(lambda: not _links(http.get("/world").json(), SCENE_ASSET), timeout=30, what="the link gone")


@pytest.mark.parametrize("how", ["absolute", "dot-dot", "link-out"])
def test_a_file_outside_the_scans_folder_is_refused_and_never_served(lab, http, how):
    (lab.tmp / "private").mkdir(exist_ok=True)
    secret = _patch(lab.tmp / "private" / "secret.pcd", seed=3)  # a usable scan: refused for where it is
    if how == "link-out":
        (lab.scans / "innocent.pcd").unlink(missing_ok=True)
        (lab.scans / "innocent.pcd").symlink_to(secret)
    file = {"absolute": str(secret), "dot-dot": "../private/secret.pcd", "link-out": "innocent.pcd"}[how]
    before = http.get("/world/files/scene.json").json()
    r = http.post("/world/actions/addObstacle", json={"name": "peek", "type": "points", "file": file,
                                                     "position": SENSOR})
    assert r.status_code == 422 and r.headers["content-type"].startswith("application/problem+json"), r.text
    problem = r.json()
    assert problem["reason"] == "file-outside-scans"
    assert file in problem["detail"] and str(lab.scans.resolve()) in problem["detail"] and "\n" not in problem["detail"]
    assert "peek" not in {o["name"] for o in http.get("/world/properties/obstacles").json()}
    assert http.get("/world/files/scene.json").json() == before  # nothing moved, nothing new to download
    assert {http.get(f"/world/files/scene-{n}.pcd").status_code for n in ("secret", "innocent")} == {404}
    assert http.get("/world/properties/stepping").json() is True  # the world keeps serving
