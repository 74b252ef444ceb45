"""Arms nobody here picked: the `example-robot-data` package's robots, an arm of KIT's ARMAR-4 humanoid
(the `armar` package), one of IIT's iCub (`icub-models`, a Gazebo model set whose 213 links are more
than a pybullet body holds) and Hello Robot's Stretch (`hello-robot-stretch-urdf`, a telescoping arm),
as a researcher would drop them in.

For each arm of the zoo (6- and 7-DoF arms, a 5-DoF arm with a jaw, grippers with mimic joints,
unlimited joints, two-arm robots, mobile manipulators, an arm on a quadruped, a lift with nested
tubes): the chain chosen (base and tip link, joint count), the TD generated with its chain named, a
watertight hull, and 200 reachable targets (FK of random configurations) solved by our IK and
checked by pybullet's own forward kinematics within 0.01 mm. Every arm joins a running lab, gets its
TD and moves there. The packages are test extras; without them the module is skipped (in CI it
fails instead).
"""
from __future__ import annotations

import csv
import io
import json
import math
import time
from pathlib import Path

import httpx
import numpy as np
import pybullet as pb
import pytest
import trimesh
from labs import stop_process
from zoo import ROBOTS, SHARE, STRETCH_NESTED, ZOO

from mesh.messages.relations import POINTS
from tdgen.generate import generate
from tdgen.robot import ik
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import Robot, RobotError
from tdgen.robot.workspace import WorkspaceError

# fifteen arms, each generated and solved 200 times: minutes of CPU, so the lab layer's, not the unit layer's
pytestmark = [pytest.mark.lab, pytest.mark.slow]

TARGETS = 200
TOL_MM = 0.01


HANGING = {"talos-arm", "icub-arm"}  # humanoid arms: their base is a shoulder or a chest, not a mounting flange


@pytest.fixture(scope="module", params=sorted(ZOO))
def arm(request):
    urdf, options, expected, kind = ZOO[request.param]
    return request.param, ROBOTS / urdf, options, expected, kind


def test_two_arm_robots_are_refused_with_both_arms_named_until_one_is_picked():
    with pytest.raises(RobotError) as err:
        Robot.load(ROBOTS / "baxter_description/urdf/baxter.urdf")
    assert "2 arms of 7 joints" in str(err.value) and "left_wrist, right_wrist" in str(err.value)
    assert "--ee" in str(err.value)


def test_each_arm_gets_its_chain_a_watertight_workspace_and_a_td_that_names_the_chain(arm, tmp_path):
    name, urdf, options, (base, tip, n), kind = arm
    robot = Robot.load(urdf, **options)
    assert (robot.base_link, robot.ee_link, len(robot.joints)) == (base, tip, n), robot.describe_chain()
    for joint in options.get("fixed", {}):
        assert joint not in [j.name for j in robot.joints] and joint in robot.held
    hangs = name in HANGING
    if hangs:
        with pytest.raises(WorkspaceError, match="--no-surface"):
            generate(robot, None, 300, seed=0, out_dir=tmp_path / "on-a-floor", workers=1)
    result = generate(robot, None, 1500, seed=0, out_dir=tmp_path, workers=1, surface=not hangs)
    hull = trimesh.load_mesh(result.files["workspace"])
    assert hull.is_watertight and hull.volume > 0
    td = result.td
    assert len(td["properties"]["getJointposition"]["properties"]) == n
    assert f"base link {base} to the tip link {tip}" in td["properties"]["getJointposition"]["description"]
    info = json.loads(result.files["robot-info"].read_text())
    assert (info["baseLink"], info["tipLink"]) == (base, tip)
    print(f"\n{name:10s} {kind:40s} {base} -> {tip}, {n} joints, {result.collision_free}/{result.samples} "
          f"collision-free")


