"""A robot on another host whose scene holds a scan: the tdgen service cannot read the scan by the robot's path,
fetches it from the robot Thing (`files/<name>`, `TwinDescription.scene_files`) and generates as if the file
were here: the same points.csv as from the file read by path, other flags than the scene without the scan,
and a scene.json naming the robot's path (which the robot serves under its own name). A file the robot cannot
serve fails that robot alone, the status naming the file and why.

On a mesh: a Zenoh router on loopback, the service and the robots' file servers on sessions of their own, the
robots `ExposedThing`s serving the files a robot Thing would (what the service asks of a robot is its files),
their twins handed to the service as its discovery would. In a lab: `twinmesh robot` in a mount namespace of
its own (another host's files: its scene's folder is empty on the lab's side) joins the shared lights lab.
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
from contextlib import ExitStack
from pathlib import Path

import httpx
import msgspec
import numpy as np
import pytest
from labs import REPO, free_port, stop_process
from scans import render_scan, write_gltf, write_pcd
from waiting import eventually

from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.server import ExposedThing
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from mesh.messages.relations import POINTS, WORKSPACE
from mesh.messages.scene_description import Pose, TwinDescription
from mesh.wot.problem import NotFound, Unavailable
from mesh.wot.thing_description import decode_td, thing_id
from tdgen.remote_scene_files import fetched_twin, robot_paths
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.errors import SceneError
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import BoxBody, Surroundings, load_scene
from tdgen.service import TdgenService

ELSEWHERE = "/robot-host/lab/scans/room.pcd"  # the scan's path on the robot's host: nothing there on this one
SERVED = "scene-room.pcd"
TABLE = {"type": "box", "name": "table", "size": [0.6, 0.6, 0.6], "position": [0.0, 0.0, 0.3]}


@pytest.fixture(scope="module")
def scan_file(tmp_path_factory) -> tuple[Path, dict]:
    """A scan of a wall and a crate beside the robot (PCD), and its points body (without `file`)."""
    room = Surroundings(name="room", bodies=[
        BoxBody(name="wall", size=(2.0, 0.1, 1.6), position=(0.0, 0.6, 0.8)),
        BoxBody(name="crate", size=(0.3, 0.3, 0.4), position=(0.55, -0.2, 0.8))])
    scan = render_scan(room, eye=(1.4, -1.3, 1.5), target=(0.0, 0.2, 0.6), size=(96, 72), seed=3)
    path = write_pcd(scan, tmp_path_factory.mktemp("robot-host") / "room.pcd")
    return path, {"type": "points", "name": "room", "position": list(scan.position), "rpy": list(scan.rpy),
                  "voxel": 0.03}


def _twin(robot: str, bodies: list[dict], files: dict[str, str] | None = None) -> TwinDescription:
    ur10 = Robot.load("ur10.urdf").urdf_path
    return TwinDescription(robot=robot, urdf="ur10.urdf", urdf_sha256=hashlib.sha256(ur10.read_bytes()).hexdigest(),
                           base=Pose((0.0, 0.0, 0.6)), scene={"bodies": bodies}, scene_files=files or {},
                           samples=1500)


# --- the copies (no mesh) --------------------------------------------------------------------------
def test_a_file_not_here_is_fetched_once_per_content_and_named_by_it(scan_file, tmp_path):
    path, body = scan_file
    asked: list[str] = []
    twin = _twin("farbot", [TABLE, {**body, "file": ELSEWHERE}, {**body, "name": "again", "file": ELSEWHERE}],
                 {ELSEWHERE: SERVED})
    fetched, paths = fetched_twin(twin, tmp_path, lambda name: asked.append(name) or path.read_bytes())
    copy = tmp_path / f"{hashlib.sha256(path.read_bytes()).hexdigest()}.pcd"
    assert asked == [SERVED] and copy.read_bytes() == path.read_bytes()
    assert [b.get("file") for b in fetched.scene["bodies"]] == [None, str(copy), str(copy)]
    assert paths == {str(copy): ELSEWHERE}
    assert fetched_twin(_twin("nearbot", [{**body, "file": str(path)}]), tmp_path, asked.append)[1] == {}
    assert asked == [SERVED]  # a file here is read by its path: nothing fetched


def test_the_scene_json_made_from_the_copy_names_the_robots_path(tmp_path):
    scene = b'{"name": "s", "robot": {}, "bodies": [{"type": "points", "name": "room", "file": "/cache/ab.pcd"}]}'
    assert msgspec.json.decode(robot_paths(scene, {"/cache/ab.pcd": ELSEWHERE}))["bodies"][0]["file"] == ELSEWHERE


@pytest.mark.parametrize(("served", "fetch", "why"), [
    ({}, None, "serves no file for it"),
    ({ELSEWHERE: SERVED}, NotFound(f"{SERVED}: the scene's file cannot be read (No such file or directory)"),
     "No such file or directory"),
    ({ELSEWHERE: SERVED}, b"", "the file is empty")], ids=["unnamed", "unreadable", "empty"])
def test_a_file_the_robot_cannot_serve_is_a_scene_error_naming_it_and_why(served, fetch, why, tmp_path):
    def ask(name: str) -> bytes:
        if isinstance(fetch, Exception):
            raise fetch
        return fetch or b""

    with pytest.raises(SceneError, match=why) as err:
        fetched_twin(_twin("farbot", [{"type": "points", "name": "room", "file": ELSEWHERE}], served), tmp_path, ask)
    assert ELSEWHERE in str(err.value)


# --- through the service, on a mesh ----------------------------------------------------------------
@pytest.fixture
def mesh():
    settings = MeshSettings(connect=(f"tcp/127.0.0.1:{free_port()}",))
    with open_session(settings.as_router()):
        yield settings


def _robot_host(stack: ExitStack, mesh: MeshSettings, name: str, files: dict[str, Path]) -> None:
    """A Thing serving `files` (name -> path) as a robot Thing serves its scene's files."""
    def lookup(file: str) -> tuple[bytes, str]:
        if file not in files:
            raise NotFound(f"{name} has no file {file!r}")
        try:
            return files[file].read_bytes(), "application/octet-stream"
        except OSError as e:
            raise NotFound(f"{file}: the scene's file {files[file]} cannot be read ({e.strerror})") from None

    td = decode_td({"title": name, "id": thing_id(name), "properties": {}})
    thing = ExposedThing(stack.enter_context(open_session(mesh)), td, name, mesh.keys).on_any_file(lookup)
    thing.expose()
    stack.callback(thing.destroy)


