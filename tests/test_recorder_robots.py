"""The recorder draws every robot Thing: from its URDF, animated by its joint values, with its workspace.

The first recording comes from a synthetic UR10 Thing served by this test on a real lab's mesh: a
TD linking twin.json, the URDF, the points CSV and the hull STL, joint values published for a known
sequence, then the TD re-published with a regenerated workspace. Then the drawer alone, for a robot
that is also in the world's scene; last, once `twinmesh robot` exists, a real UR10 Thing end to end.
"""
import importlib.util
import json
import math
import subprocess
import time
from pathlib import Path

import msgspec
import numpy as np
import pytest
from labs import REPO, start_lab, stop_process
from rerun_view import frame_transforms, joint_values, shared_frames
from rerun_view import joint_units as series_units

from mesh.fabric.settings import MeshSettings
from mesh.messages.relations import MODEL, POINTS, WORKSPACE
from mesh.messages.relations import TWIN as TWIN_REL
from mesh.messages.scene_description import Pose, RobotModel, SceneDescription, TwinDescription
from mesh.recorder.robots import DrawnWorkspace, RobotDrawer, RobotFiles, joint_units, link_file, to_twin_frame
from mesh.recorder.scene_drawer import SceneDrawer, SceneFiles, lab_blueprint
from mesh.wot.thing_description import DataSchema, Link, PropertyAffordance, ThingDescription
from recordings import RERUN, read_column, scalars, texts, wait_for_line

pytestmark = pytest.mark.lab

UR10_URDF = (REPO / "tdgen" / "robot" / "models" / "ur10.urdf").read_text()
JOINTS = ["shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint",
          "wrist_3_joint"]
BASE = Pose((0.8, -0.4, 0.1), (0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)))  # yawed 90°
TWIN = TwinDescription(robot="ur10", urdf="tdgen/robot/models/ur10.urdf", urdf_sha256="0" * 64, urdf_file="ur10.urdf",
                       base=BASE)
SWEEP_DEG = [round(1.5 * i, 3) for i in range(40)]  # shoulder_pan, deg
ELBOW_DEG = -30.0
FIRST = {j: 0.0 for j in JOINTS}
LINKS = [Link(href="files/twin.json", rel=TWIN_REL, type="application/json"),
         Link(href="files/ur10.urdf", rel=MODEL, type="application/xml"),
         Link(href="files/workspace.stl", rel=WORKSPACE, type="model/stl"),
         Link(href="files/points.csv", rel=POINTS, type="text/csv")]


def robot_td(links: list[Link] = LINKS) -> ThingDescription:
    def observable(unit: str, fields: list[str]) -> PropertyAffordance:
        return PropertyAffordance(type="object", readOnly=True, observable=True,
                                  properties={f: DataSchema(type="number", unit=unit) for f in fields})

    return ThingDescription(title="ur10", description="a synthetic UR10 Thing for the recorder's tests", links=links,
                            properties={"getJointposition": observable("qudt:DEG", JOINTS),
                                        "getCartesianposition": observable("qudt:MilliM", list("xyz"))})


def make_points(n: int, seed: int) -> tuple[bytes, np.ndarray, np.ndarray]:
    """A points CSV (mm, base frame): n random points, those below z = 100 mm colliding."""
    rng = np.random.default_rng(seed)
    xyz = np.round(rng.uniform([-900, -900, -200], [900, 900, 1200], (n, 3)), 3)
    colliding = xyz[:, 2] < 100
    q = np.round(rng.uniform(-180, 180, (n, len(JOINTS))), 3)
    lines = [",".join(["x", "y", "z", "collision", *JOINTS])]
    lines += [",".join([*(f"{v:.3f}" for v in p), str(int(c)), *(f"{v:.3f}" for v in qq)])
              for p, c, qq in zip(xyz, colliding, q)]
    return ("\n".join(lines) + "\n").encode(), xyz, colliding


def make_hull(xyz: np.ndarray) -> bytes:
    import trimesh

    return trimesh.convex.convex_hull(xyz).export(file_type="stl")


def stl_vertex_count(stl: bytes) -> int:
    import io

    import trimesh

    return len(trimesh.load_mesh(io.BytesIO(stl), file_type="stl").vertices)


