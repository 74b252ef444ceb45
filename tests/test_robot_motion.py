"""Safe motion: every accepted move follows a collision-free path (re-checked here in a pybullet client
of the test's own, ten times finer), refusals name why, a dry run moves nothing, a move can be stopped."""
from __future__ import annotations

import threading

import msgspec
import numpy as np
import pytest
from waiting import always, eventually

from devices.planning.moves import MovePlan
from devices.planning.paths import STEP_MM, NoPath, PathChecker, find_path
from devices.sim.pybullet_world import World
from devices.sim.robot_twin import Base, RobotTwin, workspace_from_csv
from mesh.wot.problem import Problem
from tdgen.generate import generate
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.fast_collision import FastCollision
from tdgen.robot.surroundings import BoxBody, build_into

SAMPLES = 4000
START = {"shoulder_pan_joint": -170.0, "shoulder_lift_joint": -20.0, "elbow_joint": 0.0, "wrist_1_joint": 0.0,
         "wrist_2_joint": 0.0, "wrist_3_joint": 0.0}
BEYOND_THE_WALL = {**START, "shoulder_pan_joint": -10.0}  # panning straight there sweeps the arm through the wall


@pytest.fixture(scope="module")
def workspace(ur10, scene, tmp_path_factory):
    out = tmp_path_factory.mktemp("ur10")
    generate(ur10, scene, SAMPLES, 0, out, workers=1)
    return workspace_from_csv((out / "points.csv").read_bytes())


@pytest.fixture(scope="module")
def referee(ur10, scene):
    """The test's own collision world (its own pybullet client), checking ten times finer than the robot."""
    checker = PathChecker(CollisionWorld(ur10, scene), step_mm=STEP_MM / 10)
    yield checker
    checker.world.close()


@pytest.fixture
def twin(ur10, scene, workspace):
    world = World(speed=None)
    build_into(scene, world.client)
    world.start()
    t = RobotTwin(world, ur10, "ur10", Base(tuple(scene.robot.position)), scene)
    t.set_workspace(workspace)
    yield t
    t.close()
    world.close()


def assert_safe(plan: MovePlan, start: np.ndarray, referee: PathChecker) -> None:
    """The path starts where the arm was, ends at its goal, and collides nowhere, re-checked densely."""
    path = plan.path.waypoints
    assert np.allclose(path[0], start, atol=1e-9)
    assert referee.free(path[0]) and referee.path_free(path), f"{plan.path.method} path collides"


def test_a_straight_path_through_the_wall_is_replaced_by_a_planned_one_that_ends_at_the_goal(twin, ur10, referee):
    twin.move_to_joints(START)
    straight = PathChecker(CollisionWorld(ur10, twin.scene))
    try:
        assert not straight.segment_free(twin.q, ur10.from_user_units([BEYOND_THE_WALL[j.name] for j in ur10.joints]))
    finally:
        straight.world.close()
    start = twin.q.copy()
    plan = twin.move_to_joints(BEYOND_THE_WALL)
    assert plan.path.method == "planned" and len(plan.path.waypoints) >= 3
    assert_safe(plan, start, referee)
    assert twin.joint_position() == pytest.approx(BEYOND_THE_WALL, abs=1e-6)
    answer = plan.answer(twin)
    assert answer["method"] == "planned" and answer["planning_ms"] > 0
    assert answer["path"]["joints"] == [j.name for j in ur10.joints]
    assert answer["path"]["points"][0] == pytest.approx(list(START.values()), abs=1e-6)
    assert answer["path"]["points"][-1] == pytest.approx(list(BEYOND_THE_WALL.values()), abs=1e-6)
    tip = np.array(answer["path"]["tip"])
    assert len(tip) == 8 * (len(answer["path"]["points"]) - 1) + 1
    assert tip[-1] == pytest.approx([answer["reached"][a] for a in "xyz"], abs=1e-3)
    times = answer["path"]["times"]
    assert times[0] == 0 and all(b > a for a, b in zip(times, times[1:])) and len(times) == len(answer["path"]["points"])


