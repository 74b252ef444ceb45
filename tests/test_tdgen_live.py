"""Live updates (tdgen.live): a box put down or taken away re-checks only the samples it can touch, and
the result is what a generation from scratch in the new scene gives, flag for flag and byte for byte."""
from __future__ import annotations

import hashlib

import msgspec
import numpy as np
import pytest

from mesh.messages.scene_description import Pose, TwinDescription
from tdgen.artefacts import artefact_key, live_artefacts, load_robot, make_artefacts, scene_of, write_entry
from tdgen.cache import ArtefactCache
from tdgen.following import Following
from tdgen.generate import collision_warnings
from tdgen.live import LiveSamples, NeedsGeneration
from tdgen.robot import points_csv
from tdgen.robot.model import Robot, resolve_urdf
from tdgen.robot.surroundings import BoxBody, CylinderBody, RobotPlacement, load_scene
from tdgen.sampling import sample_workspace

SAMPLES = 3000
# on the table beside the UR10 (table-and-wall: the robot's base on the table top at z = 0.625 m, a wall at y = 0.6)
CRATE = BoxBody(name="crate", size=(0.3, 0.3, 0.3), position=(0.45, 0.25, 0.775))
PILLAR = CylinderBody(name="pillar", radius=0.08, length=0.6, position=(-0.4, 0.3, 0.925))


@pytest.fixture(scope="module")
def ur10() -> Robot:
    return Robot.load("ur10.urdf")


@pytest.fixture(scope="module")
def base():
    return load_scene("table-and-wall")


def encoded(robot: Robot, samples) -> bytes:
    return points_csv.encode(robot, samples.positions, samples.collision, samples.q)


def with_bodies(scene, *bodies):
    return msgspec.structs.replace(scene, bodies=[*scene.bodies, *bodies])


@pytest.mark.parametrize("model", ["fast", "exact"])
def test_adding_moving_and_removing_boxes_flags_the_samples_as_a_generation_would(ur10, base, model):
    generated = sample_workspace(ur10, base, SAMPLES, seed=3, collision_model=model)
    live = LiveSamples(ur10, base, generated, encoded(ur10, generated), model)
    try:
        moved = msgspec.structs.replace(CRATE, position=(0.35, -0.3, 0.8))
        for scene in (with_bodies(base, CRATE), with_bodies(base, CRATE, PILLAR), with_bodies(base, moved, PILLAR),
                      with_bodies(base, moved), base):
            live, checked = live.rescene(scene)
            scratch = sample_workspace(ur10, scene, SAMPLES, seed=3, collision_model=model)
            assert np.array_equal(live.samples.collision, scratch.collision), scene.bodies[-1].name
            assert live.flags.data == encoded(ur10, scratch)
            assert checked <= 2 * int((~generated.collision).sum())  # only base-free samples, once per new body
            if scene is not base:
                assert live.samples.collision.sum() > generated.collision.sum(), f"{scene.bodies[-1].name} touches none"
            assert live.warnings() == collision_warnings(ur10, scene, scratch)  # the TD's words too
            assert not live.warnings(), "the UR10 among its table and wall collides in most samples by design"
        assert (live.samples.collision != generated.collision).sum() == 0  # the same scene again
        crate = with_bodies(base, CRATE)
        live, _ = live.rescene(crate)
        assert not (generated.collision & ~live.samples.collision).any(), "a box freed a sample"
        assert live.warnings() == collision_warnings(ur10, crate, live.samples)
    finally:
        live.close()