def test_a_mostly_colliding_workspace_is_said_and_allowed_pairs_free_it(tmp_path):
    """Baxter's left arm touches its own visual-named collision meshes at rest: tdgen says so and names
    the pairs; allowing them (as an SRDF disables them) frees samples and the at-rest warning goes."""
    urdf = ROBOTS / "baxter_description/urdf/baxter.urdf"
    plain = generate(Robot.load(urdf, ee="left_wrist"), None, 800, seed=0, out_dir=tmp_path / "a", workers=1)
    assert plain.warnings and "of the samples collide" in plain.warnings[0]
    assert f"Warning: {plain.warnings[0]}" in plain.td["description"]  # said in the TD a lab serves too
    assert any("collides at rest" in w and "left_upper_forearm / left_upper_elbow_visual" in w for w in plain.warnings)
    allowed = Robot.load(urdf, ee="left_wrist", allowed_collisions=[("left_upper_forearm", "left_upper_elbow_visual"),
                                                                     ("left_upper_shoulder", "left_upper_elbow")])
    freer = generate(allowed, None, 800, seed=0, out_dir=tmp_path / "b", workers=1)
    assert freer.collision_free > plain.collision_free
    assert not any("collides at rest" in w for w in freer.warnings)
    with pytest.raises(RobotError, match="no link named 'nope', 'nowhere' for an allowed collision"):
        Robot.load(urdf, ee="left_wrist", allowed_collisions=[("nope", "nowhere")])
    # a link and a name that is no link: a scene body, looked for in the scene
    with pytest.raises(ValueError, match="no link or scene body named 'nope'.*scene bodies: mounting-surface"):
        generate(Robot.load(urdf, ee="left_wrist", allowed_collisions=[("nope", "torso")]), None, 100, seed=0,
                 out_dir=tmp_path / "c", workers=1)


def test_an_arm_shipped_with_visual_meshes_only_collides_with_them_and_says_so(tmp_path):
    """The UR5 of the collection as hobby and classic arms ship: its `<collision>` elements taken out,
    its visual .dae meshes left. The tool says which links it takes the visual geometry of, once; the
    arm meets the floor and itself through those meshes (about as often as through its own collision
    meshes); no free point lies under the floor; and the points are where our forward kinematics puts
    the tip of their joint values."""
    import re

    from tdgen.robot.points_csv import read as read_points_csv

    source = (ROBOTS / "ur_description/urdf/ur5_robot.urdf").read_text()
    stripped = re.sub(r"<collision>.*?</collision>", "", source, flags=re.S)
    assert stripped.count("<visual>") == source.count("<visual>") and "<collision>" not in stripped
    urdf = tmp_path / "ur5_visual_only.urdf"
    urdf.write_text(stripped)
    packages = {"example-robot-data": SHARE}
    robot = Robot.load(urdf, packages=packages)
    shaped = ["base_link", "shoulder_link", "upper_arm_link", "forearm_link", "wrist_1_link", "wrist_2_link",
              "wrist_3_link"]
    assert list(robot.visual_collisions) == shaped
    assert robot.notes() == [f"7 link(s) have no collision geometry; their visual geometry is used for collision: "
                             f"{', '.join(shaped)}"]
    visual = generate(robot, None, 3000, seed=3, out_dir=tmp_path / "visual", workers=1)
    own = generate(Robot.load(ROBOTS / "ur_description/urdf/ur5_robot.urdf"), None, 3000, seed=3,
                   out_dir=tmp_path / "own", workers=1)
    assert visual.collision_free < visual.samples, "the arm went through the floor and itself unseen"
    positions, collision = read_points_csv(visual.files["points"])
    differ = float(np.mean(collision != read_points_csv(own.files["points"])[1]))  # the same seed: the same q
    assert differ < 0.02, f"{differ:.1%} of the samples collide otherwise than with the arm's collision meshes"
    assert positions[~collision][:, 2].min() >= -1.0  # mm: nothing free under the floor it stands on
    rows = np.loadtxt(visual.files["points"], delimiter=",", skiprows=1)
    q = np.radians(rows[:, 4:4 + len(robot.joints)])
    fk = ForwardKinematics(robot)
    tips = fk.positions(q[:200]) * 1000.0
    assert np.abs(tips - positions[:200]).max() <= 0.01
    print(f"\nUR5, visual meshes only: {visual.collision_free} of {visual.samples} free; with its collision meshes "
          f"{own.collision_free}; {differ:.2%} of the flags differ")