POINTS_1, XYZ_1, COLLIDING_1 = make_points(300, seed=1)
POINTS_2, XYZ_2, COLLIDING_2 = make_points(120, seed=2)
HULL_1 = make_hull(XYZ_1[~COLLIDING_1])


TIP_MM = [[600.0, -200.0, 400.0], [620.0, -150.0, 450.0], [640.0, -100.0, 500.0]]
MOVE_CALL = {"input": {"x": 640, "y": -100, "z": 500}, "status": 200, "seconds": 0.5,  # as the runtime publishes it
             "output": {"path": {"joints": JOINTS, "points": [[0.0] * 6, [1.0] * 6], "times": [0.0, 0.5],
                                 "tip": TIP_MM},
                        "reached": {"x": 640.0, "y": -100.0, "z": 500.0}, "error_mm": 0.0, "method": "straight",
                        "planning_ms": 3.0}}


def joint_sample(i: int) -> dict[str, float]:
    return {**FIRST, "shoulder_pan_joint": SWEEP_DEG[i], "elbow_joint": ELBOW_DEG}


@pytest.fixture(scope="module")
def recording(tmp_path_factory) -> Path:
    """Serve `ur10` here, record its sweep, regenerate its workspace (TD re-published), stop with Ctrl-C."""
    from mesh.fabric.server import ExposedThing
    from mesh.fabric.session import open_session

    tmp = tmp_path_factory.mktemp("rec-robots")
    lab = start_lab(tmp, "lights", http=False, things={"light-left"})
    path, log = tmp / "robots.rrd", tmp / "recorder.log"
    served = {"points.csv": POINTS_1}
    try:
        with open_session(MeshSettings(connect=(lab.endpoint,))) as session:
            robot = ExposedThing(session, robot_td(), "ur10").state("getJointposition", FIRST)
            robot.state("getCartesianposition", {"x": 0.0, "y": 0.0, "z": 0.0})
            robot.on_file("twin.json", lambda: msgspec.json.encode(TWIN), "application/json")
            robot.on_file("ur10.urdf", lambda: UR10_URDF.encode(), "application/xml")
            robot.on_file("points.csv", lambda: served["points.csv"], "text/csv")
            robot.on_file("workspace.stl", lambda: HULL_1, "model/stl")
            with robot:
                lab.wait_things({"ur10"})  # seen by the mesh before the recorder starts: its join is read first
                recorder = lab.spawn("record", str(path), log=log)
                wait_for_line(log, "recording to", recorder)
                for i in range(len(SWEEP_DEG)):
                    robot.set_value("getJointposition", joint_sample(i))
                    time.sleep(0.005)
                session.put("wot/ur10/actions/moveToCartesianPosition", msgspec.json.encode(MOVE_CALL))
                served["points.csv"] = POINTS_2  # the workspace regenerated: the robot says so with its TD
                robot.update_td(robot_td())
                time.sleep(1.5)  # the last samples and the new workspace reach the recorder
                assert stop_process(recorder), f"the recorder did not stop on Ctrl-C:\n{log.read_text()}"
        assert recorder.returncode == 0, log.read_text()
    finally:
        assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"
    return path


def static_values(path: Path, entity: str, component: str) -> list:
    """Every static value of an entity's component, oldest first (a static log replaces the one before)."""
    from rerun.chunk import RrdReader

    rows = []
    for chunk in RrdReader(path).stream().filter(content=entity, is_static=True):
        batch = chunk.to_record_batch()
        if chunk.entity_path == entity and component in batch.schema.names:
            rows += zip(batch.column("rerun.controls.RowId").to_pylist(), batch.column(component).to_pylist())
    return [v for _, v in sorted(rows, key=lambda r: r[0])]  # row ids grow with time


def latest(path: Path, entity: str, component: str):
    values = static_values(path, entity, component)
    assert values, f"nothing static at {entity} {component}"
    return values[-1]


def rgb(packed: int) -> tuple[int, int, int]:
    return packed >> 24, (packed >> 16) & 0xFF, (packed >> 8) & 0xFF