def test_a_scan_added_flags_the_samples_and_words_the_td_as_a_generation_would(ur10, base, tmp_path, monkeypatch):
    """A scan of a crate and a pillar beside the UR10, added live: its distance field clears most samples
    at once, and the flags and warnings are still those of a generation in the scene with the scan."""
    from tdgen.robot.surroundings import PointsBody, Surroundings
    from tests.scans import render_scan, write_pcd

    monkeypatch.setenv("TWINMESH_CACHE", str(tmp_path / "cache"))
    seen = Surroundings(name="seen", bodies=[CRATE, PILLAR])
    scan = render_scan(seen, eye=(1.2, -1.0, 1.6), target=(0.0, 0.2, 0.8), size=(96, 72), seed=4)
    body = PointsBody(name="scan", file=str(write_pcd(scan, tmp_path / "seen.pcd")), position=scan.position,
                      rpy=scan.rpy)
    generated = sample_workspace(ur10, base, SAMPLES, seed=3)
    live = LiveSamples(ur10, base, generated, encoded(ur10, generated))
    try:
        scene = with_bodies(base, body)
        live, _ = live.rescene(scene)
        scratch = sample_workspace(ur10, scene, SAMPLES, seed=3)
        assert live.samples.collision.sum() > generated.collision.sum(), "the scan touches no sample"
        assert np.array_equal(live.samples.collision, scratch.collision)
        assert live.flags.data == encoded(ur10, scratch)
        assert live.warnings() == collision_warnings(ur10, scene, scratch)
    finally:
        live.close()


def test_a_change_a_live_update_cannot_follow_asks_for_a_generation(ur10, base):
    generated = sample_workspace(ur10, base, 500, seed=1)
    live = LiveSamples(ur10, base, generated, encoded(ur10, generated))
    try:
        with pytest.raises(NeedsGeneration, match="gone"):
            live.rescene(msgspec.structs.replace(base, bodies=base.bodies[1:]))
        with pytest.raises(NeedsGeneration, match="moved"):
            live.rescene(msgspec.structs.replace(base, robot=RobotPlacement(position=(0.1, 0.0, 0.0))))
    finally:
        live.close()


def test_a_digest_makes_the_new_points_file_only_from_the_same_samples(ur10, base):
    before = sample_workspace(ur10, base, 800, seed=2)
    after = sample_workspace(ur10, with_bodies(base, CRATE), 800, seed=2)
    other = sample_workspace(ur10, base, 800, seed=5)
    held = points_csv.Flags(encoded(ur10, before))
    digest = points_csv.Flags(encoded(ur10, after)).digest()
    assert len(digest) < 200  # a sha and 100 bytes of flags, not the file
    made = held.from_digest(digest)
    assert made is not None and np.array_equal(made.collision, after.collision)  # the flags, before any bytes
    assert made.data == encoded(ur10, after) and np.array_equal(made.collision, after.collision)
    assert held.data == encoded(ur10, before), "re-flagging changed the file it was made from"
    assert points_csv.Flags(encoded(ur10, other)).from_digest(digest) is None


def twin_for(scene, samples: int = SAMPLES) -> TwinDescription:
    path = resolve_urdf("ur10.urdf")
    bodies = msgspec.to_builtins(scene)
    bodies.pop("robot", None)
    return TwinDescription(robot="ur10", urdf="ur10.urdf", urdf_sha256=hashlib.sha256(path.read_bytes()).hexdigest(),
                           urdf_file="ur10.urdf", urdf_dir=str(path.parent), base=Pose(p=[0, 0, 0], q=[0, 0, 0, 1]),
                           ee=None, scene=bodies, samples=samples, seed=4)


def test_the_services_live_update_writes_the_files_a_generation_writes(tmp_path, base):
    """The cache entry of a live update is the one a generation from scratch makes: td.json, points,
    hull, scene (so a robot that restarts, or another service, serves the same TD)."""
    first, second = twin_for(base), twin_for(with_bodies(base, CRATE))
    second = msgspec.structs.replace(second, version=1)
    cache = ArtefactCache(tmp_path / "live")
    make_artefacts(first, cache, artefact_key(first))
    robot, calibration = load_robot(first)
    held = LiveSamples.from_file(robot, scene_of(first), first.samples, first.seed,
                                 cache.dir / artefact_key(first) / "points.csv")
    following = Following(first, robot, calibration, held)
    assert following.follows(second) and not following.follows(msgspec.structs.replace(second, seed=5))
    samples, _ = held.rescene(scene_of(second))
    live_entry = write_entry(cache, artefact_key(second), live_artefacts(second, samples, robot, calibration))
    scratch_entry = make_artefacts(second, ArtefactCache(tmp_path / "scratch"), artefact_key(second))
    for name in ("td.json", "points.csv", "workspace.stl", "scene.json", "twin.json", "robot-info.json"):
        assert (live_entry / name).read_bytes() == (scratch_entry / name).read_bytes(), name
    samples.close()
