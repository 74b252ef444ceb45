"""The tdgen cache sees a scene's scan by its content: the room scanned again into the same file is a new
generation with the new flags; a file only touched (or written again unchanged) is the entry made before."""
from __future__ import annotations

import hashlib
import os

import numpy as np
import pytest

from mesh.messages.scene_description import Pose, TwinDescription
from tdgen.artefacts import artefact_key, make_artefacts
from tdgen.cache import ArtefactCache
from tdgen.robot import points_csv
from tdgen.robot.model import resolve_urdf

SAMPLES = 400


@pytest.fixture(autouse=True)
def scan_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TWINMESH_CACHE", str(tmp_path / "scans"))  # the prepared scans, not the compiled code


def _wall(path, x: float) -> None:
    """A scan of a wall across the x axis at `x` (m), 2 m wide and tall, a point every 2 cm."""
    y, z = np.meshgrid(np.arange(-1.0, 1.0, 0.02), np.arange(0.0, 2.0, 0.02))
    np.savetxt(path, np.column_stack([np.full(y.size, x), y.ravel(), z.ravel()]), fmt="%.4f")


def _twin(scan) -> TwinDescription:
    urdf = resolve_urdf("ur10.urdf")
    body = {"type": "points", "name": "scan", "file": str(scan), "voxel": 0.04}
    return TwinDescription(robot="ur10", urdf="ur10.urdf", urdf_sha256=hashlib.sha256(urdf.read_bytes()).hexdigest(),
                           base=Pose(p=[0, 0, 0], q=[0, 0, 0, 1]), scene={"bodies": [body]}, samples=SAMPLES, seed=3)


def _colliding(entry) -> np.ndarray:
    return points_csv.read(entry / "points.csv")[1]


def test_a_scan_written_again_into_the_same_file_is_generated_again(tmp_path):
    scan, cache = tmp_path / "room.xyz", ArtefactCache(tmp_path / "tdgen")
    _wall(scan, 1.1)
    twin = _twin(scan)
    far_key = artefact_key(twin)
    far = make_artefacts(twin, cache, far_key, workers=1)
    _wall(scan, 0.45)  # the same path, the wall nearer the robot
    near_key = artefact_key(twin)
    assert near_key != far_key and not cache.has(near_key)
    near = make_artefacts(twin, cache, near_key, workers=1)
    before, after = _colliding(far), _colliding(near)
    assert after.sum() > before.sum()  # the nearer wall takes more of the arm's room
    assert (near / "workspace.stl").read_bytes() != (far / "workspace.stl").read_bytes()


def test_a_scan_only_touched_is_the_entry_made_before(tmp_path):
    scan, cache = tmp_path / "room.xyz", ArtefactCache(tmp_path / "tdgen")
    _wall(scan, 0.8)
    twin = _twin(scan)
    key = artefact_key(twin)
    make_artefacts(twin, cache, key, workers=1)
    later = scan.stat().st_mtime + 3600
    os.utime(scan, (later, later))
    assert artefact_key(twin) == key and cache.has(key)
    scan.write_bytes(scan.read_bytes())  # written again, unchanged
    assert artefact_key(twin) == key


def test_a_missing_scan_is_a_key_of_its_own(tmp_path):
    scan = tmp_path / "room.xyz"
    _wall(scan, 0.8)
    twin = _twin(scan)
    key = artefact_key(twin)
    scan.unlink()
    assert artefact_key(twin) != key
