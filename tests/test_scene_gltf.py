"""A glTF model kept in several files (`crate.gltf` naming `crate.bin` and a texture): whole wherever its scene
counts. A Thing serves it as one GLB of the same geometry, which rebuilds the same body in an empty folder; a
missing or outside file is one line naming the .gltf and the file; its content is that of all its files (a
.bin written again is a new mesh); the tdgen service fetches it from a robot as that GLB, and keeps its
fetched copies bounded however many different files stream through.

A glTF made by trimesh with its buffers in separate files, a PNG texture added by hand (trimesh exports
textures inside the buffers).
"""
from __future__ import annotations

import hashlib
import json
import struct
from pathlib import Path

import numpy as np
import pytest
import trimesh
from click.testing import CliRunner
from scans import write_gltf

from devices.cli.main import main
from devices.things.scene_files import SceneAssets
from mesh.messages.scene_description import Pose, TwinDescription
from mesh.wot.problem import NotFound, Refused
from tdgen import remote_scene_files
from tdgen.remote_scene_files import fetched_twin, prune
from tdgen.robot.scan_io import content_digest, read_mesh
from tdgen.robot.surroundings import load_scene, prepare

SIZE = (0.4, 0.3, 0.2)


@pytest.fixture(autouse=True)
def scan_cache(tmp_path, monkeypatch):
    monkeypatch.setenv("TWINMESH_CACHE", str(tmp_path / "cache"))


def glb_parts(glb: bytes) -> tuple[dict, bytes]:
    """The JSON and the binary chunk of a GLB."""
    magic, version, length = struct.unpack_from("<III", glb)
    assert (magic, version, length) == (0x46546C67, 2, len(glb))
    size, _ = struct.unpack_from("<II", glb, 12)
    gltf = json.loads(glb[20:20 + size])
    binary = glb[20 + size + 8:]
    return gltf, binary


def _scene(folder: Path, file: str) -> Path:
    body = {"type": "mesh", "name": "crate", "file": file, "position": [1.0, 0.0, 0.5], "rpy": [0, 0, 30]}
    path = folder / "scene.json"
    path.write_text(json.dumps({"name": "crated", "bodies": [body]}))
    return path


