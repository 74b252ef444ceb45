"""The workspace as a solid: convex hull (and an optional alpha shape) of the collision-free points.

The convex hull is what the TD links and what targets are checked against: it is unique, fast and
watertight. It over-states the workspace where the reachable set is not convex (the table a robot
stands on lies inside it), hence the collision probability beside it in `tdgen.robot.workspace_check`, and the
optional alpha shape, a tighter but tunable picture for people to look at.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
from scipy.spatial import ConvexHull, Delaunay, QhullError

if TYPE_CHECKING:
    import trimesh

ALPHA_SPACINGS = 3.0  # default alpha radius, in typical point spacings


class WorkspaceError(Exception):
    """Points that span no solid (too few, or all on a plane or a line)."""


@dataclass(frozen=True)
class Solid:
    vertices: np.ndarray  # (V, 3)
    faces: np.ndarray     # (F, 3) vertex indices, counter-clockwise seen from outside
    volume: float         # in the points' unit, cubed

    @property
    def mesh(self) -> "trimesh.Trimesh":
        """The solid as a trimesh mesh (trimesh is imported here, not by `twinmesh tdgen`: a third of a second)."""
        import trimesh

        return trimesh.Trimesh(self.vertices, self.faces, process=False)


def bounds(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(min xyz, max xyz) of the points."""
    if len(points) == 0:
        raise WorkspaceError("no collision-free point: every sampled configuration collides")
    return points.min(axis=0), points.max(axis=0)


def qhull(points: np.ndarray) -> ConvexHull:
    """scipy's hull of the points, or a WorkspaceError saying why there is none."""
    if len(points) < 4:
        raise WorkspaceError(f"{len(points)} collision-free points span no volume (a hull needs 4 or more)")
    try:
        hull = ConvexHull(points)
    except QhullError:
        raise _flat(points) from None
    # points on a plane but for float dust (a lift and a telescoping arm, the tip on the wrist's axis: x
    # varied by 1e-3 mm over a metre) make a hull of no volume that every target is outside of
    corners = hull.points[hull.vertices]
    extents = np.linalg.svd(corners - corners.mean(axis=0), compute_uv=False)
    if extents[-1] <= FLAT * extents[0]:
        raise _flat(points)
    return hull


FLAT = 1e-5  # a hull thinner than this share of its length is the plane its points lie on


def _flat(points: np.ndarray) -> WorkspaceError:
    spread = np.linalg.svd(points - points.mean(axis=0), compute_uv=False)
    rank = int(np.sum(spread > FLAT * spread[0])) if spread[0] > 0 else 0
    shape = {0: "a single point", 1: "a line", 2: "a plane"}.get(rank, "a degenerate set")
    return WorkspaceError(f"the {len(points)} collision-free points lie on {shape}: no workspace volume "
                          "(a robot with fewer than three independent motions, or a tip on the axis of the last "
                          "joint? --ee LINK picks another tip)")


def convex_hull(points: np.ndarray) -> Solid:
    """The convex hull as a watertight mesh with outward facet normals."""
    hull = qhull(points)
    faces = hull.simplices.copy()
    p = hull.points
    normals = np.cross(p[faces[:, 1]] - p[faces[:, 0]], p[faces[:, 2]] - p[faces[:, 0]])
    inward = np.einsum("ij,ij->i", normals, hull.equations[:, :3]) < 0
    faces[inward] = faces[inward][:, ::-1]
    return Solid(*_compact(p, faces), float(hull.volume))


def alpha_shape(points: np.ndarray, radius: float | None = None) -> Solid | None:
    """The union of Delaunay tetrahedra whose circumsphere radius is below `radius`; None if empty.

    Without `radius`, it is ALPHA_SPACINGS times the typical point spacing (hull volume / N)^(1/3).
    The surface may have non-manifold edges where the shape pinches; the volume is exact all the
    same (the sum of the kept tetrahedra). Degenerate input (flat, too few points) gives None.
    """
    if len(points) < 5:
        return None
    try:
        tri = Delaunay(points)
        hull_volume = ConvexHull(points).volume
    except QhullError:
        return None
    if radius is None:
        radius = ALPHA_SPACINGS * (hull_volume / len(points)) ** (1 / 3)
    tets = tri.simplices
    a, b, c, d = (points[tets[:, k]] for k in range(4))
    u, v, w = b - a, c - a, d - a
    six_volume = np.einsum("ij,ij->i", u, np.cross(v, w))
    with np.errstate(divide="ignore", invalid="ignore"):
        offset = ((u * u).sum(1)[:, None] * np.cross(v, w) + (v * v).sum(1)[:, None] * np.cross(w, u)
                  + (w * w).sum(1)[:, None] * np.cross(u, v)) / (2 * six_volume[:, None])
        keep = np.linalg.norm(offset, axis=1) < radius
    keep &= np.abs(six_volume) > 0
    if not keep.any():
        return None
    kept = tets[keep]
    # each tetrahedron's four faces, with the vertex opposite to each
    faces = np.concatenate([kept[:, [1, 2, 3]], kept[:, [0, 3, 2]], kept[:, [0, 1, 3]], kept[:, [0, 2, 1]]])
    opposite = np.concatenate([kept[:, 0], kept[:, 1], kept[:, 2], kept[:, 3]])
    _, first, counts = np.unique(np.sort(faces, axis=1), axis=0, return_index=True, return_counts=True)
    boundary = first[counts == 1]
    faces, opposite = faces[boundary], points[opposite[boundary]]
    p0, p1, p2 = (points[faces[:, k]] for k in range(3))
    towards_opposite = np.einsum("ij,ij->i", np.cross(p1 - p0, p2 - p0), opposite - p0) > 0
    faces[towards_opposite] = faces[towards_opposite][:, ::-1]
    return Solid(*_compact(points, faces), float(np.abs(six_volume[keep]).sum() / 6))


def _compact(points: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of only the vertices the faces use."""
    used, inverse = np.unique(faces, return_inverse=True)
    return points[used], inverse.reshape(faces.shape)


def stl_bytes(solid: Solid) -> bytes:
    """Binary STL with facet normals."""
    triangles = solid.vertices[solid.faces]                                       # (F, 3, 3)
    normals = np.cross(triangles[:, 1] - triangles[:, 0], triangles[:, 2] - triangles[:, 0])
    lengths = np.linalg.norm(normals, axis=1, keepdims=True)
    normals = np.divide(normals, lengths, out=np.zeros_like(normals), where=lengths > 0)
    facets = np.zeros(len(triangles), dtype=[("normal", "<f4", 3), ("corners", "<f4", (3, 3)), ("attribute", "<u2")])
    facets["normal"], facets["corners"] = normals, triangles
    header = b"twinmesh workspace (binary STL)".ljust(80, b" ")
    return header + np.uint32(len(facets)).tobytes() + facets.tobytes()