def test_a_telescoping_arms_nested_tubes_are_named_and_allowing_them_frees_its_workspace(tmp_path):
    """The Stretch's four nested tubes, as convex hulls, overlap where the real ones slide in each other:
    unnamed, they took 49 % of its poses silently (under the half that makes tdgen speak of a mostly
    colliding workspace). tdgen names the six pairs that touch at rest and are joined by prismatic joints
    only, or collide in 15 % or more of the poses (two did), with the options that allow exactly them;
    allowed, 98 % of the samples are free (93 % with the two frequent pairs alone) and nothing is said.
    Its tip is the gripper's grasp centre: the wrist's own frame lies on the yaw axis, and its points on
    a plane (refused as such, with --ee suggested)."""
    urdf, options, _, _ = ZOO["stretch"]
    plain = generate(Robot.load(urdf), None, 2000, seed=0, out_dir=tmp_path / "plain", workers=1)
    named = [w for w in plain.warnings if "touching at rest" in w]
    assert len(named) == 1, plain.warnings
    assert named[0].endswith(" ".join(f"--allow-collision {a}/{b}" for a, b in STRETCH_NESTED)), named[0]
    allowed = generate(Robot.load(urdf, **options), None, 2000, seed=0, out_dir=tmp_path / "allowed", workers=1)
    assert not allowed.warnings and allowed.collision_free > 0.95 * allowed.samples > plain.collision_free, \
        (allowed.collision_free, plain.collision_free)
    with pytest.raises(WorkspaceError, match="lie on a plane.*--ee LINK"):
        generate(Robot.load(urdf, ee="link_gripper", **options), None, 500, seed=0, out_dir=tmp_path / "flat", workers=1)
    print(f"\nstretch: {plain.collision_free} of 2000 free; the nested tubes allowed, {allowed.collision_free}")


def _pybullet_tip(robot: Robot, q: np.ndarray) -> np.ndarray:
    """The tip link's position (mm) by pybullet's own forward kinematics: the independent check."""
    client = pb.connect(pb.DIRECT)
    try:
        body = robot.load_into(client)
        out = []
        for row in np.atleast_2d(q):
            for index, value in robot.full_joint_values(row).items():
                pb.resetJointState(body, index, value, physicsClientId=client)
            out.append(pb.getLinkState(body, robot.ee_index, computeForwardKinematics=True,
                                       physicsClientId=client)[4])
        return np.array(out) * 1000.0
    finally:
        pb.disconnect(client)


def test_each_arm_reaches_200_random_reachable_targets_within_a_hundredth_of_a_mm(arm):
    name, urdf, options, _, _ = arm
    robot = Robot.load(urdf, **options)
    fk = ForwardKinematics(robot)
    rng = np.random.default_rng(7)
    q_true = rng.uniform(robot.lows(), robot.highs(), size=(TARGETS, len(robot.joints)))
    targets = _pybullet_tip(robot, q_true)
    started = time.perf_counter()
    solved = ik.solve_many(fk, targets / 1000.0, rng=1)
    seconds = time.perf_counter() - started
    errors = np.linalg.norm(_pybullet_tip(robot, solved.q) - targets, axis=1)
    reached = int((errors <= TOL_MM).sum())
    print(f"\n{name:10s} IK: {reached}/{TARGETS} within {TOL_MM} mm by pybullet's FK, worst "
          f"{errors.max():.2e} mm, {seconds / TARGETS * 1000:.1f} ms per target")
    assert reached == TARGETS, f"{TARGETS - reached} missed; worst {errors.max():.3f} mm"


# --- joining a lab ----------------------------------------------------------------------------
BATCH = 4  # robot processes on the mesh at once (each its own pybullet world)


def _robot_args(name: str) -> list[str]:
    """`twinmesh robot` options for a zoo arm: the same choices as the Python API (the PR2's meshes found
    through --package-path, not pybullet's search; Talos' and iCub's arms hang from a shoulder or a chest)."""
    _, options, _, _ = ZOO[name]
    args = ["--ee", options["ee"]] if "ee" in options else []
    args += ["--base-link", options["base_link"]] if "base_link" in options else []
    args += [f"--fix-joint={j}={v:g}" for j, v in options.get("fixed", {}).items()]
    args += [f"--allow-collision={a}/{b}" for a, b in options.get("allowed_collisions", ())]
    if name == "pr2":
        args += ["--package-path", f"example-robot-data={SHARE}"]
    if name in HANGING:
        args.append("--no-surface")
    return args


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


