"""Scans as scene bodies: every cloud format read alike, bad files refused in one line, and a robot that
comes within 5 mm of a scanned point never called free (scans rendered from a scene whose truth is known)."""
from __future__ import annotations

import json

import msgspec
import numpy as np
import pytest
from click.testing import CliRunner

from devices.cli.main import main
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import FastCollision
from tdgen.robot.model import Robot
from tdgen.robot.scan_io import read_cloud
from tdgen.robot.surroundings import (
    BoxBody,
    PointsBody,
    RobotPlacement,
    SceneError,
    Surroundings,
    build_into,
    load_scene,
)
from tests.scan_formats import write_e57, write_las
from tests.scans import Truth, render_scan, write_pcd, write_ply, write_xyz

TABLE = {"type": "box", "name": "table", "size": [0.6, 0.6, 0.6], "position": [0.0, 0.0, 0.3]}  # known, not scanned
ROOM = Surroundings(name="room", bodies=[
    BoxBody(name="floor", size=(3.0, 3.0, 0.02), position=(0.0, 0.0, -0.01)),
    BoxBody(name="wall", size=(2.0, 0.1, 1.6), position=(0.0, 0.6, 0.8)),
    BoxBody(name="crate", size=(0.3, 0.3, 0.4), position=(0.55, -0.2, 0.2))])


@pytest.fixture(autouse=True, scope="module")
def scan_cache(tmp_path_factory):
    with pytest.MonkeyPatch.context() as mp:
        mp.setenv("TWINMESH_CACHE", str(tmp_path_factory.mktemp("cache")))
        yield


@pytest.fixture(scope="module")
def scan():
    return render_scan(ROOM, eye=(1.4, -1.3, 1.5), target=(0.0, 0.2, 0.4), size=(96, 72), seed=3)


def _scene(tmp_path, file: str, pose=None, table: bool = False, **extra) -> str:
    """A scene of the scan in `file` seen from `pose`; with `table`, the robot on a known table in it."""
    position, rpy = pose if pose else ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0))
    body = {"type": "points", "name": "scan", "file": file, "position": list(position), "rpy": list(rpy), **extra}
    path = tmp_path / "scene.json"
    path.write_text(json.dumps({"name": "scanned", "robot": {"position": [0, 0, 0.6 if table else 0.0]},
                                "bodies": [TABLE, body] if table else [body]}))
    return str(path)


def _show(scene: str):
    return CliRunner().invoke(main, ["scene", "show", scene])


@pytest.mark.parametrize("write", [
    lambda s, d: write_pcd(s, d / "a.pcd", "ascii"), lambda s, d: write_pcd(s, d / "b.pcd", "binary"),
    lambda s, d: write_pcd(s, d / "c.pcd", "binary_compressed"),
    lambda s, d: write_pcd(s, d / "d.pcd", "binary_compressed", extra=False),
    lambda s, d: write_ply(s, d / "e.ply", ascii=True), lambda s, d: write_ply(s, d / "f.ply"),
    lambda s, d: write_xyz(s, d / "g.xyz"), lambda s, d: write_las(s, d / "h.las"),
    lambda s, d: write_las(s, d / "i.laz"), lambda s, d: write_e57(s, d / "j.e57")],
    ids=["pcd-ascii", "pcd-binary", "pcd-compressed-label-rgba", "pcd-compressed-xyz", "ply-ascii", "ply-binary",
         "xyz-text", "las", "laz", "e57"])
def test_every_cloud_format_gives_the_scans_points(scan, tmp_path, write):
    points = read_cloud(write(scan, tmp_path))
    assert points.shape == scan.finite().shape  # an organized cloud's NaN points dropped, none else
    assert np.allclose(points, scan.finite(), atol=1e-4)


