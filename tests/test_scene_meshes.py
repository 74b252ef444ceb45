"""CAD meshes as scene bodies: a closed mesh split into hulls (its hole stays free), an open surface kept
a surface (never filled to its hull), every format alike, a mesh without faces refused in one line."""
from __future__ import annotations

import json

import numpy as np
import pybullet as pb
import pytest
import trimesh
from click.testing import CliRunner

from devices.cli.main import main
from tdgen.robot.surroundings import build_into, load_scene, prepare
from tests.scans import render_scan, triangulate


@pytest.fixture(autouse=True, scope="module")
def scan_cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TWINMESH_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


def _scene(folder, file: str, **extra):
    body = {"type": "mesh", "name": "thing", "file": file, "position": [1.0, 0.0, 0.0], "rpy": [0, 0, 90], **extra}
    path = folder / "scene.json"
    path.write_text(json.dumps({"name": "meshes", "bodies": [body]}))
    return path


class Probe:
    """A small sphere moved around a scene built in pybullet: does it touch anything there?"""

    def __init__(self, scene, radius=0.01):
        self.client = pb.connect(pb.DIRECT)
        build_into(scene, self.client)
        shape = pb.createCollisionShape(pb.GEOM_SPHERE, radius=radius, physicsClientId=self.client)
        self.sphere = pb.createMultiBody(1.0, shape, -1, [0, 0, 10], physicsClientId=self.client)

    def touches(self, at) -> bool:
        pb.resetBasePositionAndOrientation(self.sphere, list(at), [0, 0, 0, 1], physicsClientId=self.client)
        pb.performCollisionDetection(physicsClientId=self.client)
        return any(c[8] < 0 for c in pb.getContactPoints(bodyA=self.sphere, physicsClientId=self.client))

    def close(self):
        pb.disconnect(self.client)


def _placed(local):
    """A point of the mesh's own frame in the scene: the body at (1, 0, 0), turned 90 degrees about z."""
    x, y, z = local
    return (1.0 - y, x, z)


def test_a_closed_mesh_is_split_into_hulls_and_its_hole_stays_free(tmp_path):
    trimesh.creation.torus(0.3, 0.06).export(tmp_path / "ring.stl")
    scene = load_scene(_scene(tmp_path, "ring.stl"))
    made = prepare(scene.bodies[0])
    assert made.kind == "hulls" and made.stats["hulls"] >= 4
    probe = Probe(scene)
    try:
        assert not probe.touches(_placed((0.0, 0.0, 0.0)))  # the ring's hole: inside its convex hull, free
        assert probe.touches(_placed((0.3, 0.0, 0.0)))  # in the tube
        assert probe.touches(_placed((0.0, -0.3, 0.0)))
    finally:
        probe.close()


def test_an_open_surface_stays_a_surface(tmp_path):
    box = trimesh.creation.box((0.6, 0.6, 0.4))
    keep = box.face_normals[:, 2] < 0.5  # an open crate: no lid
    crate = trimesh.Trimesh(box.vertices, box.faces[keep])
    crate.export(tmp_path / "crate.obj")
    scene = load_scene(_scene(tmp_path, "crate.obj"))
    assert prepare(scene.bodies[0]).kind == "surface"
    probe = Probe(scene, radius=0.02)
    try:
        assert not probe.touches(_placed((0.0, 0.0, 0.05)))  # inside the crate, clear of its walls
        assert probe.touches(_placed((0.3, 0.0, 0.0)))  # through a wall
        assert probe.touches(_placed((0.0, 0.0, -0.2)))  # on the bottom
    finally:
        probe.close()


@pytest.mark.parametrize("suffix", ["stl", "obj", "ply", "glb", "off"])
def test_every_mesh_format_gives_the_same_body(tmp_path, suffix):
    trimesh.creation.box((0.2, 0.4, 0.6)).export(tmp_path / f"box.{suffix}")
    scene = load_scene(_scene(tmp_path, f"box.{suffix}", scale=2.0))
    made = prepare(scene.bodies[0])
    assert made.kind == "hull"
    assert np.allclose(made.high - made.low, (0.4, 0.8, 1.2))
    probe = Probe(scene)
    try:
        assert probe.touches(_placed((0.0, 0.35, 0.0))) and not probe.touches(_placed((0.0, 0.45, 0.0)))
    finally:
        probe.close()


def test_a_triangulated_scan_is_an_open_mesh(tmp_path):
    from tdgen.robot.surroundings import BoxBody, Surroundings

    wall = Surroundings(name="wall", bodies=[BoxBody(name="wall", size=(2.0, 0.1, 1.6), position=(0.0, 0.6, 0.8))])
    scan = render_scan(wall, eye=(0.0, -1.0, 0.8), target=(0.0, 0.6, 0.8), size=(64, 48), holes=0.0)
    triangulate(scan, tmp_path / "wall.ply")
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"name": "w", "bodies": [{"type": "mesh", "name": "wall", "file": "wall.ply",
                                                          "position": list(scan.position), "rpy": list(scan.rpy)}]}))
    scene = load_scene(path)
    assert prepare(scene.bodies[0]).kind == "surface"
    probe = Probe(scene, radius=0.02)
    try:
        assert probe.touches((0.0, 0.55, 0.8))  # on the scanned face
        assert not probe.touches((0.0, 0.45, 0.8))
    finally:
        probe.close()


@pytest.mark.parametrize("name, make, said", [
    ("points.ply", lambda p: trimesh.PointCloud(np.random.default_rng(0).random((50, 3))).export(p), "no faces"),
    ("empty.stl", lambda p: p.write_bytes(b""), "empty"),
    ("broken.obj", lambda p: p.write_text("v 0 0 0\nf 1 2 3\n"), "cannot read"),
    ("thing.step", lambda p: p.write_text("ISO-10303-21;"), "unknown mesh format"),
    ("huge.stl", lambda p: trimesh.creation.box((800.0, 600.0, 400.0)).export(p), "millimetres given as metres"),
])
def test_a_bad_mesh_is_one_line_naming_the_file_and_exit_2(tmp_path, name, make, said):
    make(tmp_path / name)
    shown = CliRunner().invoke(main, ["scene", "show", str(_scene(tmp_path, name))])
    assert shown.exit_code == 2
    lines = shown.output.strip().splitlines()
    assert len(lines) == 1 and name in lines[0] and said in lines[0], shown.output
