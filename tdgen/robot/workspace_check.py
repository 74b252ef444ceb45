"""Target checking before a Cartesian move: inside the workspace hull, and how likely to collide.

Both answers come from the sampled points of a generated TD directory (`points.csv`), in the frame
they were written in (twin, or real after calibration), in mm:
- inside: the half-space test against the convex hull of the collision-free points (scipy
  ConvexHull's facet equations A x + b <= eps for every facet, A unit normals, so A x + b is a
  signed distance to each facet's plane);
- collision probability: among ALL sampled points (colliding ones too), the share of colliding
  ones among the k nearest within `radius` of the target. It says how often a random
  configuration that puts the end effector there collides with the robot itself or the scene;
  no neighbour within the radius means nothing is known, and the move is refused.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import cKDTree

from tdgen.robot import points_csv
from tdgen.robot.workspace import convex_hull, qhull

if TYPE_CHECKING:
    import trimesh

DEFAULT_K = 20
DEFAULT_RADIUS_MM = 100.0
DEFAULT_MAX_PROBABILITY = 0.5
INSIDE_EPS_MM = 1e-3


@dataclass(frozen=True)
class CheckResult:
    target: tuple[float, float, float]       # mm
    inside: bool
    margin_mm: float                         # > 0 inside: distance to the hull surface; < 0 outside: minus the distance
    collision_probability: float | None      # None: no sampled point within the radius
    neighbours: int                          # sampled points the probability rests on
    ok: bool                                 # safe to move there
    reason: str                              # why not (or why yes), one line for people


class Workspace:
    """The hull of the collision-free points and a k-d tree of all points, built once, asked often."""

    def __init__(self, positions: np.ndarray, collision: np.ndarray, tree: cKDTree | None = None):
        self.positions = np.asarray(positions, dtype=float)
        self.collision = np.asarray(collision, dtype=bool)
        free = self.positions[~self.collision]
        self._hull = qhull(free)
        self._mesh: "trimesh.Trimesh | None" = None
        self._tree = cKDTree(self.positions) if tree is None else tree

    def with_collision(self, collision: np.ndarray) -> "Workspace":
        """The same points with other collision flags (their scene changed): a new hull, the same k-d tree."""
        if len(collision) != len(self.positions):
            raise ValueError(f"{len(collision)} flags for {len(self.positions)} points")
        return Workspace(self.positions, collision, self._tree)

    @classmethod
    def load(cls, td_dir: str | Path) -> "Workspace":
        """From a directory written by `tdgen.generate` (its points.csv)."""
        path = Path(td_dir) / "points.csv"
        if not path.is_file():
            raise FileNotFoundError(f"{path}: no points.csv (is {td_dir} a directory written by `twinmesh tdgen`?)")
        return cls(*points_csv.read(path))

    def plane_distances(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) -> (N, facets): signed distances to the facet planes (> 0: outside that facet)."""
        eq = self._hull.equations
        return np.atleast_2d(points) @ eq[:, :3].T + eq[:, 3]

    def contains(self, points: np.ndarray, eps: float = INSIDE_EPS_MM) -> np.ndarray:
        """(N, 3) -> (N,) bool: inside the hull (on it within eps counts as inside)."""
        return np.asarray((self.plane_distances(points) <= eps).all(axis=1))

    def margin(self, point: np.ndarray) -> float:
        """Signed distance to the hull surface: > 0 inside, < 0 outside (exact, mm)."""
        worst = float(self.plane_distances(point).max())
        if worst <= 0:
            return -worst  # inside a convex solid, the nearest facet plane is the nearest surface
        if self._mesh is None:
            self._mesh = convex_hull(self.positions[~self.collision]).mesh
        import trimesh  # here, not at import: `twinmesh tdgen` and the robots start a third of a second sooner

        return -float(trimesh.proximity.closest_point(self._mesh, np.atleast_2d(point))[1][0])

    def collision_probability(self, point: np.ndarray, k: int = DEFAULT_K,
                              radius: float = DEFAULT_RADIUS_MM) -> tuple[float | None, int]:
        """(share of colliding points among the k nearest within radius, how many there were)."""
        dist, idx = self._tree.query(np.asarray(point, dtype=float), k=k, distance_upper_bound=radius)
        idx = np.atleast_1d(idx)[np.isfinite(np.atleast_1d(dist))]
        if len(idx) == 0:
            return None, 0
        return float(self.collision[idx].mean()), int(len(idx))

    def check(self, target, k: int = DEFAULT_K, radius: float = DEFAULT_RADIUS_MM,
              max_probability: float = DEFAULT_MAX_PROBABILITY) -> CheckResult:
        """May the end effector move to `target` (mm)? Refused outside the hull or when too likely to collide."""
        if k < 1 or radius <= 0:
            raise ValueError("k must be >= 1 and radius > 0")
        point = np.asarray(target, dtype=float).reshape(3)
        inside = bool(self.contains(point)[0])
        margin = self.margin(point)
        probability, n = self.collision_probability(point, k, radius)
        if not inside:
            ok, reason = False, f"outside the workspace hull by {-margin:.1f} mm"
        elif probability is None:
            ok, reason = False, f"no sampled point within {radius:g} mm: collision risk unknown"
        elif probability > max_probability:
            ok, reason = False, (f"collision probability {probability:.0%} from {n} nearby samples "
                                 f"exceeds {max_probability:.0%}")
        else:
            ok, reason = True, (f"inside the workspace ({margin:.1f} mm from its surface), collision probability "
                                f"{probability:.0%} from {n} nearby samples")
        return CheckResult((float(point[0]), float(point[1]), float(point[2])), inside, margin, probability, n,
                           ok, reason)


def check_target(td_dir: str | Path, target, k: int = DEFAULT_K, radius: float = DEFAULT_RADIUS_MM,
                 max_probability: float = DEFAULT_MAX_PROBABILITY) -> CheckResult:
    """One-shot check against a generated TD directory (load the workspace once to check many)."""
    return Workspace.load(td_dir).check(target, k, radius, max_probability)
