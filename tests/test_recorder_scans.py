"""The recorder draws a scene's scan as points and its CAD mesh as a mesh, from the files a Thing serves.

The drawer alone (no lab): a robot's twin.json whose scene holds a points body (an organized PCD with NaN
points, as a depth camera writes it) and a mesh body (an OBJ in millimetres), the files handed over as the
recorder's fetcher gets them, drawn into a real Rerun recording and read back with rerun's reader.
"""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import rerun as rr
import trimesh
from scan_formats import write_e57, write_las
from scans import Scan, write_pcd
from scipy.spatial.transform import Rotation

from mesh.messages.scene_description import Pose, TwinDescription
from mesh.recorder.robots import RobotDrawer, read_scene_assets
from mesh.recorder.scene_assets import MAX_POINTS, read_asset
from mesh.recorder.scene_drawer import SceneDrawer
from recordings import latest_static, placed

UR10_URDF = (Path(__file__).resolve().parents[1] / "tdgen" / "robot" / "models" / "ur10.urdf").read_text()
SENSOR = {"position": [1.2, -0.8, 1.4], "rpy": [-120.0, 5.0, 40.0]}
CRATE = {"position": [0.6, 0.3, 0.2], "rpy": [0.0, 0.0, 30.0], "scale": 0.001}


def _organized_cloud(seed: int = 1) -> Scan:
    rng = np.random.default_rng(seed)
    points = rng.uniform([-1, -1, 0.5], [1, 1, 3], (48, 64, 3))
    points[rng.random((48, 64)) < 0.1] = np.nan  # holes: nothing came back
    return Scan(points, tuple(SENSOR["position"]), tuple(SENSOR["rpy"]))  # type: ignore[arg-type]


def _twin(bodies: list[dict], files: dict[str, str]) -> TwinDescription:
    return TwinDescription(robot="ur10", urdf="tdgen/robot/models/ur10.urdf", urdf_sha256="0" * 64,
                           urdf_file="ur10.urdf", base=Pose((0.0, 0.0, 0.6)), scene={"bodies": bodies},
                           scene_files=files)


@pytest.fixture(scope="module")
def drawn(tmp_path_factory):
    """The robot drawn in its own world with a scan, a crate (OBJ, mm) and a body whose file is broken."""
    folder = tmp_path_factory.mktemp("scans")
    scan = _organized_cloud()
    write_pcd(scan, folder / "room.pcd")
    crate = trimesh.creation.box((300.0, 200.0, 400.0))  # mm
    crate.export(folder / "crate.obj")
    served = {"scene-room.pcd": (folder / "room.pcd").read_bytes(), "scene-crate.obj": (folder / "crate.obj").read_bytes(),
              "scene-broken.stl": b"solid nothing here"}
    bodies = [{"type": "box", "name": "table", "size": [0.6, 0.6, 0.6], "position": [0, 0, 0.3]},
              {"type": "points", "name": "room", "file": "/lab/scans/room.pcd", **SENSOR},
              {"type": "mesh", "name": "crate", "file": "/lab/cad/crate.obj", **CRATE},
              {"type": "mesh", "name": "broken", "file": "/lab/cad/broken.stl"}]
    twin = _twin(bodies, {"/lab/scans/room.pcd": "scene-room.pcd", "/lab/cad/crate.obj": "scene-crate.obj",
                          "/lab/cad/broken.stl": "scene-broken.stl"})
    from mesh.recorder.robots import RobotFiles

    files = RobotFiles("ur10", twin, UR10_URDF, read_scene_assets(twin, served.__getitem__))
    path = folder / "drawn.rrd"
    rec = rr.RecordingStream("scan-drawer")
    rec.save(str(path))
    problems = RobotDrawer(rec, SceneDrawer(rec)).draw_robot(files)
    rec.flush()
    rec.disconnect()
    return path, scan, trimesh.load(folder / "crate.obj", force="mesh"), problems


def test_a_scan_is_drawn_as_its_finite_points_where_the_sensor_stood(drawn):
    path, scan, _, _ = drawn
    entity = "/robots/ur10/scene/room"
    points = latest_static(path, entity, "Points3D:positions")
    assert len(points) == len(scan.finite())  # the holes left out, every other point drawn
    assert np.allclose(placed(path, entity, points), scan.world(), atol=1e-5)


def test_a_cad_mesh_is_drawn_as_its_triangles_scaled_to_metres_in_its_pose(drawn):
    path, _, crate, _ = drawn
    entity = "/robots/ur10/scene/crate"
    assert len(latest_static(path, entity, "Mesh3D:triangle_indices")) == len(crate.faces)
    drawn = placed(path, entity, latest_static(path, entity, "Mesh3D:vertex_positions"))
    truth = Rotation.from_euler("xyz", CRATE["rpy"], degrees=True).apply(crate.vertices * 0.001) + CRATE["position"]
    assert np.allclose(drawn, truth, atol=1e-6)


def test_a_file_that_cannot_be_drawn_is_said_and_the_rest_is_drawn(drawn):
    path, _, _, problems = drawn
    assert [p for p in problems if "broken" in p] and all("room" not in p and "crate" not in p for p in problems)
    assert latest_static(path, "/robots/ur10/scene/table", "Boxes3D:half_sizes")


def test_a_large_cloud_is_drawn_with_at_most_100k_of_its_own_points(tmp_path):
    from pypcd4 import PointCloud

    n = 150_000
    xyz = np.column_stack([np.arange(n) * 1e-4, np.zeros(n), np.ones(n)]).astype(np.float32)
    PointCloud.from_xyz_points(xyz).save(tmp_path / "big.pcd")
    asset = read_asset("points", "big.pcd", (tmp_path / "big.pcd").read_bytes())
    assert asset.total == n and len(asset.points) == MAX_POINTS
    index = np.round(asset.points[:, 0] / 1e-4).astype(int)
    assert len(set(index)) == MAX_POINTS and np.allclose(asset.points, xyz[index])  # its own points, each once
    again = read_asset("points", "big.pcd", (tmp_path / "big.pcd").read_bytes())
    assert np.array_equal(again.points, asset.points)  # the same choice every time: a redraw shows the same cloud


@pytest.mark.parametrize("name, write", [("room.las", write_las), ("room.laz", write_las), ("room.e57", write_e57)])
def test_a_las_or_e57_scan_is_drawn_as_its_points_where_the_sensor_stood(tmp_path, name, write):
    from mesh.recorder.robots import RobotFiles

    scan = _organized_cloud(seed=2)
    served = {f"scene-{name}": write(scan, tmp_path / name).read_bytes()}
    twin = _twin([{"type": "points", "name": "room", "file": f"/lab/scans/{name}", **SENSOR}],
                 {f"/lab/scans/{name}": f"scene-{name}"})
    path = tmp_path / "drawn.rrd"
    rec = rr.RecordingStream("scan-formats")
    rec.save(str(path))
    problems = RobotDrawer(rec, SceneDrawer(rec)).draw_robot(
        RobotFiles("ur10", twin, UR10_URDF, read_scene_assets(twin, served.__getitem__)))
    rec.flush()
    rec.disconnect()
    assert not problems
    entity = "/robots/ur10/scene/room"
    points = latest_static(path, entity, "Points3D:positions")
    assert len(points) == len(scan.finite())
    assert np.allclose(placed(path, entity, points), scan.world(), atol=1e-4)