def _generated_td(http: httpx.Client, name: str, log: Path, proc, limit: float = 1200.0) -> dict:
    """The robot's TD once the tdgen service has generated its workspace. No fixed time: it waits while
    the robot runs and its generation has not failed (a busy machine only makes it slower); `limit`
    is a last resort for a hang, and the failure says what it waited for."""
    deadline = time.monotonic() + limit
    status: dict = {}
    while time.monotonic() < deadline:
        r = http.get(f"/{name}")
        if r.status_code == 200 and any("workspace" in link["rel"] for link in r.json()["links"]):
            return r.json()
        if proc.poll() is not None:
            raise AssertionError(f"{name}: the robot exited ({proc.returncode}) before its TD was generated\n"
                                 f"{log.read_text()[-3000:]}")
        status = http.get("/tdgen/properties/robots").json().get(name, {})
        if status.get("status") == "failed":
            raise AssertionError(f"{name}: generation failed: {status.get('error')}\n{log.read_text()[-3000:]}")
        time.sleep(0.5)
    raise AssertionError(f"{name}: waited {limit:.0f} s for the tdgen service to generate its TD (last status "
                         f"{status}); the robot still runs\n{log.read_text()[-3000:]}")


def _free_goal(http: httpx.Client, td: dict, joints: dict) -> dict[str, float]:
    """A collision-free sample of the arm's own workspace (its points.csv, linked from the TD), the one
    nearest to where it stands, each joint counted in its range: a goal every arm can be asked for."""
    href = next(link["href"] for link in td["links"] if link["rel"] == POINTS)
    rows = list(csv.DictReader(io.StringIO(http.get(href).text)))
    now = http.get(f"/{td['title']}/properties/getJointposition").json()
    free = [row for row in rows if row["collision"] == "0"]
    span = {j: (s["maximum"] - s["minimum"]) or 1.0 for j, s in joints.items()}
    nearest = min(free, key=lambda row: max(abs(float(row[j]) - now[j]) / span[j] for j in joints))
    return {j: round(float(nearest[j]), 3) for j in joints}


def test_every_zoo_arm_joins_a_lab_gets_its_td_generated_and_moves(lab):
    names = sorted(ZOO)
    moved, refused = [], {}
    with httpx.Client(base_url=lab.http, timeout=120) as http:
        for batch in [names[i:i + BATCH] for i in range(0, len(names), BATCH)]:
            procs = {name: lab.spawn("robot", str(ROBOTS / ZOO[name][0]), "--name", name, "--samples", "1500",
                                     "--speed", "max", *_robot_args(name), log=lab.tmp / f"{name}.log")
                     for name in batch}
            for name in batch:
                td = _generated_td(http, name, lab.tmp / f"{name}.log", procs[name])
                base, tip, n = ZOO[name][2]
                assert f"arm chain {base} -> {tip}: {n} joints" in (lab.tmp / f"{name}.log").read_text()  # said
                joints = td["properties"]["getJointposition"]["properties"]
                assert len(joints) == n and f"{base} to the tip link {tip}" in \
                    td["properties"]["getJointposition"]["description"]
                goal = _free_goal(http, td, joints)
                r = http.post(f"/{name}/actions/moveToJointPosition", json=goal)
                assert r.status_code in (200, 422), r.text  # moved, or a refusal that says why (a collision)
                if r.status_code == 200:
                    now = http.get(f"/{name}/properties/getJointposition").json()
                    assert all(math.isclose(now[j], goal[j], abs_tol=1e-3) for j in goal), (now, goal)
                    moved.append(name)
                else:
                    refused[name] = r.json()["reason"]
            for proc in procs.values():
                assert stop_process(proc), "a robot did not stop cleanly on Ctrl-C"
    print(f"\n{len(names)} arms joined; moved: {', '.join(moved)}; refused: {refused}")
    assert len(moved) >= len(names) - 2, refused
