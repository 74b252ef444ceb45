"""Which files `addObstacle` takes: only those in the lab's scans folder, since the world then serves them to
anyone who may read it. A path relative to the folder or absolute inside it is read; one that leaves it (an
absolute path elsewhere, `..`, a symbolic link pointing out) is refused with `file-outside-scans`, in one line
naming the path and the folder, before anything is read."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from devices.sim.layouts.obstacles import default_scans_dir, from_input
from mesh.wot.problem import Refused

SENSOR = [2.3, -0.42, 0.9]


@pytest.fixture(autouse=True)
def _own_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TWINMESH_CACHE", str(tmp_path / "cache"))  # a scan's voxels are cached there


def _cloud(path: Path, seed: int = 1) -> Path:
    """A usable XYZ scan: a 20 cm patch of numbers, as any `.txt` or `.csv` of three columns would be."""
    path.parent.mkdir(parents=True, exist_ok=True)
    xyz = np.random.default_rng(seed).uniform([-0.1, -0.1, -0.05], [0.1, 0.1, 0.05], (300, 3))
    np.savetxt(path, xyz, fmt="%.5f")
    return path


@pytest.fixture
def folders(tmp_path) -> tuple[Path, Path]:
    """The scans folder (with a usable scan in it) and a secret beside it that parses as a cloud too."""
    scans = tmp_path / "scans"
    _cloud(scans / "room.xyz")
    return scans, _cloud(tmp_path / "private" / "secret.txt", seed=2)


def _scan(file: str) -> dict:
    return {"name": "scan", "type": "points", "file": file, "position": SENSOR, "voxel": 0.03}


def _refused(value: dict, scans: Path) -> Refused:
    with pytest.raises(Refused) as caught:
        from_input(value, scans)
    return caught.value


def test_a_scan_in_the_folder_is_taken_by_a_relative_or_an_absolute_path(folders):
    scans, _ = folders
    (scans / "today").mkdir()
    _cloud(scans / "today" / "shelf.xyz", seed=3)
    assert from_input(_scan("room.xyz"), scans).file == str((scans / "room.xyz").resolve())
    assert from_input(_scan(str(scans / "room.xyz")), scans).file == str((scans / "room.xyz").resolve())
    assert from_input(_scan("today/../today/shelf.xyz"), scans).file == str((scans / "today" / "shelf.xyz").resolve())


def test_a_link_inside_the_folder_to_a_file_inside_it_is_taken(folders):
    scans, _ = folders
    (scans / "latest.xyz").symlink_to(scans / "room.xyz")
    assert from_input(_scan("latest.xyz"), scans).file == str((scans / "room.xyz").resolve())


@pytest.mark.parametrize("how", ["absolute", "dot-dot", "link-out", "linked-folder-out", "mesh"])
def test_a_file_outside_the_folder_is_refused_naming_it_and_the_folder(folders, how):
    scans, secret = folders
    if how == "link-out":
        (scans / "innocent.xyz").symlink_to(secret)
    if how == "linked-folder-out":
        (scans / "linked").symlink_to(secret.parent, target_is_directory=True)
    file = {"absolute": str(secret), "dot-dot": "../private/secret.txt", "link-out": "innocent.xyz",
            "linked-folder-out": "linked/secret.txt", "mesh": str(secret)}[how]
    value = {**_scan(file), "type": "mesh"} if how == "mesh" else _scan(file)
    problem = _refused(value, scans)
    assert problem.status == 422 and problem.reason == "file-outside-scans"
    detail = problem.detail
    assert file in detail and str(scans.resolve()) in detail and "\n" not in detail


def test_a_missing_folder_refuses_every_file_but_never_one_outside_it_as_missing(tmp_path, folders):
    _, secret = folders
    gone = tmp_path / "no-scans-yet"
    assert _refused(_scan("room.xyz"), gone).reason == "unusable-file"  # said as a file it cannot use
    assert _refused(_scan(str(secret)), gone).reason == "file-outside-scans"


def test_the_default_folder_is_the_data_directorys_scans_unless_the_environment_says(monkeypatch, tmp_path):
    monkeypatch.delenv("TWINMESH_SCANS", raising=False)
    monkeypatch.setenv("XDG_DATA_HOME", str(tmp_path / "data"))
    assert default_scans_dir() == tmp_path / "data" / "twinmesh" / "scans"
    monkeypatch.setenv("TWINMESH_SCANS", str(tmp_path / "elsewhere"))
    assert default_scans_dir() == tmp_path / "elsewhere"
