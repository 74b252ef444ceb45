"""A scene's CAD meshes and scans are reachable from the TD: a consumer that downloads scene.json and the files
it links over HTTP rebuilds the same scene; the recorder draws them from the same files.

The robot: `twinmesh robot --scene FILE` on the shared lights lab, its scene holding a known table, a closed mesh (a ring,
STL, in a subfolder), a scan (an organized PCD with NaN points, in another subfolder) and a chest (a .gltf whose
geometry is in .bin files beside it, with a texture in a folder below: served as one GLB), at `--speed max` with
the exact collision model. A client does what any HTTP consumer would: GET the TD through the adapter, GET
scene.json and every `scene-asset` link into an empty folder, load it with tdgen's scene loader, and asks the
rebuilt scene about configurations of the robot's own points.csv. The world: a `world` Thing served from
this test process on the same mesh, its scene (the same bodies, the UR10 standing where the robot does) naming
the same files, downloaded and rebuilt the same way. Then `twinmesh record` records the robot: its
scan drawn as points and its ring and chest as meshes, where the scene puts them, in the robot's own world and in
the world's.
"""
from __future__ import annotations

import hashlib
import json
from pathlib import Path
from urllib.parse import urljoin

import httpx
import numpy as np
import pytest
import trimesh
from labs import stop_process
from scans import render_scan, write_gltf, write_pcd
from waiting import eventually

from mesh.messages.relations import POINTS, SCENE, SCENE_ASSET, TWIN, WORKSPACE
from recordings import latest_static, placed, wait_for_line
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.model import Robot
from tdgen.robot.scan_io import read_cloud
from tdgen.robot.surroundings import Surroundings, load_scene, prepare

pytestmark = pytest.mark.lab

NAME = "scanbot"
RING = {"type": "mesh", "name": "ring", "file": "cad/ring.stl", "position": [0.55, 0.35, 0.95], "rpy": [90, 0, 0]}
TABLE = {"type": "box", "name": "table", "size": [0.6, 0.6, 0.6], "position": [0.0, 0.0, 0.3]}
CHEST = {"type": "mesh", "name": "chest", "file": "cad/chest/chest.gltf", "position": [-0.55, -0.4, 0.8],
         "rpy": [0, 0, 20]}


@pytest.fixture(autouse=True, scope="module")
def scan_cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TWINMESH_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def scene_file(tmp_path_factory) -> Path:
    """scene.json with a table, the ring (cad/ring.stl), the room's scan (scans/room.pcd) and the chest
    (cad/chest/chest.gltf, chest_0.bin and chest_1.bin beside it, a texture in cad/chest/textures/)."""
    from tdgen.robot.surroundings import BoxBody

    folder = tmp_path_factory.mktemp("scene")
    (folder / "cad").mkdir()
    (folder / "scans").mkdir()
    trimesh.creation.torus(0.25, 0.05).export(folder / "cad" / "ring.stl")
    (folder / "cad" / "chest").mkdir()
    write_gltf(folder / "cad" / "chest", name="chest", size=(0.4, 0.3, 0.4))
    room = Surroundings(name="room", bodies=[
        BoxBody(name="wall", size=(2.0, 0.1, 1.6), position=(0.0, 0.6, 0.8)),
        BoxBody(name="crate", size=(0.3, 0.3, 0.4), position=(0.55, -0.2, 0.8))])
    scan = render_scan(room, eye=(1.4, -1.3, 1.5), target=(0.0, 0.2, 0.6), size=(96, 72), seed=3)
    write_pcd(scan, folder / "scans" / "room.pcd")
    points = {"type": "points", "name": "room", "file": "scans/room.pcd", "position": list(scan.position),
              "rpy": list(scan.rpy), "voxel": 0.03}
    path = folder / "scene.json"
    path.write_text(json.dumps({"name": "scanned-bench", "robot": {"position": [0, 0, 0.6]},
                                "bodies": [TABLE, RING, points, CHEST]}))
    return path