def test_scene_show_tells_what_a_scan_became(scan, tmp_path):
    write_pcd(scan, tmp_path / "room.pcd")
    shown = _show(_scene(tmp_path, "room.pcd", (scan.position, scan.rpy)))
    assert shown.exit_code == 0, shown.output
    line = next(s for s in shown.output.splitlines() if s.strip().startswith("scan:"))
    assert f"{len(scan.finite()):,} points" in line and "voxels" in line and "boxes" in line
    lo, hi = (np.array([float(v) for v in part.strip(" ()m").split(",")]) for part in line.split("box ")[1].split(".."))
    truth = scan.world()  # the box is in the scene frame: the sensor's pose applied
    assert np.all(lo <= truth.min(axis=0)) and np.all(hi >= truth.max(axis=0))
    assert np.all(hi - lo < truth.max(axis=0) - truth.min(axis=0) + 0.1)


def _nan_pcd(path):
    from pypcd4 import Encoding, PointCloud

    PointCloud.from_xyz_points(np.full((40, 3), np.nan, dtype=np.float32)).save(path, encoding=Encoding.BINARY_COMPRESSED)


def _cut_pcd(path):
    """A binary_compressed PCD whose compressed block is cut short (a copy interrupted)."""
    whole = write_pcd(render_scan(ROOM, eye=(1.4, -1.3, 1.5), target=(0.0, 0.2, 0.4), size=(32, 24), seed=4), path)
    path.write_bytes(whole.read_bytes()[:-200])


@pytest.mark.parametrize("name, make, said", [
    ("missing.pcd", None, "file not found"),
    ("cut.pcd", _cut_pcd, "compressed data"),
    ("empty.pcd", lambda p: p.write_bytes(b""), "empty"),
    ("garbage.pcd", lambda p: p.write_bytes(b"\x00\x01not a pcd at all" * 20), "cannot read"),
    ("garbage.las", lambda p: p.write_bytes(b"LASF but nothing else" * 20), "LAS header is broken"),
    ("garbage.e57", lambda p: p.write_bytes(b"ASTM-E57 but nothing else" * 20), "cannot read"),
    ("scan.e58", lambda p: p.write_text("1 2 3\n"), "unknown point cloud format"),
    ("holes.pcd", _nan_pcd, "NaN"),
    ("millimetres.xyz", lambda p: p.write_text("0 0 0\n1500 0 0\n0 2500 800\n"), "millimetres given as metres"),
    ("words.xyz", lambda p: p.write_text("1 2 3\nfour five six\n"), "not x y z"),
])
def test_a_bad_scan_is_one_line_naming_the_file_and_exit_2(tmp_path, name, make, said):
    if make:
        make(tmp_path / name)
    shown = _show(_scene(tmp_path, name))
    assert shown.exit_code == 2
    lines = shown.output.strip().splitlines()
    assert len(lines) == 1 and name in lines[0] and said in lines[0], shown.output
    assert "Traceback" not in shown.output


def test_a_scan_in_millimetres_is_fine_with_its_scale(tmp_path):
    (tmp_path / "mm.xyz").write_text("0 0 0\n1500 0 0\n0 2500 800\n")
    scene = load_scene(_scene(tmp_path, "mm.xyz", scale=0.001))
    assert isinstance(scene.bodies[0], PointsBody)


def test_a_voxel_out_of_range_is_refused(tmp_path):
    (tmp_path / "a.xyz").write_text("0 0 0\n")
    with pytest.raises(SceneError, match="voxel must be between"):
        load_scene(_scene(tmp_path, "a.xyz", voxel=0))


@pytest.fixture(scope="module")
def scanned_world(scan, tmp_path_factory):
    """UR10 on its table in the room, the room known only from its scan; the truth from the scanned points."""
    folder = tmp_path_factory.mktemp("room")
    write_pcd(scan, folder / "room.pcd")
    scene = load_scene(_scene(folder, "room.pcd", (scan.position, scan.rpy), table=True))
    robot = Robot.load("ur10.urdf")
    truth = Truth(robot, scene, scan.world(), msgspec.structs.replace(scene, bodies=scene.bodies[:1]))
    world = CollisionWorld(robot, scene)
    yield robot, scene, world, truth
    world.close()
    truth.close()


