"""The generic robot twin in-process: checked moves in a real World, the tdgen service's cache, and a
scene change regenerating the workspace on a real (in-process) mesh."""
from __future__ import annotations

import queue
import time
from contextlib import ExitStack

import msgspec
import numpy as np
import pytest
from labs import free_port
from scipy.spatial.transform import Rotation
from tdschema import assert_valid_td
from waiting import eventually

from devices.planning.moves import TdFrame
from devices.sim.pybullet_world import World
from devices.sim.robot_twin import Base, RobotTwin, workspace_from_csv
from devices.things.robot_thing import RobotThing, provisional_td
from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from mesh.messages.relations import MODEL, POINTS, SCENE, TWIN, WORKSPACE
from mesh.wot.problem import Problem
from mesh.wot.thing_description import decode_td
from tdgen.cache import cache_key as twin_hash
from tdgen.generate import generate
from tdgen.robot.calibration import fit_calibration
from tdgen.robot.surroundings import BoxBody, build_into
from tdgen.service import TdgenService

SAMPLES = 4000


@pytest.fixture(scope="module")
def generated(ur10, scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("ur10")
    generate(ur10, scene, SAMPLES, 0, out, workers=1)
    return workspace_from_csv((out / "points.csv").read_bytes())


@pytest.fixture
def world(scene):
    w = World(speed=None)
    build_into(scene, w.client)
    w.start()
    yield w
    w.close()


@pytest.fixture
def twin(world, ur10, scene):
    t = RobotTwin(world, ur10, "ur10", Base(tuple(scene.robot.position)), scene)
    yield t
    t.close()


def safe_targets(workspace, twin: RobotTwin, n: int, seed: int = 0) -> np.ndarray:
    """Collision-free sampled points the check accepts with no colliding neighbour, well inside the hull."""
    free = workspace.positions[~workspace.collision]
    out = []
    for p in free[np.random.default_rng(seed).permutation(len(free))]:
        c = workspace.check(p, twin.planner.k, twin.planner.radius_mm, 0.5)
        if c.ok and c.collision_probability == 0 and c.margin_mm > 50:
            out.append(p)
            if len(out) == n:
                break
    return np.array(out)


def test_cartesian_moves_are_refused_with_503_until_the_workspace_is_known(twin):
    td = msgspec.to_builtins(provisional_td(twin))
    assert_valid_td(td)
    assert all("minimum" not in axis for axis in td["properties"]["getCartesianposition"]["properties"].values())
    assert {link["rel"] for link in td["links"]} == {TWIN, MODEL}
    before = twin.joint_position()
    with pytest.raises(Problem) as err:
        twin.move_to_cartesian((500, 0, 500))
    assert err.value.status == 503 and err.value.reason == "workspace-generating"
    assert twin.joint_position() == before


def test_a_reachable_target_is_reached_within_a_hundredth_of_a_millimetre(twin, generated):
    twin.set_workspace(generated)
    for target in safe_targets(generated, twin, 3):
        result = twin.move_to_cartesian(target)
        reached = twin.cartesian_position()
        assert result.error_mm <= 0.01
        assert np.linalg.norm(np.array([reached[a] for a in "xyz"]) - target) <= 0.01


def _tip_pose(twin: RobotTwin) -> tuple[np.ndarray, Rotation]:
    """The tip's pose in the base frame (mm) as pybullet places the twin's own arm in its world."""
    position, quaternion = twin.arm.link_pose(twin.robot.ee_link)
    base = Rotation.from_quat(twin.base.quaternion)
    return base.inv().apply(np.array(position) - twin.base.position) * 1000.0, base.inv() * Rotation.from_quat(quaternion)


def test_a_pose_target_is_reached_within_a_hundredth_of_a_mm_and_of_a_degree(twin, generated):
    twin.set_workspace(generated)
    a, b = safe_targets(generated, twin, 2, seed=3)
    twin.move_to_cartesian(a)
    position, orientation = _tip_pose(twin)  # a pose the arm can take, with the orientation IK chose there
    twin.move_to_cartesian(b)
    rpy = orientation.as_euler("xyz", degrees=True)
    answer = twin.move_to_pose(position, rpy).answer(twin)
    reached, now = _tip_pose(twin)
    assert np.linalg.norm(reached - position) <= 0.01
    assert np.degrees((now * orientation.inv()).magnitude()) <= 0.01
    assert answer["error_mm"] <= 0.01 and answer["error_deg"] <= 0.01
    assert set(answer["orientation"]) == {"roll", "pitch", "yaw"}
    before = twin.joint_position()
    with pytest.raises(Problem) as err:
        twin.move_to_pose((0, 0, 3000), (0, 0, 0))
    assert err.value.status == 422 and err.value.reason == "unreachable" and err.value.extra["error_mm"] > 1000
    with pytest.raises(Problem) as err:
        twin.move_to_pose(position, (0, 0, 0, 0))  # a quaternion of length 0
    assert err.value.status == 400
    assert twin.joint_position() == before


def _in_wall(generated) -> tuple[int, int, int]:
    """A point inside the wall (y 550..650 mm) that the hull contains and samples surround."""
    return next(p for p in ((x, 600, z) for x in range(-400, 401, 50) for z in range(500, 951, 50))
                if generated.check(p).inside and generated.check(p).neighbours)


def test_refused_moves_name_their_reason_and_nothing_moves(twin, generated):
    twin.set_workspace(generated)
    before = twin.joint_position()
    cases = {"outside-workspace": (0, 0, 3000), "collision": _in_wall(generated)}
    for reason, target in cases.items():
        with pytest.raises(Problem) as err:
            twin.move_to_cartesian(target)
        assert err.value.status == 422 and err.value.reason == reason, err.value
    assert err.value.extra["collision_probability"] > 0.5  # information, in every answer
    assert any("wall" in pair for pair in err.value.extra["collisions"]), err.value.extra
    assert twin.joint_position() == before


def test_the_neighbour_collision_probability_gates_a_move_only_when_asked(world, ur10, scene, generated):
    gated = RobotTwin(world, ur10, "ur10-gated", Base(tuple(scene.robot.position)), scene,
                      max_collision_probability=0.5)
    try:
        gated.set_workspace(generated)
        with pytest.raises(Problem) as err:
            gated.move_to_cartesian(_in_wall(generated))
        assert err.value.status == 422 and err.value.reason == "collision-risk"  # the thesis's check
        assert err.value.extra["max_collision_probability"] == 0.5
    finally:
        gated.close()


def test_a_joint_move_into_the_table_is_refused(twin):
    before = twin.joint_position()
    into_table = {**before, "shoulder_lift_joint": 90.0}  # the arm straight down through the table top
    with pytest.raises(Problem) as err:
        twin.move_to_joints(into_table)
    assert err.value.status == 422 and err.value.reason == "collision"
    assert "table" in err.value.detail
    assert twin.joint_position() == before


def test_moves_keep_every_joint_within_its_velocity_limit_in_simulated_time(twin, world, ur10):
    samples: list[tuple[float, np.ndarray]] = []
    twin.on_state(lambda: samples.append((world.time, twin.q.copy())))
    goal = {"shoulder_pan_joint": 90.0, "shoulder_lift_joint": -60.0, "elbow_joint": 45.0,
            "wrist_1_joint": 0.0, "wrist_2_joint": 30.0, "wrist_3_joint": 0.0}
    expected = twin.motion_duration(ur10.from_user_units([goal[j.name] for j in ur10.joints]))
    twin.move_to_joints(goal)
    times = np.array([t for t, _ in samples])
    assert times[-1] - times[0] + world.dt == pytest.approx(expected, abs=2 * world.dt)  # one sample per step
    q = np.array([q for _, q in samples])
    speed = np.abs(np.diff(q, axis=0)) / np.diff(times)[:, None]
    ratio = speed.max(axis=0) / np.array([j.max_velocity for j in ur10.joints])
    assert (ratio <= 1.001).all() and ratio.max() > 0.95  # the joint with the longest way sets the pace
    assert twin.joint_position() == pytest.approx(goal, abs=1e-6)


def test_a_calibrated_twin_reports_checks_and_moves_in_the_real_frame(world, ur10, scene, tmp_path):
    a = np.diag([1.02, 0.98, 1.01])
    t = np.array([12.0, -30.0, 5.0])
    twin_pts = np.random.default_rng(3).uniform(-800, 800, (8, 3))
    cal = fit_calibration(twin_pts, twin_pts @ a.T + t)
    generate(ur10, scene, SAMPLES, 0, tmp_path, calibration=cal, frame="real", workers=1)
    robot = RobotTwin(world, ur10, "ur10-real", Base(tuple(scene.robot.position)), scene, calibration=cal)
    try:
        base_frame = robot.fk.positions(robot.q) * 1000
        now = robot.cartesian_position()
        assert [now[k] for k in "xyz"] == pytest.approx(base_frame @ a.T + t, abs=1e-3)
        frame = TdFrame(cal)
        assert frame.to_base(frame.from_base(base_frame)) == pytest.approx(base_frame)
        workspace = workspace_from_csv((tmp_path / "points.csv").read_bytes())
        robot.set_workspace(workspace)
        target = safe_targets(workspace, robot, 1)[0]
        robot.move_to_cartesian(target)
        reached = robot.cartesian_position()
        assert np.linalg.norm(np.array([reached[k] for k in "xyz"]) - target) <= 0.01
        assert robot.description("ur10.urdf", "x", "ur10.urdf", SAMPLES).frame == "real"
    finally:
        robot.close()


def test_the_generation_cache_key_covers_every_input(twin):
    d = twin.description("ur10.urdf", "abc", "ur10.urdf", SAMPLES)
    assert twin_hash(d) == twin_hash(msgspec.structs.replace(d, version=7))  # the version is no input
    for change in ({"samples": SAMPLES + 1}, {"seed": 1}, {"urdf_sha256": "abd"}, {"ee": "wrist_3_link"},
                   {"scene": {**d.scene, "bodies": []}}, {"robot": "ur10-b"}, {"frame": "real"},
                   {"calibration": [[0, 0, 0, 1, 1, 1]]}):
        assert twin_hash(msgspec.structs.replace(d, **change)) != twin_hash(d), change



CACHED_TD = """
import json, sys
from pathlib import Path
import msgspec
from mesh.messages.scene_description import TwinDescription
from tdgen.cache import ArtefactCache
from tdgen.artefacts import artefact_key, make_artefacts
twin = msgspec.json.decode(Path(sys.argv[1]).read_bytes(), type=TwinDescription)
cache = ArtefactCache(Path(sys.argv[2]))
key = artefact_key(twin)
cached = cache.has(key)
if not cached:
    make_artefacts(twin, cache, key, workers=1)
td = json.loads((cache.entry(key) / "td.json").read_text())
print(json.dumps({"key": key, "cached": cached, "description": td["description"]}))
"""


@pytest.mark.lab  # three processes and a copy of the code
def test_a_cached_td_is_used_only_while_the_code_that_made_it_is_the_same(tmp_path):
    """The tdgen cache key is derived, never bumped by hand: the same twin twice is one generation,
    and an edit to the TD-building code (here, its description) gives a fresh TD, not the cached one."""
    import hashlib
    import json
    import os
    import shutil
    import subprocess
    import sys
    from pathlib import Path

    from compiling import compiling_elsewhere
    from labs import REPO

    from mesh.messages.scene_description import Pose, TwinDescription

    urdf = REPO / "tdgen" / "robot" / "models" / "ur10.urdf"
    twin = TwinDescription(robot="ur10", urdf=str(urdf), urdf_sha256=hashlib.sha256(urdf.read_bytes()).hexdigest(),
                           base=Pose((0.0, 0.0, 0.0)), samples=400, seed=0)
    (tmp_path / "twin.json").write_bytes(msgspec.json.encode(twin))
    edited = tmp_path / "edited"
    for package in ("mesh", "tdgen"):
        shutil.copytree(REPO / package, edited / package, ignore=shutil.ignore_patterns("__pycache__"))
    generate_py = edited / "tdgen" / "generate.py"
    text = generate_py.read_text()
    assert "generated by twinmesh tdgen" in text
    generate_py.write_text(text.replace("generated by twinmesh tdgen", "generated by an edited twinmesh tdgen"))

    def run(code: Path, uncompiled: dict[str, str] | None = None) -> dict:
        env = {**os.environ, "PYTHONPATH": str(code), **(uncompiled or {})}
        done = subprocess.run([sys.executable, "-c", CACHED_TD, str(tmp_path / "twin.json"), str(tmp_path / "cache")],
                              capture_output=True, text=True, env=env, cwd=tmp_path, timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        return json.loads(done.stdout.splitlines()[-1])

    first, again = run(REPO), run(REPO)
    assert not first["cached"] and again["cached"] and again["key"] == first["key"]
    with compiling_elsewhere(tmp_path / "numba") as uncompiled:  # uncompiled, whatever was compiled: not the point
        fresh = run(edited, uncompiled)
    assert not fresh["cached"] and fresh["key"] != first["key"]
    assert "an edited twinmesh tdgen" in fresh["description"] and "an edited" not in first["description"]

# --- on a mesh -------------------------------------------------------------------------------------
@pytest.fixture
def mesh():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = MeshSettings(connect=(endpoint,))
    with open_session(settings.as_router()):
        yield settings


def _wait(q: queue.Queue, accept, timeout: float = 60.0):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        try:
            item = q.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            break
        if accept(item):
            return item
    raise AssertionError(f"nothing accepted within {timeout} s")


def test_a_new_obstacle_regenerates_a_smaller_workspace_and_td_observers_see_it(mesh, twin, tmp_path):
    """set_scene -> twinChanged -> the service regenerates -> the robot serves the new TD and checks with it."""
    tds: queue.Queue = queue.Queue()
    with ExitStack() as stack:
        observer = stack.enter_context(open_session(mesh))
        stack.enter_context(TdgenService(stack.enter_context(open_session(mesh)), mesh, tmp_path / "cache", 1))
        observer.declare_subscriber(mesh.keys.td("ur10"), lambda s: tds.put(decode_td(s.payload.to_bytes())))
        progress: list[tuple[int, float]] = []  # (twin version, fraction) as the service publishes them
        observer.declare_subscriber(mesh.keys.property("tdgen", "robots"), lambda s: progress.extend(
            (r["version"], r["progress"]) for r in [msgspec.json.decode(s.payload.to_bytes()).get("ur10", {})]
            if "progress" in r))
        thing = stack.enter_context(RobotThing(stack.enter_context(open_session(mesh)), mesh, twin, samples=SAMPLES))
        client = MeshClient(observer, mesh)

        first = _wait(tds, lambda td: td.version is not None)
        assert first.version == {"instance": "0"}
        assert_valid_td(msgspec.to_builtins(first))
        points_before = workspace_from_csv(client.file("ur10", "points.csv").payload)
        hash_before = twin.workspace_hash
        target = safe_targets(points_before, twin, 1)[0]  # the box will stand right there

        box = BoxBody(name="box", size=(0.3, 0.3, 0.3), position=tuple(target / 1000 + np.array([0, 0, 0.625])))
        assert twin.set_scene(msgspec.structs.replace(twin.scene, bodies=[*twin.scene.bodies, box])) == 1
        assert msgspec.json.decode(client.file("ur10", "twin.json").payload)["version"] == 1

        second = _wait(tds, lambda td: td.version == {"instance": "1"})
        served = client.file("tdgen", "ur10.points.csv").payload  # a live update's: from memory, on disk later
        points_after = workspace_from_csv(client.file("ur10", "points.csv").payload)
        assert (~points_after.collision).sum() < (~points_before.collision).sum()
        assert twin.workspace_hash != hash_before
        assert "box" in client.file("ur10", "scene.json").payload.decode()
        robots = client.read("tdgen", "robots")
        assert robots["ur10"]["status"] == "ready" and robots["ur10"]["version"] == 1
        regenerating = [f for version, f in progress if version == 1]  # the service shows how far it is
        assert regenerating[0] == 0.0 and regenerating[-1] == 1.0 and regenerating == sorted(regenerating), progress
        assert "progress" not in robots["ur10"], "a finished generation has no progress figure"
        assert robots["ur10"]["hash"] == twin.workspace_hash and robots["ur10"]["cached"] is False
        assert robots["ur10"].get("live") is True  # only the box checked: the samples kept from the generation
        with pytest.raises(Problem) as err:  # where the box now stands
            client.invoke("ur10", "moveToCartesianPosition", dict(zip("xyz", target.tolist())))
        assert err.value.status == 422 and err.value.reason in ("collision", "no-path", "outside-workspace")
        assert {(link.rel, link.href) for link in second.links} >= {
            (WORKSPACE, "files/workspace.stl"), (POINTS, "files/points.csv"),
            (SCENE, "files/scene.json"), (TWIN, "files/twin.json"), (MODEL, "files/ur10.urdf")}
        assert thing.thing.td == second or thing.thing.td.version == second.version
        entry = tmp_path / "cache" / twin.workspace_hash
    # the service has stopped: what it served is in its cache, whole, for the next start
    assert (entry / "points.csv").read_bytes() == served
    assert workspace_from_csv(served).collision.tolist() == points_after.collision.tolist()
    assert {p.name for p in entry.iterdir()} >= {"done", "td.json", "twin.json", "workspace.stl", "scene.json"}


def test_a_robot_slow_to_give_its_twin_at_first_still_gets_its_td(mesh, twin, tmp_path):
    """A robot that just started may not answer for seconds (on a fresh machine it compiles its loops): the
    service asked for its twin file once, timed out and gave up, and the robot never got a TD (a zoo
    robot in a fresh clone's run waited for it until the test's time was up)."""
    patient = msgspec.structs.replace(mesh, query_timeout=1.0)
    tds: queue.Queue = queue.Queue()
    with ExitStack() as stack:
        observer = stack.enter_context(open_session(mesh))
        observer.declare_subscriber(mesh.keys.td("ur10"), lambda s: tds.put(decode_td(s.payload.to_bytes())))
        thing = RobotThing(stack.enter_context(open_session(mesh)), mesh, twin, samples=SAMPLES)
        source, media = thing._files["twin.json"]
        asked: list[float] = []

        def slow_at_first() -> bytes:
            asked.append(time.monotonic())
            if len(asked) == 1:
                time.sleep(1.5)  # longer than the service's query timeout
            return source()

        thing._files["twin.json"] = (slow_at_first, media)
        stack.enter_context(thing)
        stack.enter_context(TdgenService(stack.enter_context(open_session(patient)), patient, tmp_path / "cache", 1))
        generated = _wait(tds, lambda td: td.version == {"instance": "0"} and any(
            link.rel == WORKSPACE for link in td.links))
        assert len(asked) >= 2, "the service never asked again"
        assert generated.version == {"instance": "0"}


def test_a_failed_generation_is_reported_and_explains_the_refusals(mesh, twin, tmp_path):
    with ExitStack() as stack:
        service = stack.enter_context(TdgenService(stack.enter_context(open_session(mesh)), mesh, tmp_path, 1))
        # the URDF the service would find is not the robot's: it must not generate from it
        stack.enter_context(RobotThing(stack.enter_context(open_session(mesh)), mesh, twin,
                                       urdf="kuka_iiwa/model.urdf", samples=SAMPLES))
        eventually(lambda: twin.workspace_error is not None, timeout=60, what="the twin told of the failed generation")
        assert service.robots()["ur10"]["status"] == "failed", service.robots()
        assert "differs" in service.robots()["ur10"]["error"] and "differs" in twin.workspace_error
        with pytest.raises(Problem) as err:
            twin.move_to_cartesian((500, 0, 500))
        assert err.value.status == 503 and err.value.reason == "workspace-failed"


def test_the_ur10_scene_runs_the_generic_robot_at_the_lab_speed():
    from devices.lab import entries
    from devices.lab.scenes import LabOptions, scene_specs
    from devices.things.robot_setup import RobotSetup

    (spec,) = scene_specs("ur10", LabOptions(speed=None, samples=5000))
    assert spec.kwargs["setup"] == RobotSetup(urdf="ur10.urdf", name="ur10", scene="table-and-wall", speed=None,
                                              samples=5000)
    assert spec.target is entries.robot
    (lab,) = scene_specs("iot-lab", LabOptions(speed=2.0))
    assert (lab.kwargs["speed"], lab.kwargs["samples"]) == (2.0, 80_000) and lab.target is entries.iot_lab


def test_a_calibrated_robot_gets_its_td_checks_and_moves_in_the_real_frame_from_the_service(mesh, world, ur10, scene,
                                                                                           tmp_path):
    a, t = np.diag([1.02, 0.98, 1.01]), np.array([12.0, -30.0, 5.0])
    pairs = np.random.default_rng(3).uniform(-800, 800, (8, 3))
    robot = RobotTwin(world, ur10, "ur10-real", Base(tuple(scene.robot.position)), scene,
                      calibration=fit_calibration(pairs, pairs @ a.T + t))
    tds: queue.Queue = queue.Queue()
    with ExitStack() as stack:
        stack.callback(robot.close)
        observer = stack.enter_context(open_session(mesh))
        observer.declare_subscriber(mesh.keys.td("ur10-real"), lambda s: tds.put(decode_td(s.payload.to_bytes())))
        stack.enter_context(TdgenService(stack.enter_context(open_session(mesh)), mesh, tmp_path, 1))
        stack.enter_context(RobotThing(stack.enter_context(open_session(mesh)), mesh, robot, samples=SAMPLES))
        td = _wait(tds, lambda td: td.version is not None)
        client = MeshClient(observer, mesh)
        points = workspace_from_csv(client.file("ur10-real", "points.csv").payload)
        free = points.positions[~points.collision]
        bounds = td.properties["getCartesianposition"].properties
        assert [bounds[k].minimum for k in "xyz"] == pytest.approx(free.min(axis=0), abs=1e-3)
        assert "real robot's frame" in td.description
        base_frame = robot.fk.positions(robot.q) * 1000
        assert [client.read("ur10-real", "getCartesianposition")[k] for k in "xyz"] == \
            pytest.approx(base_frame @ a.T + t, abs=1e-3)
        target = safe_targets(points, robot, 1)[0]
        client.invoke("ur10-real", "moveToCartesianPosition", dict(zip("xyz", target.tolist())))
        reached = client.read("ur10-real", "getCartesianposition")
        assert np.linalg.norm(np.array([reached[k] for k in "xyz"]) - target) <= 0.01
