"""The recorder draws a simulated world: robots from their URDFs, animated joints, moving cubes, states.

The first recording comes from a synthetic `world` Thing served by this test on a real lab's mesh,
publishing a known sequence of poses; the last one from the `iot-platform` scene running the cube
workflow. Both are read back with rerun's own reader.
"""
import importlib.util
import math
import subprocess
import time
from pathlib import Path

import msgspec
import pytest
from labs import REPO, start_lab, stop_process
from rerun_view import frame_transforms, joint_units, joint_values, transforms_by_frame

from mesh.fabric.settings import MeshSettings
from mesh.messages.scene_description import Body, Pose, Poses, RobotModel, SceneDescription
from mesh.recorder.scene_drawer import SceneDrawer, SceneFiles
from mesh.wot.thing_description import PropertyAffordance, ThingDescription
from recordings import RERUN, read_column, scalars, texts, wait_for_line

pytestmark = pytest.mark.lab

UARM_URDF = (REPO / "tdgen" / "robot" / "models" / "uarm_swift_pro.urdf").read_text()
UARM_BASE = Pose((-0.375, 0.0, 0.75))
SWEEP = [round(0.1 + 0.02 * i, 4) for i in range(60)]  # lower_arm, rad
CUBE_PATH = [(round(0.1 + 0.005 * i, 4), 0.19, 0.79) for i in range(len(SWEEP))]
CUBE_START = Pose((0.05, 0.19, 0.79))
SCENE = SceneDescription("test-bench", robots=[RobotModel("uarm", "uarm.urdf", UARM_BASE)], bodies=[
    Body("table", "box", (1.0, 1.0, 0.75), Pose((0.0, 0.0, 0.375)), (0.55, 0.45, 0.35)),
    Body("post", "cylinder", (0.02, 0.3), Pose((0.3, -0.3, 0.9)), (0.2, 0.2, 0.2)),
    Body("cube", "box", (0.028, 0.028, 0.028), CUBE_START, (0.86, 0.12, 0.10), moving=True)])
SCENE_JSON = msgspec.json.encode(SCENE)


def world_td() -> ThingDescription:
    return ThingDescription(title="world", description="a synthetic world for the recorder's tests",
                            properties={"poses": PropertyAffordance(type="object", readOnly=True, observable=True)})