def test_near_a_scanned_point_is_never_free_far_from_all_is(scanned_world):
    robot, _, world, truth = scanned_world
    qs = np.random.default_rng(5).uniform(robot.lows(), robot.highs(), (400, len(robot.lows())))
    exact_hits, fast_hits = world.colliding(qs), FastCollision(world).colliding(qs)
    assert np.array_equal(fast_hits, exact_hits)  # the scan's boxes cut into pieces: the exact test's answers
    exact, fast = truth.figures(qs, exact_hits), truth.figures(qs, fast_hits)
    for figures in (exact, fast):
        assert figures.near > 20 and figures.near_free == 0
        assert figures.far > 20 and figures.far_share >= 0.99
    only_scan = [q for q, hit, other in zip(qs, world.colliding(qs), truth.free.colliding(qs)) if hit and not other]
    assert only_scan and all(any(pair.endswith("/ scan") for pair in world.what_collides(q)) for q in only_scan[:5])


def test_the_twins_target_check_refuses_what_comes_near_a_scanned_point(scanned_world):
    from devices.planning.moves import MovePlanner, TdFrame

    robot, scene, _, truth = scanned_world
    planner = MovePlanner(robot, "ur10", scene, TdFrame(), peak_speed=1.5)
    try:
        qs = np.random.default_rng(6).uniform(robot.lows(), robot.highs(), (200, len(robot.lows())))
        figures = truth.figures(qs, np.array([planner.collides(q) for q in qs]))
    finally:
        planner.close()
    assert figures.near > 10 and figures.near_free == 0
    assert figures.far > 10 and figures.far_share >= 0.99


def test_merged_boxes_cover_exactly_the_occupied_voxels():
    from tdgen.robot.scan_bodies import merge_cells

    rng = np.random.default_rng(2)
    cells = np.unique(np.vstack([rng.integers(0, 12, (300, 3)), np.argwhere(np.ones((6, 5, 1), dtype=bool))]), axis=0)
    lo, hi = merge_cells(cells)
    covered = [tuple(c) for a, b in zip(lo, hi) for c in np.argwhere(np.ones(b - a + 1, dtype=bool)) + a]
    assert len(covered) == len(set(covered)) == len(cells)  # no voxel twice
    assert set(covered) == {tuple(c) for c in cells}
    assert len(lo) < len(cells) - 20  # the 6 x 5 slab is a few boxes, not 30


def test_cells_too_far_apart_for_one_sort_key_merge_all_the_same():
    from tdgen.robot.scan_bodies import merge_cells

    slab = np.argwhere(np.ones((4, 3, 2), dtype=bool))
    cells = np.vstack([slab, slab + (1 << 20)])  # five spans of 21 bits each: more than one int64 holds
    lo, hi = merge_cells(cells)
    far = 1 << 20
    assert sorted(map(tuple, np.hstack([lo, hi]))) == [(0, 0, 0, 3, 2, 1), (far, far, far, far + 3, far + 2, far + 1)]


def test_a_body_made_where_a_scan_was_removed_is_itself_to_the_fast_model(tmp_path):
    """pybullet gives a removed body's id to the next one made: a shelf of as many parts as the scan had, made
    there, is its own boxes to the fast model, not the scan's."""
    import pybullet as pb

    from tdgen.robot.spheres import scene_elements

    (tmp_path / "a.xyz").write_text("".join(f"{x / 10} {y / 10} 1.0\n" for x in range(10) for y in range(10)))
    client = pb.connect(pb.DIRECT)
    try:
        scan = build_into(load_scene(_scene(tmp_path, "a.xyz")), client)[0]
        assert len(scene_elements(pb, client, scan)) > 1  # the scan's boxes
        links = pb.getNumJoints(scan, physicsClientId=client)
        pb.removeBody(scan, physicsClientId=client)
        part = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=[0.1, 0.1, 0.1], physicsClientId=client)
        shelf = pb.createMultiBody(0.0, part, -1, [5.0, 0.0, 0.0], linkMasses=[0.0] * links,
                                   linkCollisionShapeIndices=[part] * links, linkVisualShapeIndices=[-1] * links,
                                   linkPositions=[[0.0, 0.0, 0.3 * (k + 1)] for k in range(links)],
                                   linkOrientations=[[0, 0, 0, 1]] * links, linkInertialFramePositions=[[0, 0, 0]] * links,
                                   linkInertialFrameOrientations=[[0, 0, 0, 1]] * links, linkParentIndices=[0] * links,
                                   linkJointTypes=[pb.JOINT_FIXED] * links, linkJointAxis=[[0, 0, 1]] * links,
                                   physicsClientId=client)
        assert shelf == scan  # the id given again (else this test shows nothing)
        corners = np.vstack([e.points for e in scene_elements(pb, client, shelf)])
        assert np.allclose(corners[:, :2].mean(axis=0), [5.0, 0.0], atol=1e-6)  # the shelf's, at x = 5 m
    finally:
        pb.disconnect(client)