def test_a_free_straight_path_is_taken_as_it_is(twin, ur10, referee):
    twin.move_to_joints(START)
    start = twin.q.copy()
    plan = twin.move_to_joints({**START, "shoulder_pan_joint": -175.0})
    assert plan.path.method == "straight" and len(plan.path.waypoints) == 2
    assert_safe(plan, start, referee)


def test_the_resolution_bounds_how_far_any_point_moves_between_two_checked_states(ur10, scene):
    """Sweep bound: measured link-frame and link-geometry displacement stays under STEP_MM per subdivision."""
    world = CollisionWorld(ur10, scene)
    try:
        checker = PathChecker(world)
        import pybullet as pb

        rng = np.random.default_rng(1)
        for _ in range(20):
            a, b = rng.uniform(ur10.lows(), ur10.highs(), (2, len(ur10.joints)))
            n = checker.subdivisions(a, b)
            frames = []  # every link's frame at each of the n + 1 checked states, each state measured once
            for k in range(n + 1):
                world._set(world._values((a + (b - a) * k / n)[None])[0])
                frames.append([pb.getLinkState(world.body, link, computeForwardKinematics=True,
                                               physicsClientId=world.client)[4]
                               for link in range(pb.getNumJoints(world.body, physicsClientId=world.client))])
            worst = float(np.max(np.linalg.norm(np.diff(np.array(frames), axis=0), axis=2)))
            assert worst * 1000 <= STEP_MM + 1e-6, (worst, n)
    finally:
        world.close()


def test_a_target_under_the_table_top_is_refused_as_a_collision(twin, workspace):
    under = next(p for p in ((x, y, -60) for x in range(200, 601, 50) for y in range(-300, 301, 50))
                 if workspace.check(p).inside)  # inside the hull, which reaches down past the table's edges
    before = twin.joint_position()
    with pytest.raises(Problem) as err:
        twin.move_to_cartesian(under)
    assert err.value.status == 422 and err.value.reason == "collision", err.value
    assert any("table" in pair for pair in err.value.extra["collisions"])
    assert twin.joint_position() == before


def test_a_target_boxed_in_by_an_added_obstacle_is_refused_and_nothing_moves(twin, workspace):
    target = next(p for p in workspace.positions[~workspace.collision]
                  if 300 < np.linalg.norm(p) < 900 and p[2] > 200 and workspace.check(p).inside)
    centre = np.asarray(target) / 1000 + np.array([0, 0, 0.625])
    box = BoxBody(name="crate", size=(0.25, 0.25, 0.25), position=tuple(float(v) for v in centre))
    twin.set_scene(msgspec.structs.replace(twin.scene, bodies=[*twin.scene.bodies, box]))
    before = twin.joint_position()
    with pytest.raises(Problem) as err:
        twin.move_to_cartesian(target)
    assert err.value.status == 422 and err.value.reason in ("collision", "no-path"), err.value
    assert "crate" in err.value.detail or err.value.reason == "no-path"
    assert twin.joint_position() == before


def test_plan_move_answers_like_a_move_and_moves_nothing(twin, ur10, referee):
    twin.move_to_joints(START)
    before, start = twin.joint_position(), twin.q.copy()
    plan = twin.plan_move(joints=BEYOND_THE_WALL)
    assert plan.path.method == "planned"
    assert_safe(plan, start, referee)
    assert twin.joint_position() == before
    assert np.allclose(plan.q, ur10.from_user_units([BEYOND_THE_WALL[j.name] for j in ur10.joints]))
    with pytest.raises(Problem) as err:
        twin.plan_move(joints={**START, "shoulder_lift_joint": 90.0})  # down through the table
    assert err.value.reason == "collision" and twin.joint_position() == before