def test_a_thing_serves_a_gltf_with_separate_files_as_one_glb_that_rebuilds_the_same_body(tmp_path):
    here, there = tmp_path / "here", tmp_path / "there"
    here.mkdir()
    there.mkdir()
    gltf = write_gltf(here)
    assets = SceneAssets(taken=["scene.json"])
    bodies = json.loads(_scene(here, str(gltf)).read_text())["bodies"]
    (asset,) = assets.add(bodies)
    assert (asset.name, asset.media_type) == ("scene-crate.glb", "model/gltf-binary")
    assert [(link.href, link.type) for link in assets.links(bodies)] == [("files/scene-crate.glb", "model/gltf-binary")]
    served = assets.relative({"name": "crated", "bodies": bodies})
    assert served["bodies"][0]["file"] == "scene-crate.glb"

    (there / "scene.json").write_text(json.dumps(served))  # a consumer's empty folder: scene.json and the link
    (there / asset.name).write_bytes(asset.read())
    original, rebuilt = load_scene(here / "scene.json"), load_scene(there / "scene.json")
    made, remade = prepare(original.bodies[0]), prepare(rebuilt.bodies[0])
    assert (made.kind, made.stats) == (remade.kind, remade.stats)
    assert np.allclose(made.low, remade.low) and np.allclose(made.high, remade.high)
    ours, theirs = read_mesh(gltf), read_mesh(there / asset.name)
    assert np.array_equal(ours.vertices, theirs.vertices) and np.array_equal(ours.faces, theirs.faces)

    packed, binary = glb_parts(asset.read())
    (image,) = packed["images"]
    view = packed["bufferViews"][image["bufferView"]]
    texture = binary[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
    assert image["mimeType"] == "image/png" and texture == (here / "textures" / "wood grain.png").read_bytes()
    assert "uri" not in json.dumps(packed)  # nothing left to fetch


def test_a_gltf_of_data_uris_is_served_as_a_glb_of_the_same_mesh(tmp_path):
    path = tmp_path / "inline.gltf"
    files = trimesh.exchange.gltf.export_gltf(trimesh.Scene(trimesh.creation.icosphere(2, 0.2)), embed_buffers=True)
    assert set(files) == {"model.gltf"}  # every buffer a data: URI
    path.write_bytes(files["model.gltf"])
    (asset,) = SceneAssets().add([{"type": "mesh", "name": "ball", "file": str(path)}])
    (tmp_path / asset.name).write_bytes(asset.read())
    assert np.array_equal(read_mesh(path).vertices, read_mesh(tmp_path / asset.name).vertices)


@pytest.mark.parametrize("spoil, said", [
    (lambda folder: (folder / "crate_0.bin").unlink(), "names 'crate_0.bin', which is not there"),
    (lambda folder: (folder / "textures" / "wood grain.png").unlink(), "which is not there"),
    (lambda folder: _rename(folder / "crate.gltf", "crate_1.bin", "../secret.bin"), "outside its folder"),
    (lambda folder: _rename(folder / "crate.gltf", "crate_1.bin", "https://example.org/crate.bin"),
     "not a file beside it"),
], ids=["buffer-missing", "texture-missing", "outside", "url"])
def test_a_gltf_naming_a_file_it_cannot_have_is_one_line_naming_both_and_exit_2(tmp_path, spoil, said):
    write_gltf(tmp_path)
    (tmp_path.parent / "secret.bin").write_bytes(b"\1" * 256)
    spoil(tmp_path)
    shown = CliRunner().invoke(main, ["scene", "show", str(_scene(tmp_path, "crate.gltf"))])
    assert shown.exit_code == 2
    lines = shown.output.strip().splitlines()
    assert len(lines) == 1 and "crate.gltf" in lines[0] and said in lines[0], shown.output


@pytest.mark.parametrize("files_beside", [True, False], ids=["its-files-beside-it", "its-files-missing"])
def test_a_glb_naming_files_outside_itself_is_one_line_and_exit_2(tmp_path, files_beside):
    """A GLB is served as it is: one naming files would reach a consumer on another host without them."""
    gltf = json.loads(write_gltf(tmp_path).read_text())
    if not files_beside:
        for file in tmp_path.glob("crate_*.bin"):
            file.unlink()
    chunk = json.dumps(gltf).encode()
    chunk += b" " * (-len(chunk) % 4)
    (tmp_path / "crate.glb").write_bytes(struct.pack("<III", 0x46546C67, 2, 20 + len(chunk))
                                         + struct.pack("<II", len(chunk), 0x4E4F534A) + chunk)
    shown = CliRunner().invoke(main, ["scene", "show", str(_scene(tmp_path, "crate.glb"))])
    assert shown.exit_code == 2
    lines = shown.output.strip().splitlines()
    assert len(lines) == 1 and "crate.glb" in lines[0] and "names 'crate_0.bin' outside itself" in lines[0], \
        shown.output


def _rename(gltf: Path, uri: str, to: str) -> None:
    gltf.write_text(gltf.read_text().replace(f'"{uri}"', f'"{to}"'))


def test_a_served_gltf_whose_file_went_is_not_found_naming_both_and_never_carries_a_file_from_elsewhere(tmp_path):
    gltf = write_gltf(tmp_path)
    (asset,) = SceneAssets().add([{"type": "mesh", "name": "crate", "file": str(gltf)}])
    (tmp_path / "crate_1.bin").unlink()
    with pytest.raises(NotFound, match=r"scene-crate.glb: .*crate.gltf: names 'crate_1.bin', which is not there"):
        asset.read()
    (tmp_path.parent / "secret.bin").write_bytes(b"secret" * 40)
    _rename(gltf, "crate_1.bin", "../secret.bin")
    with pytest.raises(NotFound, match="outside its folder"):
        asset.read()


def test_a_gltf_is_known_by_the_content_of_every_file_it_names(tmp_path):
    gltf = write_gltf(tmp_path)
    before = content_digest(gltf)
    assert before != hashlib.sha256(gltf.read_bytes()).hexdigest()
    write_gltf(tmp_path / "textures", size=(0.5, 0.3, 0.2))  # the same files' names, another box
    for other in (tmp_path / "textures").glob("*.bin"):  # the .bin files written again, the .gltf untouched
        (tmp_path / other.name).write_bytes(other.read_bytes())
    after = content_digest(gltf)
    assert after != before and content_digest(gltf) == after
    assert not np.allclose(read_mesh(gltf).extents, SIZE)  # and is read anew


def test_the_worlds_scans_folder_takes_a_gltf_with_its_files_and_never_one_naming_a_file_outside(tmp_path):
    """`addObstacle` serves what it takes: a .gltf in the scans folder may not carry a file from beside it."""
    from devices.sim.layouts.obstacles import from_input

    scans = tmp_path / "scans"
    scans.mkdir()
    write_gltf(scans)
    (tmp_path / "secret.bin").write_bytes(b"secret" * 40)
    obstacle = {"name": "crate", "type": "mesh", "file": "crate.gltf", "position": [1.0, 0.0, 0.5]}
    assert from_input(obstacle, scans).file == str((scans / "crate.gltf").resolve())
    _rename(scans / "crate.gltf", "crate_1.bin", "../secret.bin")
    with pytest.raises(Refused, match="names '../secret.bin', outside its folder") as refused:
        from_input(obstacle, scans)
    assert refused.value.reason == "unusable-file"


# --- fetched by the tdgen service -------------------------------------------------------------------
ELSEWHERE = "/robot-host/cad/crate.gltf"


def _twin(bodies: list[dict], files: dict[str, str]) -> TwinDescription:
    return TwinDescription(robot="farbot", urdf="ur10.urdf", urdf_sha256="0" * 64, base=Pose((0.0, 0.0, 0.6)),
                           scene={"bodies": bodies}, scene_files=files)


def test_the_service_fetches_a_gltf_as_the_glb_the_robot_serves_and_rebuilds_the_same_body(tmp_path):
    robot_host = tmp_path / "robot-host"
    robot_host.mkdir()
    gltf = write_gltf(robot_host)
    (asset,) = SceneAssets().add([{"type": "mesh", "name": "crate", "file": str(gltf)}])
    body = {"type": "mesh", "name": "crate", "file": ELSEWHERE, "position": [1.0, 0.0, 0.5]}
    fetched, paths = fetched_twin(_twin([body], {ELSEWHERE: asset.name}), tmp_path / "copies",
                                  lambda name: asset.read())
    copy = Path(fetched.scene["bodies"][0]["file"])
    assert copy.suffix == ".glb" and paths == {str(copy): ELSEWHERE}
    local = prepare(load_scene(_scene(robot_host, "crate.gltf")).bodies[0])
    remote = prepare(load_scene(_scene(tmp_path, str(copy))).bodies[0])
    assert np.allclose(local.low, remote.low) and np.allclose(local.high, remote.high)


def test_a_gltf_here_without_its_files_is_fetched_whole(tmp_path):
    gltf = write_gltf(tmp_path)
    glb = SceneAssets().add([{"type": "mesh", "name": "crate", "file": str(gltf)}])[0].read()
    (tmp_path / "crate_0.bin").unlink()  # the .gltf in a shared folder, its .bin not
    asked: list[str] = []
    fetched, _ = fetched_twin(_twin([{"type": "mesh", "name": "crate", "file": str(gltf)}], {str(gltf): "scene-crate.glb"}),
                              tmp_path / "copies", lambda name: asked.append(name) or glb)
    assert asked == ["scene-crate.glb"] and fetched.scene["bodies"][0]["file"].endswith(".glb")


def test_a_stream_of_new_clouds_keeps_the_copies_bounded_and_the_current_one_works(tmp_path):
    folder, rng = tmp_path / "copies", np.random.default_rng(4)
    body = {"type": "points", "name": "latest", "file": "/robot-host/scans/latest.xyz", "voxel": 0.05}
    twin = _twin([body], {body["file"]: "scene-latest.xyz"})
    clouds = ["\n".join(" ".join(f"{v:.4f}" for v in p) for p in rng.uniform(-1, 1, (200, 3))).encode()
              for _ in range(remote_scene_files.KEPT_COPIES + 20)]
    copies = []
    for cloud in clouds:  # a depth camera's cloud, replaced again and again
        fetched, _ = fetched_twin(twin, folder, lambda name, cloud=cloud: cloud)
        copies.append(Path(fetched.scene["bodies"][0]["file"]))
        assert len(list(folder.iterdir())) <= remote_scene_files.KEPT_COPIES + 1  # and the twin's own
    assert copies[-1].read_bytes() == clouds[-1] and not copies[0].exists()
    assert prepare(load_scene(_scene_of(tmp_path, fetched.scene)).bodies[0]).stats["points"] == 200
    again, _ = fetched_twin(twin, folder, lambda name: clouds[0])  # an old cloud back: fetched again
    assert Path(again.scene["bodies"][0]["file"]) == copies[0] and copies[0].read_bytes() == clouds[0]


def _scene_of(folder: Path, scene: dict) -> Path:
    path = folder / "fetched.json"
    path.write_text(json.dumps({"name": "fetched", **scene}))
    return path


def test_the_copies_fit_in_their_bytes_the_last_used_kept_the_twins_own_always_and_dead_parts_go(tmp_path):
    import os

    paths = []
    for k in range(6):
        path = tmp_path / f"{k:064x}.pcd"
        path.write_bytes(b"x" * 1000)
        os.utime(path, ns=(k * 10**9, k * 10**9))  # the last used: the highest k
        paths.append(path)
    (tmp_path / ".fetching-dead").write_bytes(b"half a scan")  # a service died writing it, long ago
    os.utime(tmp_path / ".fetching-dead", ns=(0, 0))
    (tmp_path / ".fetching-now").write_bytes(b"being written")
    deleted = prune(tmp_path, keep={paths[0]}, copies=10, size=3500)
    assert set(deleted) == set(paths[1:4])  # the twin's own (1000) and the last two used fit in 3500
    assert sorted(tmp_path.iterdir()) == [tmp_path / ".fetching-now", paths[0], paths[4], paths[5]]