def _box_distance(points: np.ndarray, boxes: np.ndarray) -> np.ndarray:
    """Each point's Euclidean distance to the nearest of the boxes (low, high), 0 inside one."""
    out = np.full(len(points), np.inf)
    for start in range(0, len(boxes), 256):
        lo, hi = boxes[start:start + 256, 0], boxes[start:start + 256, 1]
        gap = np.maximum(np.maximum(lo[None] - points[:, None], points[:, None] - hi[None]), 0.0)
        out = np.minimum(out, np.linalg.norm(gap, axis=2).min(axis=1))
    return out


@pytest.fixture(scope="module")
def scan_alone(scanned_world):
    """The scan alone in a world holding part of the scene, as a live update checks an added body."""
    robot, scene, _, truth = scanned_world
    world = CollisionWorld(robot, msgspec.structs.replace(scene, bodies=scene.bodies[1:]), part=True)
    yield robot, world, truth
    world.close()


def test_the_distance_field_never_puts_a_place_further_from_the_scan_than_it_is(scan_alone):
    from tdgen.robot.scan_bodies import clearance, scan_of

    _, world, _ = scan_alone
    scan = scan_of(world._pb, world.client, next(iter(world._scene_names)))
    assert scan is not None
    field = clearance(scan)
    low, high = scan.boxes[:, 0].min(axis=0), scan.boxes[:, 1].max(axis=0)
    points = np.random.default_rng(8).uniform(low - 0.5, high + 0.5, (6_000, 3))  # also beyond the grid
    points[:600] = scan.boxes[:600 // 2, 0].repeat(2, axis=0)[:600] + 1e-4  # some just inside a box
    true, said = _box_distance(points, scan.boxes), field.distance(points)
    assert np.all(said <= true + 1e-6), f"{np.max(said - true):.4f} m more than the truth"
    inside = np.all((points > low) & (points < high), axis=1)  # beyond the grid: taken at its edge
    away = inside & (true > 0.2) & (true < 0.6)  # where a link's sphere would be cleared
    assert away.sum() > 150 and np.mean(said[away] > 0.05) > 0.99


def test_the_scans_shortcut_clears_no_sample_that_touches_it(scan_alone):
    """A live update asks a world of the added scan which base-free samples touch it: the distance field
    clears most at once, and never one that touches the scan or comes within 5 mm of a scanned point."""
    robot, world, truth = scan_alone
    fast = FastCollision(world)
    assert fast.scans is not None
    qs = np.random.default_rng(9).uniform(robot.lows(), robot.highs(), (600, len(robot.lows())))
    exact, cleared = world.colliding(qs), fast.scans.clear(qs)
    assert exact.sum() > 50 and not (cleared & exact).any()
    assert cleared.sum() > 0.5 * (~exact).sum()  # it does spare the compiled check most of the free ones
    assert not any(truth.touches(0.005, q) for q in qs[cleared])
    assert np.array_equal(fast.colliding(qs), exact)


def test_a_distance_field_cut_to_where_a_robot_reaches_puts_no_place_further_than_it_is(scan_alone):
    """A field made only around the robot (`within`) is a lower bound everywhere, also beyond that region
    (where nothing may be cleared: the boxes cut away are not in it), and still clears places in it."""
    from tdgen.robot.scan_bodies import clearance, scan_of

    _, world, _ = scan_alone
    scan = scan_of(world._pb, world.client, next(iter(world._scene_names)))
    assert scan is not None
    region = (np.array([-0.8, -0.9, 0.1]), np.array([0.7, 0.8, 1.2]))  # cuts the floor and the wall
    field = clearance(scan, region)
    assert field.centres.size < clearance(scan).centres.size
    low, high = scan.boxes[:, 0].min(axis=0), scan.boxes[:, 1].max(axis=0)
    points = np.random.default_rng(10).uniform(low - 0.5, high + 0.5, (6_000, 3))
    points[:600] = scan.boxes[:600 // 2, 0].repeat(2, axis=0)[:600] + 1e-4  # some just inside a box
    true, said = _box_distance(points, scan.boxes), field.distance(points)
    assert np.all(said <= true + 1e-6), f"{np.max(said - true):.4f} m more than the truth"
    inside = np.all((points > region[0] + 0.1) & (points < region[1] - 0.1), axis=1)
    away = inside & (true > 0.2)
    assert away.sum() > 50 and np.mean(said[away] > 0.05) > 0.99


@pytest.fixture(scope="module")
def live_scan(scanned_world):
    """The UR10's samples generated on its table alone, then the scan added live."""
    from tdgen.live import LiveSamples
    from tdgen.robot import points_csv
    from tdgen.sampling import sample_workspace

    robot, scene, _, _ = scanned_world
    base = msgspec.structs.replace(scene, bodies=scene.bodies[:1])
    generated = sample_workspace(robot, base, 2000, seed=2)
    live = LiveSamples(robot, base, generated,
                       points_csv.encode(robot, generated.positions, generated.collision, generated.q))
    yield live
    live.close()


def test_a_scan_added_live_names_what_collides_as_a_world_of_the_whole_scene_does(scanned_world, live_scan):
    """The TD's warnings count what collides in the first colliding samples: asked of the base and of the
    scan alone, it is what a world holding both says, the scan named as the scene names it."""
    from tdgen.generate import PAIR_SAMPLES

    robot, scene, world, _ = scanned_world
    live, _ = live_scan.rescene(scene)
    rows = np.flatnonzero(live.samples.collision)[:PAIR_SAMPLES]
    said = live.pairs()
    assert any(pair.endswith("/ scan") for pairs in said for pair in pairs)
    assert [sorted(p) for p in said] == [sorted(world.what_collides(q)) for q in live.base_samples.q[rows]]


def test_the_same_scan_added_again_is_answered_without_a_check(scanned_world, live_scan):
    robot, scene, _, _ = scanned_world
    first, checked = live_scan.rescene(scene)
    crate = BoxBody(name="crate", size=(0.2, 0.2, 0.2), position=(0.5, 0.3, 0.7))
    boxed, _ = live_scan.rescene(msgspec.structs.replace(scene, bodies=[scene.bodies[0], crate]))
    again, checked_again = boxed.rescene(msgspec.structs.replace(boxed.scene, bodies=scene.bodies))
    assert checked_again == 0 and np.array_equal(again.samples.collision, first.samples.collision)
    assert again.pairs() == first.pairs()


def test_a_scan_written_again_under_its_name_is_checked_anew(scanned_world, tmp_path):
    """Answers are kept by the file's content: a newer cloud in the same file is another body."""
    from tdgen.live import LiveSamples
    from tdgen.robot import points_csv
    from tdgen.sampling import sample_workspace

    robot, scene, _, _ = scanned_world
    base = msgspec.structs.replace(scene, bodies=scene.bodies[:1])
    generated = sample_workspace(robot, base, 500, seed=4)
    live = LiveSamples(robot, base, generated,
                       points_csv.encode(robot, generated.positions, generated.collision, generated.q))
    try:
        cloud = tmp_path / "latest.xyz"
        near = "".join(f"{0.4 + x / 20} {y / 20 - 0.5} {z / 20 + 0.6}\n" for x in range(8) for y in range(20)
                       for z in range(12))
        cloud.write_text(near)  # a block beside the robot, on its table
        body = PointsBody(name="camera", file=str(cloud))
        with_near, _ = live.rescene(msgspec.structs.replace(base, bodies=[*base.bodies, body]))
        assert with_near.samples.collision.sum() > generated.collision.sum()
        cloud.write_text("9.0 9.0 9.0\n9.1 9.0 9.0\n")  # out of reach now
        with_far, checked = live.rescene(msgspec.structs.replace(base, bodies=[*base.bodies, body]))
        assert checked > 0 and np.array_equal(with_far.samples.collision, generated.collision)
    finally:
        live.close()


GRAZE = 0.0048  # m: a link this far above a scanned point, within the 5 mm that must collide


def _grazing_patch(robot: Robot, q: np.ndarray, folder) -> tuple[Surroundings, Surroundings]:
    """A scan of a small floor patch, a 2 mm grid of points, right under the lowest point of the robot at
    q, `GRAZE` below it, the points just under a voxel's top face (so that only the padding, not the
    voxel, reaches the link): (the scene without the scan, with it)."""
    import pybullet as pb

    placed = Surroundings(name="grazed", robot=RobotPlacement(position=(0.0, 0.0, 1.0)))
    world = CollisionWorld(robot, msgspec.structs.replace(placed, bodies=[
        BoxBody(name="probe", size=(6.0, 6.0, 0.01), position=(0.0, 0.0, -2.0))]))
    try:
        world._set(world._values(q[None])[0])
        probe = next(iter(world._scene_names))
        closest = min(pb.getClosestPoints(world.body, probe, 10.0, physicsClientId=world.client), key=lambda c: c[8])
        lowest = np.array(closest[5])  # on the robot
    finally:
        world.close()
    voxel = 0.02
    height = np.floor(lowest[2] / voxel) * voxel - 0.0005  # just under a voxel's top face
    if lowest[2] - height < GRAZE:
        height -= voxel
    lift = height + GRAZE - lowest[2]  # the robot moved down onto it (its base; every point moves alike)
    xs = np.arange(-25, 26) * 0.002
    points = np.array([(lowest[0] + x, lowest[1] + y, height) for x in xs for y in xs])
    np.savetxt(folder / "patch.xyz", points, fmt="%.6f")
    base = msgspec.structs.replace(placed, robot=RobotPlacement(position=(0.0, 0.0, float(1.0 + lift))))
    scan = PointsBody(name="patch", file=str(folder / "patch.xyz"), voxel=voxel)
    return base, msgspec.structs.replace(base, bodies=[scan])


def test_a_link_grazing_a_scanned_point_is_never_free_nor_cleared_live(scanned_world, tmp_path):
    """The 5 mm rule at its edge: a link 4.8 mm above a scanned point that lies just under its voxel's top
    face, so that only the boxes' padding reaches it, collides in the exact test, the fast model, the scan's
    distance field and a live update (the padding weakened below that, this fails)."""
    from tdgen.live import LiveSamples
    from tdgen.robot import points_csv
    from tdgen.robot.fast_collision import ScanClearance
    from tdgen.sampling import Samples

    robot = scanned_world[0]
    q = np.array([0.3, -0.4, 1.9, 0.2, 1.2, 0.0])  # the forearm and wrist reaching down in front
    base, scene = _grazing_patch(robot, q, tmp_path)
    truth = Truth(robot, scene, np.loadtxt(tmp_path / "patch.xyz"), base)
    alone = CollisionWorld(robot, msgspec.structs.replace(scene, bodies=[]), part=True)
    world = CollisionWorld(robot, scene)
    try:
        assert truth.touches(0.005, q) and not truth.free.collides(q)  # near a point, free otherwise
        assert world.collides(q) and FastCollision(world).collides(q)
        alone.set_bodies(scene.bodies)
        fast = FastCollision(alone)
        assert isinstance(fast.scans, ScanClearance) and not fast.scans.clear(q[None])[0]
        assert fast.colliding(q[None])[0]
        positions = np.zeros((1, 3))
        samples = Samples(q[None], positions, np.zeros(1, dtype=bool))
        live = LiveSamples(robot, base, samples, points_csv.encode(robot, positions, samples.collision, q[None]))
        try:
            assert live.rescene(scene)[0].samples.collision[0]
        finally:
            live.close()
    finally:
        truth.close()
        alone.close()
        world.close()