@pytest.fixture(scope="module")
def robot_td(lights, scene_file) -> dict:
    lights.spawn("robot", "ur10.urdf", "--scene", str(scene_file), "--name", NAME, "--samples", "1500",
                 "--collision-model", "exact", "--speed", "max", log=lights.tmp / f"{NAME}.log")

    def generated() -> dict | None:
        r = httpx.get(f"{lights.http}/{NAME}", timeout=10)
        if r.status_code != 200:
            return None
        td = r.json()
        return td if any(link.get("rel") == WORKSPACE for link in td.get("links", [])) else None

    try:
        return eventually(generated, timeout=300, what=f"{NAME}'s generated TD")
    except AssertionError:
        print((lights.tmp / f"{NAME}.log").read_text()[-3000:])
        raise


def _links(td: dict, rel: str) -> list[dict]:
    return [link for link in td["links"] if link.get("rel") == rel]


def _download(td: dict, folder: Path) -> Path:
    """scene.json and every scene-asset link of `td`, fetched over HTTP into `folder`."""
    with httpx.Client(timeout=60) as http:
        (folder / "scene.json").write_bytes(http.get(_links(td, SCENE)[0]["href"]).raise_for_status().content)
        for link in _links(td, SCENE_ASSET):
            (folder / link["href"].rsplit("/", 1)[-1]).write_bytes(http.get(link["href"]).raise_for_status().content)
    return folder / "scene.json"


@pytest.fixture(scope="module")
def downloaded(robot_td, tmp_path_factory) -> Path:
    """scene.json and every scene-asset link of the TD, fetched through the adapter into an empty folder."""
    return _download(robot_td, tmp_path_factory.mktemp("downloaded"))


def test_the_td_links_each_file_the_scene_names_under_the_href_the_scene_gives_it(robot_td):
    scene_url = _links(robot_td, SCENE)[0]["href"]
    served = httpx.get(scene_url, timeout=30).json()
    files = {b["name"]: b["file"] for b in served["bodies"] if "file" in b}
    assets = {link["href"]: link["type"] for link in _links(robot_td, SCENE_ASSET)}
    assert set(files) == {"ring", "room", "chest"}
    assert {urljoin(scene_url, f) for f in files.values()} == set(assets)  # relative to scene.json, as linked
    assert assets[urljoin(scene_url, files["ring"])] == "model/stl"
    assert assets[urljoin(scene_url, files["room"])] == "application/octet-stream"  # PCD: no registered type
    assert assets[urljoin(scene_url, files["chest"])] == "model/gltf-binary"  # the .gltf, whole, as a GLB


def test_the_files_come_as_they_are_with_their_media_type(robot_td, scene_file):
    originals = {"ring": scene_file.parent / RING["file"], "room": scene_file.parent / "scans" / "room.pcd"}
    served = httpx.get(_links(robot_td, SCENE)[0]["href"], timeout=30).json()
    for body in served["bodies"]:
        if body.get("name") == "chest":
            r = httpx.get(urljoin(_links(robot_td, SCENE)[0]["href"], body["file"]), timeout=30)
            assert r.content[:4] == b"glTF" and r.headers["content-type"] == "model/gltf-binary"
        elif "file" in body:
            r = httpx.get(urljoin(_links(robot_td, SCENE)[0]["href"], body["file"]), timeout=30)
            assert r.status_code == 200
            assert hashlib.sha256(r.content).digest() == hashlib.sha256(originals[body["name"]].read_bytes()).digest()
            assert r.headers["content-type"] == ("model/stl" if body["type"] == "mesh" else "application/octet-stream")


def test_twin_json_keeps_the_paths_here_and_names_what_each_is_served_as(robot_td, scene_file):
    twin = httpx.get(_links(robot_td, TWIN)[0]["href"], timeout=30).json()
    ring = str((scene_file.parent / RING["file"]).resolve())
    assert next(b["file"] for b in twin["scene"]["bodies"] if b["name"] == "ring") == ring
    served = {link["href"].rsplit("/", 1)[-1] for link in _links(robot_td, SCENE_ASSET)}
    assert set(twin["scene_files"].values()) == served and ring in twin["scene_files"]