def pose_sample(i: int) -> Poses:
    """The i-th sample: lower_arm sweeping up, the cube sliding along x, the uArm holding from half way."""
    q = SWEEP[i]
    return Poses(time=0.01 * (i + 1),
                 joints={"uarm": {"base": 0.0, "lower_arm": q, "elbow_passive": -q, "upper_arm": 0.5,
                                  "wrist_passive": -0.5, "hand": 0.0}},
                 bodies={"cube": Pose(CUBE_PATH[i])},
                 states={"uarm": {"holding": i >= len(SWEEP) // 2, "mode": "sweep"}})


FIRST = Poses(time=0.0, joints={"uarm": {"lower_arm": 0.05}}, bodies={"cube": CUBE_START})


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """Serve `world` here, record while it publishes the sweep at about 200 samples/s, stop with Ctrl-C."""
    from mesh.fabric.server import ExposedThing
    from mesh.fabric.session import open_session

    tmp = tmp_path_factory.mktemp("rec-scene")
    lab = start_lab(tmp, "lights", http=False, things={"light-left"})
    path, log = tmp / "scene.rrd", tmp / "recorder.log"
    try:
        with open_session(MeshSettings(connect=(lab.endpoint,))) as session:
            world = ExposedThing(session, world_td(), "world").state("poses", FIRST)
            world.on_file("scene.json", lambda: SCENE_JSON, "application/json")
            world.on_file("uarm.urdf", lambda: UARM_URDF.encode(), "application/xml")
            with world:
                recorder = lab.spawn("record", str(path), log=log)
                wait_for_line(log, "recording to", recorder)
                for i in range(len(SWEEP)):
                    world.set_value("poses", pose_sample(i))
                    time.sleep(0.005)
                time.sleep(1.5)  # the last samples reach the recorder
                assert stop_process(recorder), f"the recorder did not stop on Ctrl-C:\n{log.read_text()}"
        assert recorder.returncode == 0, log.read_text()
    finally:
        assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"
    return path


def sim_times(path: Path, entity: str) -> list[float]:
    from rerun.chunk import RrdReader

    table = RrdReader(path).stream().collect().reader("sim_time", contents=entity).to_arrow_table()
    return sorted(t.total_seconds() for t in table.column("sim_time").to_pylist())


def static_column(path: Path, entity: str, component: str) -> list:
    """The values a static component of an entity holds (static data has no rows on any timeline)."""
    from rerun.chunk import RrdReader

    out = []
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=True):
        batch = chunk.to_record_batch()
        if chunk.entity_path == entity and component in batch.schema.names:
            out += batch.column(component).to_pylist()
    return out


def test_scene_recording_verifies(recording):
    r = subprocess.run([RERUN, "rrd", "verify", str(recording)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_each_joint_is_a_series_in_its_unit_holding_the_sweep_in_order(recording):
    """One entity per robot, one series per joint: a sample in which a joint moved is a row of all of them."""
    assert joint_values(recording, "/world/joints/uarm", "lower_arm") == pytest.approx([0.05] + SWEEP)
    assert joint_values(recording, "/world/joints/uarm", "upper_arm") == pytest.approx([0.5] * len(SWEEP))
    units = joint_units(recording, "/world/joints/uarm")
    assert set(units) == {"base", "lower_arm", "elbow_passive", "upper_arm", "wrist_passive", "hand"}
    assert set(units.values()) == {"rad"}


def test_joints_are_on_the_sim_time_timeline(recording):
    assert sim_times(recording, "/world/joints/uarm") == pytest.approx(
        [0.0] + [pose_sample(i).time for i in range(len(SWEEP))])


def test_a_joint_that_holds_has_its_transform_logged_once(recording):
    assert len(frame_transforms(recording, "/world/robots/uarm/joints", "uarm/upper_arm")) == 1
    # elbow_passive (its child link: elbow) moves with lower_arm, from the second sample on
    assert len(frame_transforms(recording, "/world/robots/uarm/joints", "uarm/elbow")) == len(SWEEP)


def test_joint_transforms_are_computed_from_the_urdf(recording):
    rows = frame_transforms(recording, "/world/robots/uarm/joints", "uarm/lower_arm")
    assert rows and {r["parent_frame"] for r in rows} == {"uarm/turret"}
    quaternions = [r["quaternion"] for r in rows]
    angles = [2 * math.atan2(math.hypot(x, y, z), w) for x, y, z, w in quaternions]
    assert angles == pytest.approx([0.05] + SWEEP, abs=1e-5)
    # the URDF's axis is -y: a positive angle is a rotation about -y
    assert all(y < 0 and abs(x) < 1e-6 and abs(z) < 1e-6 for x, y, z, _ in quaternions)


def test_cube_translations_follow_its_path(recording):
    """A moving body is drawn in its own frame, placed over time by the rows of `world/poses` naming it."""
    assert static_column(recording, "/world/bodies/cube", "CoordinateFrame:frame") == [["world/bodies/cube"]]
    rows = frame_transforms(recording, "/world/poses", "world/bodies/cube")
    assert {r["parent_frame"] for r in rows} == {"tf#/world"}
    translations = [r["translation"] for r in rows]
    # its pose in scene.json (drawn at the join; the value read at the join is the same), then each sample
    expected = [list(p) for p in [CUBE_START.p] + CUBE_PATH]
    assert [[round(v, 6) for v in p] for p in translations] == expected


def test_robot_is_drawn_from_its_urdf_and_placed_on_its_base(recording):
    arm = "/world/robots/uarm/visual_geometries/upper_arm/visual_0"
    assert static_column(recording, arm, "Boxes3D:half_sizes")[0][0] == pytest.approx([0.085, 0.012, 0.009])
    assert static_column(recording, arm, "CoordinateFrame:frame") == [["uarm/upper_arm"]]
    assert static_column(recording, arm, "Boxes3D:fill_mode") == [[3]]  # solid
    assert static_column(recording, "/world/robots/uarm/visual_geometries/base_link/visual_0", "Cylinders3D:radii")
    assert static_column(recording, "/world/robots/uarm", "CoordinateFrame:frame") == [["uarm/base_link"]]
    base = static_column(recording, "/world/robots/uarm/base", "Transform3D:translation")
    assert base[0][0] == pytest.approx(list(UARM_BASE.p))
    assert static_column(recording, "/world/robots/uarm/base", "Transform3D:parent_frame") == [["tf#/world"]]
    assert static_column(recording, "/world/robots/uarm/base", "Transform3D:child_frame") == [["uarm/base_link"]]
    tf_static = static_column(recording, "/world/robots/uarm/tf_static", "Transform3D:child_frame")
    assert {f[0] for f in tf_static} >= {"uarm/turret", "uarm/lower_arm", "uarm/tcp"}
    assert not static_column(recording, "/world/robots/uarm/collision_geometries/box/turret/collision_0",
                             "Boxes3D:half_sizes")


def test_static_bodies_are_drawn_with_their_colours(recording):
    assert static_column(recording, "/world/bodies/table", "Boxes3D:half_sizes")[0][0] == pytest.approx([0.5, 0.5, 0.375])
    assert static_column(recording, "/world/bodies/table", "Transform3D:translation") == [[[0.0, 0.0, 0.375]]]
    assert static_column(recording, "/world/bodies/post", "Cylinders3D:lengths")[0] == pytest.approx([0.3])
    colour = static_column(recording, "/world/bodies/table", "Boxes3D:colors")[0][0]
    assert colour >> 8 == (140 << 16) | (115 << 8) | 89  # 0xRRGGBBAA


def test_states_are_series_and_text_logged_on_change(recording):
    assert scalars(recording, "/world/states/uarm/holding") == [0.0, 1.0]
    assert texts(recording, "/world/states/uarm/mode") == ["sweep"]


def test_poses_are_not_recorded_as_a_plain_property(recording):
    assert not scalars(recording, "/things/world/properties/poses/time")
    assert "world joined" in texts(recording, "/mesh/log")


# --- the drawer alone ----------------------------------------------------------------------------
def test_two_robots_from_one_urdf_keep_their_own_frames(tmp_path):
    import rerun as rr

    path = tmp_path / "two.rrd"
    rec = rr.RecordingStream("two-robots")
    rec.save(str(path))
    scene = SceneDescription("two", robots=[RobotModel("left", "uarm.urdf", Pose((0.0, -0.3, 0.0))),
                                            RobotModel("right", "uarm.urdf", Pose((0.0, 0.3, 0.0)))])
    drawer = SceneDrawer(rec)
    assert drawer.draw_scene(SceneFiles(scene, {"uarm.urdf": UARM_URDF}), time.time(), 0) == []
    drawer.add_poses(Poses(time=1.0, joints={"left": {"base": 0.5}, "right": {"base": -0.5}}), time.time(), 1)
    drawer.flush()
    rec.flush()
    rec.disconnect()
    for robot in ("left", "right"):
        tf_static = static_column(path, f"/world/robots/{robot}/tf_static", "Transform3D:child_frame")
        assert {f[0] for f in tf_static} >= {f"{robot}/turret", f"{robot}/hand"}
        assert len(frame_transforms(path, f"/world/robots/{robot}/joints", f"{robot}/turret")) == 1
    assert joint_values(path, "/world/joints/left", "base") == [0.5]


def test_a_bad_urdf_is_reported_and_the_rest_is_drawn(tmp_path):
    import rerun as rr

    rec = rr.RecordingStream("bad-urdf")
    rec.save(str(tmp_path / "bad.rrd"))
    scene = SceneDescription("bad", robots=[RobotModel("arm", "arm.urdf", Pose((0.0, 0.0, 0.0)))],
                             bodies=[Body("table", "box", (1.0, 1.0, 0.1), Pose((0.0, 0.0, 0.0))),
                                     Body("ball", "sphere", (0.05,), Pose((0.0, 0.0, 0.1)), moving=True)])
    drawer = SceneDrawer(rec)
    problems = drawer.draw_scene(SceneFiles(scene, {"arm.urdf": "<robot"}), time.time(), 0)
    assert len(problems) == 1 and problems[0].startswith("cannot draw robot arm")
    assert set(drawer.bodies) == {"table", "ball"} and drawer.robots == {}
    drawer.flush()
    rec.disconnect()


# --- the iot-platform scene ----------------------------------------------------------------------
def _platform_missing() -> str | None:
    """Why the iot-platform recording cannot run yet (its scene and workflow are written alongside)."""
    from devices.lab.scenes import SCENES

    if "iot-platform" not in SCENES:
        return "iot-platform scene not registered yet"
    for module in ("devices.lab.iot_platform", "devices.apps.cube_workflow"):
        if importlib.util.find_spec(module) is None:
            return f"iot-platform scene not complete yet: no {module}"
    return None


@pytest.mark.skipif(_platform_missing() is not None, reason=str(_platform_missing()))
def test_cube_workflow_recording_shows_both_arms_and_the_cube_round_trip(tmp_path):
    from devices.sim.layouts.platform_layout import LAYOUT
    from devices.sim.layouts.platform_layout import UARM_BASE as PLATFORM_UARM

    path = tmp_path / "platform.rrd"
    lab = start_lab(tmp_path, "iot-platform", http=False, things={"world", "uarm", "dobot"},
                    extra_args=("--speed", "max", "--record", str(path)))
    try:
        wait_for_line(lab.log, "recording to", lab.proc, timeout=60)
        r = lab.cli("workflow", "cube", timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr
        time.sleep(1.0)  # the last poses reach the recorder
    finally:
        assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"
    assert subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, timeout=60).returncode == 0

    from rerun.chunk import RrdReader

    entities = [str(e) for e in RrdReader(path).stream().collect().schema().entity_paths()]
    for robot in ("uarm", "dobot"):
        names = joint_units(path, f"/world/joints/{robot}") if f"/world/joints/{robot}" in entities else {}
        series = [joint_values(path, f"/world/joints/{robot}", j) for j in names]
        assert series, f"no joint series for {robot}"
        assert any(max(v) - min(v) > 0.1 for v in series if v), f"{robot}'s joints never moved"
        assert static_column(path, f"/world/robots/{robot}/tf_static", "Transform3D:child_frame")

    tracks = {f: [r["translation"] for r in rows] for f, rows in transforms_by_frame(path, "/world/poses").items()
              if f.startswith("world/bodies/")}
    cube, track = max(tracks.items(), key=lambda kv: _travel(kv[1]))

    def scene_point(x_mm: float, y_mm: float, z_mm: float) -> tuple[float, float, float]:  # real uArm frame
        return tuple(b + v / 1000 for b, v in zip(PLATFORM_UARM, (x_mm, y_mm, z_mm)))

    slots = [scene_point(LAYOUT.warehouse_x, y, 0.0)[:2] for y in LAYOUT.warehouse_slots_y]
    for end in (track[0], track[-1]):
        assert min(math.dist(end[:2], s) for s in slots) < 0.03, f"{cube} is not in a warehouse slot at {end}"
    grip = scene_point(192.0, LAYOUT.right_belt_y, 52.0)  # the end of the right belt, where the uArm grips
    assert min(math.dist(p, grip) for p in track) < 0.05, f"{cube} never reached the uArm"
    assert min(p[1] for p in track) < scene_point(0, LAYOUT.left_belt_y + 30, 0)[1], f"{cube} never rode the left belt"


def _travel(points: list) -> float:
    return sum(math.dist(a, b) for a, b in zip(points, points[1:]))


def test_an_obstacle_exists_from_when_it_was_added_until_it_was_removed(tmp_path):
    """The room is there for the whole recording; an obstacle only from the scene that adds it to the
    one that drops it: scrolling back shows the lab as it was."""
    import rerun as rr

    path = tmp_path / "obstacle.rrd"
    rec = rr.RecordingStream("obstacle")
    rec.save(str(path))
    table = Body("table", "box", (1.0, 1.0, 0.1), Pose((0.0, 0.0, 0.0)))
    box = Body("obstacle-1", "box", (0.2, 0.2, 0.2), Pose((0.3, 0.0, 0.2)))
    drawer = SceneDrawer(rec)
    for at, bodies in ((0.0, [table]), (2.0, [table, box]), (5.0, [table])):
        rec.set_time("sim_time", duration=at)
        assert drawer.draw_scene(SceneFiles(SceneDescription("lab", bodies=bodies), {}), time.time(), 0) == []
    drawer.flush()
    rec.disconnect()
    assert static_column(path, "/world/bodies/table", "Boxes3D:half_sizes")
    assert not static_column(path, "/world/bodies/obstacle-1", "Boxes3D:half_sizes")
    assert set(sim_times(path, "/world/bodies/obstacle-1")) == {2.0, 5.0}  # drawn at 2 s, cleared at 5 s


def test_a_lamp_shade_shows_its_lights_colour_the_moment_the_state_changes(tmp_path):
    """A body that shows a light (Body.shows) takes the light's colour from the world's state while it
    is on and its own while off; each change is logged with the poses that carry it, not when the
    scene is next redrawn."""
    import rerun as rr

    path = tmp_path / "lamp.rrd"
    rec = rr.RecordingStream("lamp")
    rec.save(str(path))
    shade = Body("light-left-shade", "box", (0.12, 0.12, 0.06), Pose((0.0, 1.6, 1.08)), (0.35, 0.35, 0.35),
                 shows="light-left")
    drawer = SceneDrawer(rec)
    rec.set_time("seq", sequence=0)
    assert drawer.draw_scene(SceneFiles(SceneDescription("lab", bodies=[shade]), {}), time.time(), 0) == []
    states = [{"on": False, "color": [1.0, 1.0, 1.0]}, {"on": True, "color": [1.0, 1.0, 1.0]},
              {"on": True, "color": [1.0, 0.0, 0.0]}, {"on": True, "color": [1.0, 0.0, 0.0]},
              {"on": False, "color": [1.0, 0.0, 0.0]}]
    for i, state in enumerate(states, start=1):
        rec.set_time("seq", sequence=i)
        for entry in drawer.add_poses(Poses(time=0.1 * i, states={"light-left": state}), time.time(), i):
            rec.log(entry.path, entry.archetype, static=entry.static)
    drawer.flush()
    rec.disconnect()
    colours = [rgb(c[0]) for c in read_column(path, "/world/bodies/light-left-shade", "Boxes3D:colors")]
    assert colours == [(89, 89, 89), (255, 255, 255), (255, 0, 0), (89, 89, 89)]  # off, white, red, off
    assert not static_column(path, "/world/bodies/light-left-shade", "Boxes3D:colors")  # would shadow them
    assert static_column(path, "/world/bodies/light-left-shade", "Boxes3D:half_sizes")


def rgb(packed: int) -> tuple[int, int, int]:
    return packed >> 24, (packed >> 16) & 0xFF, (packed >> 8) & 0xFF
