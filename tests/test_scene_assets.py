"""How a Thing names the files of its scene's meshes and scans: one name each, never another file's, relative to
scene.json, with the media type IANA registers where there is one; a file gone from disk is a 404, not a 5xx."""
from __future__ import annotations

import pytest

from devices.things.scene_files import SceneAssets
from mesh.messages.relations import SCENE_ASSET
from mesh.wot.problem import NotFound


def _bodies(*files: tuple[str, str]) -> list[dict]:
    return [{"type": kind, "name": f"b{i}", "file": file} for i, (kind, file) in enumerate(files)]


def test_two_files_of_one_name_in_two_folders_get_two_names_and_none_is_the_things_own():
    assets = SceneAssets(taken=["scene.json", "scene-wall.stl"])
    bodies = _bodies(("mesh", "/lab/a/wall.stl"), ("mesh", "/lab/b/wall.stl"), ("points", "/scans/room scan (1).PCD"),
                     ("box", "/not/a/file.stl"))
    assets.add(bodies)
    names = assets.names()
    assert set(names) == {"/lab/a/wall.stl", "/lab/b/wall.stl", "/scans/room scan (1).PCD"}
    assert len(set(names.values())) == 3 and "scene-wall.stl" not in names.values()
    assert names["/scans/room scan (1).PCD"] == "scene-room-scan-1.PCD"  # a key chunk and a URL segment as it is


def test_the_served_scene_names_each_file_as_linked():
    assets = SceneAssets()
    bodies = _bodies(("mesh", "/cad/ring.glb"), ("points", "/scans/room.pcd"), ("mesh", "/cad/ring.glb"))
    assets.add(bodies)
    served = assets.relative({"name": "s", "bodies": bodies})
    links = assets.links(bodies)
    assert [b["file"] for b in served["bodies"]] == ["scene-ring.glb", "scene-room.pcd", "scene-ring.glb"]
    assert [(link.href, link.rel, link.type) for link in links] == [
        ("files/scene-ring.glb", SCENE_ASSET, "model/gltf-binary"),
        ("files/scene-room.pcd", SCENE_ASSET, "application/octet-stream")]


def test_a_file_gone_from_disk_is_not_found(tmp_path):
    scan = tmp_path / "room.xyz"
    scan.write_text("0 0 0\n")
    assets = SceneAssets()
    (asset,) = assets.add(_bodies(("points", str(scan))))
    assert asset.read() == b"0 0 0\n" and asset.media_type == "text/plain"
    scan.unlink()
    with pytest.raises(NotFound, match="room.xyz"):
        asset.read()