def test_the_downloaded_scene_rebuilds_the_same_bodies(downloaded, scene_file):
    here, there = load_scene(scene_file), load_scene(downloaded)
    assert [(b.name, type(b).__name__) for b in there.bodies] == [(b.name, type(b).__name__) for b in here.bodies]
    assert there.robot == here.robot
    for mine, theirs in zip(here.bodies, there.bodies):
        if hasattr(mine, "file"):
            made, remade = prepare(mine), prepare(theirs)
            assert (made.kind, made.stats) == (remade.kind, remade.stats)
            assert np.allclose(made.low, remade.low) and np.allclose(made.high, remade.high)


def test_the_downloaded_scene_gives_the_robots_own_verdicts(robot_td, downloaded, scene_file):
    """Configurations of the robot's points.csv (flagged by the exact test in the scene on the robot's host):
    the rebuilt scene calls them as the original does, and as the points file says."""
    ur10 = Robot.load("ur10.urdf")
    rows = np.loadtxt(httpx.get(_links(robot_td, POINTS)[0]["href"], timeout=60).text.splitlines()[1:],
                      delimiter=",")[:300]
    qs, flags = np.radians(rows[:, 4:]), rows[:, 3] != 0
    original, rebuilt = CollisionWorld(ur10, load_scene(scene_file)), CollisionWorld(ur10, load_scene(downloaded))
    try:
        here, there = original.colliding(qs), rebuilt.colliding(qs)
        hits = {pair.rsplit("/ ", 1)[-1] for q in qs[there] for pair in rebuilt.what_collides(q)}
    finally:
        original.close()
        rebuilt.close()
    assert (here == there).all()
    assert {"ring", "room", "chest"} <= hits  # the meshes and the scan decide some of them
    assert (there == flags).mean() >= 0.99  # the file's joints are rounded to 0.001 deg: a grazing contact may flip


# --- the world Thing ------------------------------------------------------------------------------
class ScannedRoom:
    """A `SimulatedScene` whose description holds the scene file's table, ring and scan, and the UR10."""

    name = "scanned-room"
    cube_count = 0

    def __init__(self, world, scene_file: Path):
        self.world, self.scene_file = world, scene_file

    def robot_urdfs(self) -> dict[str, Path]:
        return {"ur10": Robot.load("ur10.urdf").urdf_path}

    def describe(self):
        from scipy.spatial.transform import Rotation

        from mesh.messages.scene_description import Body, Pose, RobotModel, SceneDescription

        def pose(body: dict):
            q = Rotation.from_euler("xyz", body.get("rpy", [0, 0, 0]), degrees=True).as_quat()
            return Pose(tuple(body["position"]), tuple(float(v) for v in q))

        bodies = json.loads(self.scene_file.read_text())["bodies"]
        table, ring, room, chest = bodies
        folder = self.scene_file.parent
        return SceneDescription(self.name, robots=[RobotModel("ur10", "ur10.urdf", Pose((0.0, 0.0, 0.6)))], bodies=[
            Body("table", "box", tuple(table["size"]), pose(table)),
            Body("ring", "mesh", (0.6, 0.6, 0.1), pose(ring), file=str(folder / ring["file"])),
            Body("room", "points", (2.0, 2.0, 2.0), pose(room), file=str(folder / room["file"]), voxel=room["voxel"]),
            Body("chest", "mesh", (0.4, 0.3, 0.4), pose(chest), file=str(folder / chest["file"]))])

    def reset(self, cubes: int | None = None) -> None:
        pass


@pytest.fixture(scope="module")
def world_td(lights, scene_file):
    """The world Thing of `ScannedRoom` on the lab's mesh, its TD as the adapter serves it."""
    from devices.sim.pybullet_world import World
    from devices.things.world_thing import WorldThing
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    world = World(speed=1.0).start()
    try:
        with open_session(MeshSettings(connect=(lights.endpoint,))) as session, \
                WorldThing(session, ScannedRoom(world, scene_file)):
            yield eventually(lambda: (r := httpx.get(f"{lights.http}/world", timeout=10)).status_code == 200
                             and r.json(), timeout=120, what="the world's TD through the adapter")
    finally:
        world.close()