def test_robot_recording_verifies(recording):
    r = subprocess.run([RERUN, "rrd", "verify", str(recording)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_each_joint_is_a_series_in_rad_in_order(recording):
    pan = joint_values(recording, "/robots/ur10/joints", "shoulder_pan_joint")
    assert pan == pytest.approx([0.0] + [math.radians(d) for d in SWEEP_DEG])
    assert joint_values(recording, "/robots/ur10/joints", "elbow_joint") == pytest.approx(
        [0.0] + [math.radians(ELBOW_DEG)] * len(SWEEP_DEG))
    assert series_units(recording, "/robots/ur10/joints") == {j: "rad" for j in JOINTS}
    assert not scalars(recording, "/things/ur10/properties/getJointposition/shoulder_pan_joint")


def test_robot_is_drawn_from_its_urdf_at_its_base_in_its_own_world(recording):
    """A robot Thing of a lab without a world of its own: its own root, frame and link frames."""
    model = "/robots/ur10/model"
    assert latest(recording, model, "CoordinateFrame:frame") == ["robots/ur10/base_link"]
    assert latest(recording, f"{model}/base", "Transform3D:translation")[0] == pytest.approx(list(BASE.p))
    assert latest(recording, f"{model}/base", "Transform3D:quaternion")[0] == pytest.approx(list(BASE.q))
    assert latest(recording, f"{model}/base", "Transform3D:parent_frame") == ["tf#/robots/ur10"]
    assert latest(recording, f"{model}/base", "Transform3D:child_frame") == ["robots/ur10/base_link"]
    tf_static = static_values(recording, f"{model}/tf_static", "Transform3D:child_frame")
    assert {f[0] for f in tf_static} >= {"robots/ur10/shoulder_link", "robots/ur10/wrist_3_link", "robots/ur10/ee_link"}
    assert latest(recording, f"{model}/visual_geometries/upper_arm_link/visual_0", "Cylinders3D:fill_mode") == [3]


def test_joint_transforms_follow_the_sweep(recording):
    rows = frame_transforms(recording, "/robots/ur10/model/joints", "robots/ur10/shoulder_link")
    assert {r["parent_frame"] for r in rows} == {"robots/ur10/base_link"}
    quaternions = [r["quaternion"] for r in rows]
    angles = [2 * math.atan2(z, w) for _, _, z, w in quaternions]  # the URDF's axis is +z
    # the sweep starts where the pan is: a joint that did not move is not logged again (it holds)
    assert angles == pytest.approx([0.0] + [math.radians(d) for d in SWEEP_DEG[1:]], abs=1e-5)


def test_workspace_points_are_split_by_collision_and_coloured(recording):
    ws = "/robots/ur10/workspace/points"
    first_free = static_values(recording, f"{ws}/free", "Points3D:positions")[0]
    assert np.array(first_free) == pytest.approx(XYZ_1[~COLLIDING_1] / 1000, abs=1e-6)
    first_colliding = static_values(recording, f"{ws}/colliding", "Points3D:positions")[0]
    assert len(first_colliding) == COLLIDING_1.sum() > 0
    assert rgb(latest(recording, f"{ws}/free", "Points3D:colors")[0]) == (40, 180, 70)
    assert rgb(latest(recording, f"{ws}/colliding", "Points3D:colors")[0]) == (220, 50, 40)
    for part in ("free", "colliding"):
        assert latest(recording, f"{ws}/{part}", "CoordinateFrame:frame") == ["robots/ur10/base_link"]


def test_a_moves_swept_path_is_drawn_in_the_robots_base_frame(recording):
    strips = read_column(recording, "/robots/ur10/path", "LineStrips3D:strips")
    assert len(strips) == 1 and np.array(strips[0][0]) == pytest.approx(np.array(TIP_MM) / 1000, abs=1e-6)
    assert latest(recording, "/robots/ur10/path", "CoordinateFrame:frame") == ["robots/ur10/base_link"]


def test_hull_is_a_see_through_mesh_in_the_base_frame(recording):
    hull = "/robots/ur10/workspace/hull"
    vertices = latest(recording, hull, "Mesh3D:vertex_positions")
    assert len(vertices) == stl_vertex_count(HULL_1)
    assert np.abs(np.array(vertices)).max() == pytest.approx(np.abs(XYZ_1[~COLLIDING_1]).max() / 1000, rel=1e-6)
    assert latest(recording, hull, "Mesh3D:albedo_factor")[0] & 0xFF < 255  # alpha
    assert latest(recording, hull, "CoordinateFrame:frame") == ["robots/ur10/base_link"]


def test_a_republished_td_with_new_points_replaces_them(recording):
    ws = "/robots/ur10/workspace/points"
    assert len(latest(recording, f"{ws}/free", "Points3D:positions")) == (~COLLIDING_2).sum()
    assert len(latest(recording, f"{ws}/colliding", "Points3D:positions")) == COLLIDING_2.sum()
    lines = [t for t in texts(recording, "/robots/ur10/log") if t.startswith("workspace:")]
    assert [line.split(" points")[0] for line in lines] == ["workspace: 300", "workspace: 120"]


# --- the drawer alone ----------------------------------------------------------------------------
def _drawn(tmp_path: Path, draw) -> Path:
    import rerun as rr

    path = tmp_path / "drawer.rrd"
    rec = rr.RecordingStream("robot-drawer")
    rec.save(str(path))
    draw(rec)
    rec.flush()
    rec.disconnect()
    return path


def _workspace() -> DrawnWorkspace:
    return DrawnWorkspace.from_files("ur10", POINTS_1, HULL_1, TWIN)


def test_a_robot_in_the_worlds_scene_is_drawn_once_with_the_things_workspace(tmp_path):
    """The world's ur10 is the one drawn and animated; the Thing adds its joint series and workspace."""
    scene = SceneDescription("iot-lab", robots=[RobotModel("ur10", "ur10.urdf", Pose((2.0, 0.0, 0.0)))])

    def draw(rec):
        world = SceneDrawer(rec)
        robots = RobotDrawer(rec, world)
        assert world.draw_scene(SceneFiles(scene, {"ur10.urdf": UR10_URDF}), time.time(), 0) == []
        assert robots.draw_robot(RobotFiles("ur10", TWIN, UR10_URDF)) == []
        robots.draw_workspace(_workspace())
        robots.add_joints("ur10", joint_sample(3), time.time(), 1, None)
        robots.flush()

    path = _drawn(tmp_path, draw)
    assert not static_values(path, "/robots/ur10/model/base", "Transform3D:child_frame")
    assert latest(path, "/world/robots/ur10/base", "Transform3D:child_frame") == ["ur10/base_link"]
    assert latest(path, "/robots/ur10/workspace/hull", "CoordinateFrame:frame") == ["ur10/base_link"]
    assert joint_values(path, "/robots/ur10/joints", "shoulder_pan_joint") == pytest.approx([math.radians(SWEEP_DEG[3])])
    assert not read_column(path, "/robots/ur10/model/joints", "Transform3D:child_frame")


def test_a_world_that_takes_a_robot_over_clears_the_things_model(tmp_path):
    scene = SceneDescription("iot-lab", robots=[RobotModel("ur10", "ur10.urdf", Pose((2.0, 0.0, 0.0)))])

    def draw(rec):
        world = SceneDrawer(rec)
        robots = RobotDrawer(rec, world)
        assert robots.draw_robot(RobotFiles("ur10", TWIN, UR10_URDF)) == []
        assert robots.things["ur10"].robot is not None
        world.draw_scene(SceneFiles(scene, {"ur10.urdf": UR10_URDF}), time.time(), 0)
        assert robots.world_changed() == []
        assert robots.things["ur10"].robot is None and robots.things["ur10"].host == "ur10"

    path = _drawn(tmp_path, draw)
    assert latest(path, "/robots/ur10/model", "Clear:is_recursive") == [True]
    assert shared_frames(path) == {}  # its own model's frames are not the world's: Rerun takes both


OWN_SCENE = {"name": "table-and-wall", "bodies": [
    {"type": "urdf", "name": "table", "urdf": "pybullet_data:table/table.urdf", "scale": 0.8},
    {"type": "box", "name": "wall", "size": [2.0, 0.1, 1.6], "position": [0.0, 0.6, 0.8], "rgba": [0.8, 0.3, 0.2, 1.0]},
    {"type": "cylinder", "name": "bin", "radius": 0.1, "length": 0.3, "position": [0.5, -0.3, 0.775],
     "rpy": [0.0, 0.0, 90.0]}]}


def test_a_robot_simulated_apart_is_drawn_in_its_own_world_with_its_scene(tmp_path):
    """A robot Thing that is not one of the lab world's robots (joined with its own scene) stands in its
    own world: its own root and frame, its scene's bodies around it, its workspace in its base frame,
    its own tab; nothing of it in the lab's room."""
    lab = SceneDescription("iot-lab", robots=[RobotModel("ur10", "ur10.urdf", Pose((2.3, 0.0, 0.75)))])
    twin = msgspec.structs.replace(TWIN, robot="arm", base=Pose((0.0, 0.0, 0.625)), scene=OWN_SCENE)

    def draw(rec):
        world = SceneDrawer(rec)
        robots = RobotDrawer(rec, world)
        assert world.draw_scene(SceneFiles(lab, {"ur10.urdf": UR10_URDF}), time.time(), 0) == []
        assert robots.draw_robot(RobotFiles("arm", twin, UR10_URDF)) == []
        assert robots.world_changed() == []
        robots.draw_workspace(DrawnWorkspace.from_files("arm", POINTS_1, HULL_1, twin))
        assert robots.own_worlds() == {"arm": twin.base} and robots.bases() == {}

    path = _drawn(tmp_path, draw)
    assert latest(path, "/robots/arm/model/base", "Transform3D:parent_frame") == ["tf#/robots/arm"]
    assert latest(path, "/robots/arm/model/base", "Transform3D:child_frame") == ["robots/arm/base_link"]
    assert latest(path, "/robots/arm/workspace/hull", "CoordinateFrame:frame") == ["robots/arm/base_link"]
    assert latest(path, "/robots/arm/scene/wall", "Boxes3D:half_sizes") == [pytest.approx([1.0, 0.05, 0.8])]
    assert latest(path, "/robots/arm/scene/bin", "Cylinders3D:radii") == [pytest.approx(0.1)]
    assert latest(path, "/robots/arm/scene/table/base", "Transform3D:parent_frame") == ["tf#/robots/arm"]
    assert latest(path, "/robots/arm/scene/table/base", "Transform3D:scale") == [pytest.approx([0.8, 0.8, 0.8])]
    assert shared_frames(path) == {}


def test_a_robot_simulated_apart_gets_its_own_tab_outside_the_lab_view():
    import rerun.blueprint as rrb

    lab = SceneDescription("iot-lab", robots=[RobotModel("ur10", "ur10.urdf", Pose((2.3, 0.0, 0.75)))])
    blueprint = lab_blueprint(lab, ["ur10"], {"ur10": BASE}, {"arm": Pose((0.0, 0.0, 0.625))})
    tabs = blueprint.root_container.contents[0]
    assert isinstance(tabs, rrb.Tabs)
    room, workspaces, own = tabs.contents
    assert (room.name, workspaces.name, own.name) == ("iot-lab", "workspaces", "arm (own world)")
    assert str(own.origin) == "/robots/arm"
    assert not any("/robots/arm" in str(c) for c in _queries(room)), "the robot apart is in the room"
    assert any("/robots/ur10" in str(c) for c in _queries(room)), "the lab's UR10 Thing is not in the room"


def _queries(view) -> list:
    contents = view.contents
    return list(getattr(contents, "query", contents) or [])


def test_a_bad_urdf_is_reported_and_the_joints_still_recorded(tmp_path):
    def draw(rec):
        robots = RobotDrawer(rec, SceneDrawer(rec))
        problems = robots.draw_robot(RobotFiles("arm", TWIN, "<robot"))
        assert len(problems) == 1 and problems[0].startswith("cannot draw robot arm")
        robots.add_joints("arm", {"j1": 90.0}, time.time(), 0, None)
        lines = robots.draw_workspace(DrawnWorkspace.from_files("arm", POINTS_1, HULL_1, TWIN))
        assert "not placed" in lines[0].archetype.text.as_arrow_array().to_pylist()[0]
        robots.flush()

    path = _drawn(tmp_path, draw)
    assert joint_values(path, "/robots/arm/joints", "j1") == pytest.approx([math.pi / 2])


def test_units_come_from_the_td():
    td = ThingDescription(title="t", properties={"getJointposition": PropertyAffordance(
        type="object", properties={"a": DataSchema(type="number", unit="deg"),
                                   "b": DataSchema(type="number", unit="mm"),
                                   "c": DataSchema(type="number")})})
    assert joint_units(td) == {"a": (pytest.approx(math.pi / 180), "rad"), "b": (1e-3, "m")}


def test_link_files_are_found_whatever_the_href():
    td = ThingDescription(title="t", links=[Link(href="zenoh:wot/ur10/files/twin.json", rel=TWIN_REL),
                                            Link(href="http://lab:8080/things/ur10/files/points.csv?x=1",
                                                 rel=POINTS),
                                            Link(href="workspace.stl", rel=WORKSPACE)])
    assert [link_file(td, r) for r in (TWIN_REL, POINTS, WORKSPACE, MODEL)] == [
        "twin.json", "points.csv", "workspace.stl", None]


def test_a_real_frame_workspace_is_mapped_back_to_the_twin_frame():
    twin_points = np.array([[0, 0, 0], [100, 0, 0], [0, 200, 0], [0, 0, 300], [50, 60, 70]], dtype=float)
    real = twin_points * [1.1, 0.9, 1.0] + [5.0, -3.0, 12.0]
    real_twin = msgspec.structs.replace(TWIN, frame="real",
                                        calibration=np.column_stack([twin_points, real]).tolist())
    assert to_twin_frame(real, real_twin) == pytest.approx(twin_points, abs=1e-9)  # affine
    per_axis = msgspec.structs.replace(real_twin, calibration=real_twin.calibration[1:4])
    assert to_twin_frame(real, per_axis) == pytest.approx(twin_points, abs=1e-9)


def test_the_blueprint_hides_workspaces_in_the_lab_view_and_shows_them_in_their_own():
    import rerun.blueprint as rrb

    blueprint = lab_blueprint(None, [], {"ur10": BASE})
    tabs = blueprint.root_container.contents[0]
    lab, workspaces = tabs.contents
    assert isinstance(lab.visualizer_overrides["/robots/ur10/workspace"], rrb.EntityBehavior)
    assert workspaces.name == "workspaces" and not workspaces.visualizer_overrides


# --- a real robot Thing --------------------------------------------------------------------------
def _robot_missing() -> str | None:
    if importlib.util.find_spec("devices.things.robot_thing") is None:
        return "`twinmesh robot` not written yet: no devices/things/robot_thing.py"
    return None


@pytest.mark.skipif(_robot_missing() is not None, reason=str(_robot_missing()))
def test_a_ur10_thing_is_recorded_with_its_trajectory_and_workspace(tmp_path):
    lab = start_lab(tmp_path, "lights", http=False, things={"light-left"},
                    extra_args=("--tdgen-cache", str(tmp_path / "tdgen-cache")))
    path, log = tmp_path / "ur10.rrd", tmp_path / "recorder.log"
    try:
        recorder = lab.spawn("record", str(path), log=log)
        wait_for_line(log, "recording to", recorder)
        lab.spawn("robot", str(REPO / "tdgen" / "robot" / "models" / "ur10.urdf"), "--name", "ur10", "--samples", "3000",
                  "--speed", "max", log=tmp_path / "robot.log")
        lab.wait_things({"ur10"}, timeout=120)
        td = _wait_workspace(lab, "ur10", timeout=300)
        target = _safe_target(lab, td)
        r = lab.cli("invoke", "ur10", "moveToCartesianPosition", json.dumps(target), timeout=300)
        assert r.returncode == 0, r.stdout + r.stderr
        time.sleep(1.5)  # the last joint values reach the recorder
        assert stop_process(recorder), f"the recorder did not stop on Ctrl-C:\n{log.read_text()}"
    finally:
        assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"
    assert subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, timeout=60).returncode == 0
    series = [joint_values(path, "/robots/ur10/joints", j) for j in JOINTS]
    assert all(series), "a UR10 joint has no series"
    assert any(max(s) - min(s) > 0.01 for s in series), "the UR10 never moved"
    assert frame_transforms(path, "/robots/ur10/model/joints", "robots/ur10/shoulder_link")
    free = latest(path, "/robots/ur10/workspace/points/free", "Points3D:positions")
    colliding = static_values(path, "/robots/ur10/workspace/points/colliding", "Points3D:positions")[-1]
    assert len(free) + len(colliding) == 3000
    assert latest(path, "/robots/ur10/workspace/hull", "Mesh3D:vertex_positions")
    (swept,) = read_column(path, "/robots/ur10/path", "LineStrips3D:strips")  # the move's path, from its answer
    assert np.array(swept[0])[-1] * 1000 == pytest.approx([target[a] for a in "xyz"], abs=0.01)


def _wait_workspace(lab, thing: str, timeout: float) -> dict:
    """The robot's TD once it links its workspace (generated on the mesh after the robot starts)."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        r = lab.cli("td", thing, timeout=30)
        if r.returncode == 0:
            td = json.loads(r.stdout)
            if {WORKSPACE, POINTS} <= {link.get("rel") for link in td.get("links", [])}:
                return td
        time.sleep(1.0)
    raise AssertionError(f"{thing}'s TD never linked its workspace within {timeout} s\n{lab.log.read_text()[-3000:]}")


def _safe_target(lab, td: dict) -> dict[str, float]:
    """A collision-free sampled point whose ten nearest samples are free too, near the free points' middle."""
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.session import open_session
    from mesh.recorder.robots import read_points
    from mesh.wot.problem import Unavailable
    from mesh.wot.thing_description import decode_td

    settings = MeshSettings(connect=(lab.endpoint,))
    with open_session(settings) as session:
        client, deadline = MeshClient(session, settings), time.monotonic() + 20
        while True:  # a new session may not route to the robot at once
            try:
                csv = client.file("ur10", link_file(decode_td(td), POINTS)).payload
                break
            except Unavailable:
                if time.monotonic() > deadline:
                    raise
                time.sleep(0.2)
    from scipy.spatial import cKDTree

    xyz, colliding = read_points(csv)
    nearest = cKDTree(xyz).query(xyz, k=11)[1][:, 1:]
    safe = np.flatnonzero(~colliding & ~colliding[nearest].any(axis=1))
    assert len(safe), "no sampled point is surrounded by free ones"
    middle = xyz[~colliding].mean(axis=0)
    best = xyz[safe[np.argmin(np.linalg.norm(xyz[safe] - middle, axis=1))]]
    return {a: round(float(v), 1) for a, v in zip("xyz", best)}


def test_a_mesh_based_urdf_is_drawn_with_its_meshes(tmp_path):
    """The Panda's links are meshes (`package://meshes/...`): the recorder resolves them against the
    URDF's own folder, as pybullet does, so the recording holds a mesh per link, not only frames."""
    import pybullet_data
    from rerun.chunk import RrdReader

    from mesh.recorder.scene_drawer import DrawnRobot

    urdf = Path(pybullet_data.getDataPath()) / "franka_panda" / "panda.urdf"
    robot = DrawnRobot.load("panda", urdf.read_text(), "world/robots/panda", urdf.parent)
    assert robot.missing == []
    path = _drawn(tmp_path, lambda rec: robot.draw(rec, Pose((0.0, 0.0, 0.0))))
    meshes = {}  # entity -> bytes of the mesh file recorded there
    for chunk in RrdReader(path).stream().filter(content="/world/robots/panda/**", is_static=True):
        batch = chunk.to_record_batch()
        if "Asset3D:blob" in batch.schema.names:
            blobs = [b for b in batch.column("Asset3D:blob").to_pylist() if b]
            meshes[chunk.entity_path] = sum(len(bytes(b[0])) for b in blobs)
    links = {"panda_link0", "panda_link1", "panda_link2", "panda_link3", "panda_link4", "panda_link5", "panda_link6",
             "panda_link7", "panda_hand", "panda_leftfinger", "panda_rightfinger"}
    drawn = {link for link in links for entity, size in meshes.items() if f"/{link}/" in entity and size > 1000}
    assert drawn == links, meshes


def test_a_mesh_that_cannot_be_found_is_named_with_where_it_was_looked_for(tmp_path):
    from mesh.recorder.scene_drawer import DrawnRobot

    urdf = ('<robot name="r"><link name="base"><visual><geometry><mesh filename="package://arm/meshes/base.stl"/>'
            '</geometry></visual></link></robot>')
    robot = DrawnRobot.load("r", urdf, "world/robots/r", tmp_path)
    assert robot.missing and robot.missing[0].startswith("mesh package://arm/meshes/base.stl not found (looked in ")
    assert str(tmp_path / "arm" / "meshes" / "base.stl") in robot.missing[0]