def _flags(client: MeshClient, robot: str) -> list[str]:
    """The collision flag of each row of the robot's points.csv as the service serves it."""
    rows = client.file("tdgen", f"{robot}.points.csv").payload.decode().splitlines()[1:]
    return [row.split(",")[3] for row in rows]


def test_a_robot_elsewhere_gets_the_flags_of_its_scan_and_a_file_it_cannot_serve_fails_it_alone(mesh, scan_file,
                                                                                              tmp_path):
    path, body = scan_file
    with ExitStack() as stack:
        service = stack.enter_context(TdgenService(stack.enter_context(open_session(mesh)), mesh, tmp_path / "c", 1))
        _robot_host(stack, mesh, "farbot", {SERVED: path})
        _robot_host(stack, mesh, "lostbot", {SERVED: tmp_path / "gone.pcd"})
        client = MeshClient(stack.enter_context(open_session(mesh)), mesh)

        far = service.generate(_twin("farbot", [TABLE, {**body, "file": ELSEWHERE}], {ELSEWHERE: SERVED}))
        assert far.status == "ready", far.error
        remote = _flags(client, "farbot")
        scene = msgspec.json.decode(client.file("tdgen", "farbot.scene.json").payload)
        assert [b.get("file") for b in scene["bodies"]] == [None, ELSEWHERE]  # the robot maps it to its name

        assert service.generate(_twin("nearbot", [TABLE, {**body, "file": str(path)}])).status == "ready"
        assert service.generate(_twin("barebot", [TABLE])).status == "ready"
        assert remote == _flags(client, "nearbot")  # as if the scan were here
        changed = sum(a != b for a, b in zip(remote, _flags(client, "barebot")))
        assert changed >= 10, "the scan decides no sample"

        lost = service.generate(_twin("lostbot", [TABLE, {**body, "file": ELSEWHERE}], {ELSEWHERE: SERVED}))
        robots = service.robots()
        assert lost.status == "failed" and robots["lostbot"]["status"] == "failed"
        assert ELSEWHERE in robots["lostbot"]["error"] and "gone.pcd" in robots["lostbot"]["error"]
        assert robots["farbot"]["status"] == "ready" and _flags(client, "farbot") == remote
        with pytest.raises((NotFound, Unavailable)):
            client.file("tdgen", "lostbot.points.csv")


# --- a robot process on "another host", in a lab ---------------------------------------------------
def _private_mounts() -> list[str] | str:
    """The command prefix that runs a command in a mount namespace of its own, or why there is none."""
    prefix = ["unshare", "--mount", "--propagation", "private", *([] if os.geteuid() == 0 else ["--map-root-user"])]
    if shutil.which("unshare") is None:
        return "needs unshare (util-linux)"
    probe = subprocess.run([*prefix, "true"], capture_output=True, text=True)
    return prefix if probe.returncode == 0 else f"cannot make a mount namespace ({probe.stderr.strip()})"