def test_goals_no_path_reaches_give_way_to_fresh_ones_drawn_between_planning_rounds(ur10, scene, referee):
    """IK can hand the planner only configurations it cannot reach (an arm folded into a pocket; here, one
    down through the table, which no path reaches at all). A round that finds nothing asks for fresh
    goals instead of spending the whole budget on the same ones; a caller with none to give gets the
    refusal saying how many draws it had."""
    checker = PathChecker(FastCollision(CollisionWorld(ur10, scene)))
    to_q = lambda joints: ur10.from_user_units([joints[j.name] for j in ur10.joints])  # noqa: E731
    start, pocket, beyond = to_q(START), to_q({**START, "shoulder_lift_joint": 90.0}), to_q(BEYOND_THE_WALL)
    assert checker.free(start) and not checker.free(pocket) and not checker.segment_free(start, beyond)
    draws: list[int] = []

    def more_goals() -> list[np.ndarray]:
        draws.append(1)
        return [pocket, beyond]  # the old goal again is not tried twice

    try:
        path = find_path(checker, start, [pocket], ur10.lows(), ur10.highs(), budget_s=30.0, more_goals=more_goals)
        assert path.method == "planned" and np.array_equal(path.waypoints[-1], beyond)
        assert referee.free(path.waypoints[0]) and referee.path_free(path.waypoints)
        assert draws  # fresh goals were asked for (a round is time-sliced: a busy machine may need two)

        pockets: list[np.ndarray] = []

        def more_pockets() -> list[np.ndarray]:  # another configuration through the table each time
            pockets.append(pocket + 0.01 * (len(pockets) + 1))
            assert not checker.free(pockets[-1])
            return pockets[-1:]

        with pytest.raises(NoPath) as refused:
            find_path(checker, start, [pocket], ur10.lows(), ur10.highs(), budget_s=0.5, more_goals=more_pockets)
        draws_made = 1 + len(pockets)  # the first goals, then one per round that found nothing
        assert len(pockets) >= 1 and refused.value.tried["goal_draws"] == draws_made
        assert f"{draws_made} goal configurations from {draws_made} draws" in str(refused.value)
    finally:
        checker.world.close()


def test_every_accepted_cartesian_move_is_safe_and_reaches_its_target(twin, workspace, referee):
    rng = np.random.default_rng(7)
    free = workspace.positions[~workspace.collision]
    accepted = 0
    for p in free[rng.choice(len(free), 12, replace=False)]:
        start = twin.q.copy()
        try:
            plan = twin.move_to_cartesian(p)
        except Problem as err:
            assert err.status == 422 and err.reason in ("no-path", "collision", "outside-workspace"), err
            continue
        accepted += 1
        assert_safe(plan, start, referee)
        assert plan.error_mm <= 0.01
    assert accepted >= 9


def test_a_move_under_way_can_be_stopped_where_it_is(ur10, scene, workspace):
    world = World(speed=1.0)  # real time: the move takes seconds
    build_into(scene, world.client)
    world.start()
    twin = RobotTwin(world, ur10, "ur10", Base(tuple(scene.robot.position)), scene)
    try:
        goal = {**START, "shoulder_pan_joint": -175.0}
        start = twin.joint_position()
        errors: list[Problem] = []

        def move() -> None:
            try:
                twin.move_to_joints(goal)
            except Problem as p:
                errors.append(p)

        mover = threading.Thread(target=move)
        mover.start()
        eventually(lambda: twin.joint_position() != start, timeout=10, interval=0.01,
                   what="the move under way (planning, then moving)")
        assert twin.stop() is True
        mover.join(10)
        assert not mover.is_alive() and errors and errors[0].status == 409 and errors[0].reason == "stopped"
        halted = twin.joint_position()
        always(lambda: twin.joint_position() == halted, 0.3, what="it stays where it stopped")
        assert halted != pytest.approx(goal, abs=1e-3) and halted != start
        assert errors[0].extra["joints"] == halted
        assert twin.stop() is False  # nothing left to stop
    finally:
        twin.close()
        world.close()