def test_the_worlds_scene_json_names_its_files_as_its_td_links_them(world_td):
    scene_url = _links(world_td, SCENE)[0]["href"]
    served = httpx.get(scene_url, timeout=30).json()
    files = {b["name"]: b["file"] for b in served["bodies"] if "file" in b}
    assert set(files) == {"ring", "room", "chest"}
    types = {"ring": "model/stl", "room": "application/octet-stream", "chest": "model/gltf-binary"}
    assert {urljoin(scene_url, f): types[name] for name, f in files.items()} \
        == {link["href"]: link["type"] for link in _links(world_td, SCENE_ASSET)}


def test_the_worlds_downloaded_scene_gives_the_same_verdicts(world_td, scene_file, tmp_path):
    """The world's scene.json read as a tdgen scene for its UR10: the same bodies from the same files."""
    rebuilt = load_scene(_download(world_td, tmp_path), "ur10")
    assert [(b.name, type(b).__name__) for b in rebuilt.bodies] == [(b.name, type(b).__name__)
                                                                   for b in load_scene(scene_file).bodies]
    ur10 = Robot.load("ur10.urdf")
    qs = np.random.default_rng(11).uniform(ur10.lows(), ur10.highs(), (200, len(ur10.lows())))
    original, there = CollisionWorld(ur10, load_scene(scene_file)), CollisionWorld(ur10, rebuilt)
    try:
        assert (original.colliding(qs) == there.colliding(qs)).all()
    finally:
        original.close()
        there.close()


# --- the recording --------------------------------------------------------------------------------
@pytest.fixture(scope="module")
def recording(lights, robot_td, world_td, tmp_path_factory) -> Path:
    """`twinmesh record` started once the robot serves its generated TD and the world is up, stopped with Ctrl-C
    once it has fetched every Thing alive (its ready line)."""
    folder = tmp_path_factory.mktemp("recording")
    path, log = folder / "scan.rrd", folder / "recorder.log"
    recorder = lights.spawn("record", str(path), log=log)
    wait_for_line(log, "recording to", recorder, timeout=120)
    assert stop_process(recorder) and recorder.returncode == 0, log.read_text()
    return path


@pytest.mark.parametrize("entity", [f"/robots/{NAME}/scene/room", "/world/bodies/room"], ids=["robot", "world"])
def test_the_recording_draws_the_scan_as_its_points_where_the_sensor_saw_them(recording, scene_file, entity):
    from scipy.spatial.transform import Rotation

    body = next(b for b in json.loads(scene_file.read_text())["bodies"] if b["name"] == "room")
    drawn = placed(recording, entity, latest_static(recording, entity, "Points3D:positions"))
    truth = Rotation.from_euler("xyz", body["rpy"], degrees=True).apply(
        read_cloud(scene_file.parent / body["file"])) + body["position"]
    assert drawn.shape == truth.shape and np.allclose(drawn, truth, atol=1e-4)  # fewer than 100,000: every point


@pytest.mark.parametrize("where", [f"/robots/{NAME}/scene", "/world/bodies"], ids=["robot", "world"])
@pytest.mark.parametrize("body", [RING, CHEST], ids=["ring", "chest"])
def test_the_recording_draws_each_mesh_as_its_triangles_where_the_scene_puts_it(recording, scene_file, body, where):
    from scipy.spatial.transform import Rotation

    entity = f"{where}/{body['name']}"
    mesh = trimesh.load(scene_file.parent / body["file"], force="mesh")
    vertices = np.array(latest_static(recording, entity, "Mesh3D:vertex_positions"))
    assert len(latest_static(recording, entity, "Mesh3D:triangle_indices")) == len(mesh.faces)
    drawn = placed(recording, entity, vertices)
    truth = Rotation.from_euler("xyz", body["rpy"], degrees=True).apply(mesh.vertices) + body["position"]
    assert np.allclose(drawn.min(axis=0), truth.min(axis=0), atol=1e-5)
    assert np.allclose(drawn.max(axis=0), truth.max(axis=0), atol=1e-5)