@pytest.mark.lab
def test_a_robot_process_whose_scan_and_gltf_the_lab_cannot_see_gets_their_flags(lights, scan_file, tmp_path):
    """The scan comes as the robot's file, the chest's .gltf (its geometry in .bin files beside it) as the GLB the
    robot packs of it."""
    prefix = _private_mounts()
    if isinstance(prefix, str):
        pytest.skip(prefix)
    path, body = scan_file
    robot_host, elsewhere = tmp_path / "robot-host", tmp_path / "elsewhere"  # elsewhere: empty but in the robot's
    robot_host.mkdir()
    elsewhere.mkdir()
    shutil.copy(path, robot_host / "room.pcd")
    (robot_host / "cad").mkdir()
    write_gltf(robot_host / "cad", name="chest", size=(0.4, 0.3, 0.4))
    chest = {"type": "mesh", "name": "chest", "file": "cad/chest.gltf", "position": [-0.55, -0.4, 0.8], "rpy": [0, 0, 20]}
    scene = {"name": "scanned", "robot": {"position": [0, 0, 0.6]},
             "bodies": [TABLE, {**body, "file": "room.pcd"}, chest]}
    (robot_host / "scene.json").write_text(json.dumps(scene))
    (tmp_path / "bare.json").write_text(json.dumps({**scene, "bodies": [TABLE]}))
    (robot_host / "unchested.json").write_text(json.dumps({**scene, "bodies": scene["bodies"][:2]}))
    log = tmp_path / "farbot.log"
    robot = subprocess.Popen(
        [*prefix, "sh", "-c", 'mount --bind "$0" "$1" && shift && exec "$@"', str(robot_host), str(elsewhere),
         *lights.cli_args("robot", "ur10.urdf", "--scene", str(elsewhere / "scene.json"), "--name", "farbot",
                          "--samples", "1500", "--collision-model", "exact", "--speed", "max")],
        stdout=open(log, "wb"), stderr=subprocess.STDOUT, cwd=REPO, start_new_session=True)
    try:
        def generated() -> dict | None:
            r = httpx.get(f"{lights.http}/farbot", timeout=10)
            td = r.json() if r.status_code == 200 else {}
            return td if any(link.get("rel") == WORKSPACE for link in td.get("links", [])) else None

        try:
            td = eventually(generated, timeout=300, what="farbot's generated TD")
        except AssertionError:
            print(log.read_text()[-3000:])
            raise
        assert not any(elsewhere.iterdir()), "the robot's files are visible on the lab's side"
        href = next(link["href"] for link in td["links"] if link.get("rel") == POINTS)
        rows = np.loadtxt(httpx.get(href, timeout=60).text.splitlines()[1:], delimiter=",")[:400]
    finally:
        assert stop_process(robot)
    qs, flags = np.radians(rows[:, 4:]), rows[:, 3] != 0
    ur10 = Robot.load("ur10.urdf")
    worlds = [CollisionWorld(ur10, load_scene(robot_host / "scene.json")),
              CollisionWorld(ur10, load_scene(tmp_path / "bare.json")),
              CollisionWorld(ur10, load_scene(robot_host / "unchested.json"))]
    try:
        whole, without, unchested = (world.colliding(qs) for world in worlds)
    finally:
        for world in worlds:
            world.close()
    assert (flags == whole).mean() >= 0.99  # the file's joints are rounded to 0.001 deg: a grazing contact may flip
    assert (flags & ~without).sum() >= 5, "no flag comes from the scan"
    assert (flags & ~unchested).sum() >= 3, "no flag comes from the chest"


def test_a_robot_elsewhere_whose_gltf_names_separate_files_gets_the_td_of_a_local_one(mesh, tmp_path):
    """The robot serves its .gltf (geometry in .bin files, a texture) as the GLB of it; the service fetches that
    and makes the TD, points.csv and hull it makes from the .gltf read where it lies."""
    from devices.things.scene_files import SceneAssets

    robot_host = tmp_path / "robot-host"
    robot_host.mkdir()
    gltf = write_gltf(robot_host, size=(0.5, 0.4, 0.5))
    body = {"type": "mesh", "name": "chest", "position": [0.6, -0.3, 0.85], "rpy": [0, 0, 25]}
    (asset,) = SceneAssets().add([{**body, "file": str(gltf)}])
    elsewhere = "/robot-host/cad/crate.gltf"
    with ExitStack() as stack:
        service = stack.enter_context(TdgenService(stack.enter_context(open_session(mesh)), mesh, tmp_path / "c", 1))
        served = tmp_path / asset.name
        served.write_bytes(asset.read())
        _robot_host(stack, mesh, "chestbot", {asset.name: served})
        client = MeshClient(stack.enter_context(open_session(mesh)), mesh)

        def artefacts(twin: TwinDescription) -> dict[str, bytes]:
            status = service.generate(twin)
            assert status.status == "ready", status.error
            return {suffix: bytes(client.file("tdgen", f"chestbot.{suffix}").payload)
                    for suffix in ("td.json", "points.csv", "workspace.stl", "scene.json")}

        remote = artefacts(_twin("chestbot", [TABLE, {**body, "file": elsewhere}], {elsewhere: asset.name}))
        local = artefacts(_twin("chestbot", [TABLE, {**body, "file": str(gltf)}]))
        bare = artefacts(_twin("chestbot", [TABLE]))
    copies = list((tmp_path / "c" / "scene-files").iterdir())
    assert [copy.suffix for copy in copies] == [".glb"]
    assert remote["points.csv"] == local["points.csv"] != bare["points.csv"]
    assert remote["workspace.stl"] == local["workspace.stl"]
    assert remote["td.json"] == local["td.json"]
    assert msgspec.json.decode(remote["scene.json"])["bodies"][1]["file"] == elsewhere  # the robot's name for it
