"""Workspace solids and target checks: hulls, alpha shapes, inside/outside, collision probability."""
from __future__ import annotations

import numpy as np
import pytest

from tdgen.generate import generate
from tdgen.robot.workspace import WorkspaceError, alpha_shape, bounds, convex_hull
from tdgen.robot.workspace_check import Workspace, check_target


def _cube(n: int = 4000, seed: int = 0) -> np.ndarray:
    corners = np.array([[x, y, z] for x in (0, 100) for y in (0, 100) for z in (0, 100)], dtype=float)
    return np.vstack([corners, np.random.default_rng(seed).uniform(0, 100, (n, 3))])


def test_convex_hull_is_watertight_with_outward_normals_and_exact_volume():
    solid = convex_hull(_cube())
    assert solid.volume == pytest.approx(1e6)
    assert solid.mesh.is_watertight and solid.mesh.volume == pytest.approx(1e6)  # positive: normals outward


@pytest.mark.parametrize("points, shape", [
    (np.random.default_rng(1).uniform(0, 1, (50, 3)) * [1, 1, 0], "a plane"),
    (np.outer(np.arange(20.0), [1, 2, 3]), "a line"),
    (np.zeros((10, 3)), "a single point"),
    (np.zeros((3, 3)), "span no volume"),
])
def test_a_hull_of_degenerate_points_is_refused_saying_why(points, shape):
    with pytest.raises(WorkspaceError, match=shape):
        convex_hull(points)
    assert alpha_shape(points) is None  # the optional shape just has nothing to show


def test_points_on_a_plane_but_for_float_dust_are_refused_as_a_plane_not_given_a_hull_of_no_volume():
    """A Stretch's lift and telescoping arm with the tip on its wrist's axis: x constant to 1e-3 mm over
    a metre of y and z. qhull makes a sliver of it (0.0000 m^3) that every target would be outside of."""
    rng = np.random.default_rng(3)
    points = np.column_stack([-21.4 + rng.uniform(-1e-3, 1e-3, 2000), rng.uniform(-625, -340, 2000),
                              rng.uniform(170, 1264, 2000)])
    with pytest.raises(WorkspaceError, match="lie on a plane.*--ee LINK"):
        convex_hull(points)
    points[:, 0] = rng.uniform(-30, -10, 2000)  # 20 mm thick: a solid, thin but real
    assert convex_hull(points).volume == pytest.approx(20 * 285 * 1094, rel=0.06)  # a box, its corners cut


def test_bounds_of_nothing_say_every_configuration_collides():
    with pytest.raises(WorkspaceError, match="every sampled configuration collides"):
        bounds(np.zeros((0, 3)))


def test_alpha_shape_follows_a_concave_set_the_hull_fills_in():
    rng = np.random.default_rng(2)
    points = rng.uniform(0, 100, (30000, 3))
    l_shape = points[(points[:, 0] < 30) | (points[:, 1] < 30)]     # an L: 0.51 of the cube
    solid = alpha_shape(l_shape)
    hull = convex_hull(l_shape)
    assert hull.volume == pytest.approx(0.755e6, rel=0.04)          # the hull cuts the corner diagonally
    assert solid.volume == pytest.approx(0.51e6, rel=0.1)           # a little eroded at the faces
    assert solid.mesh.volume == pytest.approx(solid.volume, rel=0.01)


def test_inside_outside_and_margin_against_a_cube():
    workspace = Workspace(_cube(), np.zeros(4008, dtype=bool))
    assert workspace.contains(np.array([[50, 50, 50], [0, 0, 0], [100, 50, 50], [100.01, 50, 50]])).tolist() == \
        [True, True, True, False]
    assert workspace.margin(np.array([50.0, 50.0, 20.0])) == pytest.approx(20.0)
    assert workspace.margin(np.array([130.0, 50.0, 50.0])) == pytest.approx(-30.0)
    assert workspace.margin(np.array([103.0, 104.0, 50.0])) == pytest.approx(-5.0)   # to the edge, not a plane


def test_collision_probability_is_the_colliding_share_of_the_nearest_points_within_the_radius():
    positions = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0], [50, 0, 0], [0, 0, 60], [0, 70, 0]])
    collision = np.array([True, True, False, False, False, False, False])
    workspace = Workspace(positions, collision)
    assert workspace.collision_probability(np.zeros(3), k=4, radius=10) == (0.5, 4)
    assert workspace.collision_probability(np.zeros(3), k=2, radius=10) == (1.0, 2)
    assert workspace.collision_probability(np.zeros(3), k=10, radius=10) == (0.5, 4)   # the radius limits
    assert workspace.collision_probability(np.array([10.0, 10, 10]), k=4, radius=10) == (None, 0)
    refused = workspace.check((10, 10, 10), k=4, radius=10)
    assert refused.inside and not refused.ok and "unknown" in refused.reason


@pytest.fixture(scope="module")
def ur10_on_table(tmp_path_factory):
    out = tmp_path_factory.mktemp("ur10")
    generate("ur10.urdf", "table-and-wall", 6000, seed=11, out_dir=out, workers=1)
    return out


def test_a_target_far_outside_the_workspace_is_refused(ur10_on_table):
    result = check_target(ur10_on_table, (3000.0, 0.0, 0.0))
    assert not result.inside and not result.ok
    assert result.margin_mm < -1500
    assert "outside the workspace" in result.reason


def test_a_target_inside_the_wall_is_likely_to_collide(ur10_on_table):
    # base frame: the wall is at y = 550..650 mm, from the floor (z = -625) to z = 975; the UR10 reaches 1.3 m
    result = check_target(ur10_on_table, (0.0, 600.0, 300.0), radius=150)
    assert result.neighbours >= 5
    assert result.collision_probability >= 0.9
    assert not result.ok


def test_a_free_target_above_the_table_is_accepted(ur10_on_table):
    result = check_target(ur10_on_table, (400.0, -400.0, 500.0), radius=150)
    assert result.inside and result.margin_mm > 100
    assert result.collision_probability < 0.5 and result.ok
