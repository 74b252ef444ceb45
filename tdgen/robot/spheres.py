"""The shapes of the fast collision model: spheres around and inside each link, convex bodies around
and inside each scene body.

Each collision element becomes two things: *outer* spheres whose union contains it (cut into slabs
along its longest axis; a sphere around all corners of a convex piece contains the piece), grown by
`PAD` for pybullet's collision margins; and *inner* spheres that lie inside it. A scene element
becomes an outer convex polytope (half-spaces around it) and an inner one (inside it). Two outer
shapes apart means the exact test cannot find a contact; two inner shapes overlapping by more than
`SURE_DEPTH` means it must; everything between is left to the exact test (`fast_collision`).

The geometry comes from the URDF pybullet loaded (`Robot.load_path`: borrowed visual geometry and
resolved meshes included; boxes, cylinders, spheres, capsules, meshes) and from the scene's own
primitives; each link and body is then held against pybullet's (the same number of shapes, inside its
bounding box). A link that does not match (a shape this module does not read, a mesh trimesh cannot
open) gets one sphere around everything pybullet has for it and no inner sphere: slower (more left to
the exact test), never wrong.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from mesh.urdf_resources import resolve_uri
from tdgen.robot.kinematics import _rpy_matrix
from tdgen.robot.urdf_files import declared

PAD = 0.003          # m added to outer spheres: pybullet's margins around hulls (0.001) and its AABB slack
SURE_DEPTH = 0.002   # m of overlap of inner shapes that pybullet's test must see as a collision (it needs 0.0001)
MATCH = 0.006        # m: a link's outer geometry may differ this much per side from pybullet's own AABB
SIDES = 16           # a cylinder as a prism of this many sides (outside: circumscribed; inside: inscribed)
PYBULLET_SIDES = 32  # pybullet turns a URDF cylinder into a hull of this many points per cap circle


@dataclass
class Convex:
    """One convex collision element: `points` span a set that contains it; `planes` (P, 4): rows
    (n, d) of half-spaces n.x <= d whose intersection lies inside it (none: nothing sure inside)."""

    points: np.ndarray
    planes: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    sphere: tuple[np.ndarray, float] | None = None  # an exact sphere element (centre, radius)
    inside: np.ndarray | None = None  # points surely in the element as pybullet holds it (None: `points`)
    outside: np.ndarray | None = None  # (P, 4) half-spaces around it, where known without a hull (boxes, prisms)
    exact: tuple[np.ndarray, np.ndarray] | None = None  # a mesh hull's own (corners, faces) behind a k-DOP

    def inner_points(self) -> np.ndarray:
        return self.points if self.inside is None else self.inside

    def moved(self, rot: np.ndarray, pos: np.ndarray) -> "Convex":
        points = self.points @ rot.T + pos
        inside = self.inside @ rot.T + pos if self.inside is not None else None
        outside = _moved_planes(self.outside, rot, pos) if self.outside is not None else None
        exact = (self.exact[0] @ rot.T + pos, _moved_planes(self.exact[1], rot, pos)) if self.exact is not None else None
        planes = _moved_planes(self.planes, rot, pos)
        sphere = (rot @ self.sphere[0] + pos, self.sphere[1]) if self.sphere is not None else None
        return Convex(points, planes, sphere, inside, outside, exact)


def _moved_planes(planes: np.ndarray, rot: np.ndarray, pos: np.ndarray) -> np.ndarray:
    out = planes.copy()
    if len(out):
        out[:, :3] = planes[:, :3] @ rot.T
        out[:, 3] = planes[:, 3] + out[:, :3] @ pos
    return out


def _box_points(half: np.ndarray) -> np.ndarray:
    return np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)]) * half


def _box_planes(half: np.ndarray) -> np.ndarray:
    rows = []
    for k in range(3):
        for sign in (-1.0, 1.0):
            n = np.zeros(3)
            n[k] = sign
            rows.append([*n, half[k]])
    return np.array(rows)


def box(size) -> Convex:
    half = np.asarray(size, dtype=float) / 2
    return Convex(_box_points(half), _box_planes(half), outside=_box_planes(half))


def _prism_planes(apothem: float, half_length: float) -> np.ndarray:
    angles = 2 * np.pi * np.arange(SIDES) / SIDES
    sides = np.column_stack([np.cos(angles), np.sin(angles), np.zeros(SIDES), np.full(SIDES, apothem)])
    caps = np.array([[0.0, 0.0, 1.0, half_length], [0.0, 0.0, -1.0, half_length]])
    return np.vstack([sides, caps])


def cylinder(radius: float, length: float, hull_sides: int | None = None) -> Convex:
    """A cylinder along z; `hull_sides`: pybullet holds it as a hull of that many points per circle
    (a URDF's cylinder), so only the polygon inside that counts as surely inside."""
    angles = 2 * np.pi * (np.arange(SIDES) + 0.5) / SIDES
    corner = radius / math.cos(math.pi / SIDES)
    ring = np.column_stack([corner * np.cos(angles), corner * np.sin(angles)])
    points = np.vstack([np.column_stack([ring, np.full(SIDES, z)]) for z in (-length / 2, length / 2)])
    inside = radius * (math.cos(math.pi / hull_sides) if hull_sides else 1.0) * math.cos(math.pi / SIDES)
    turns = angles[::2] - np.pi / SIDES  # every other corner of the inscribed polygon
    inner_ring = inside / math.cos(math.pi / SIDES) * np.column_stack([np.cos(turns), np.sin(turns)])
    ring_points = np.vstack([np.column_stack([inner_ring, np.full(len(turns), z)]) for z in (-length / 2, length / 2)])
    return Convex(points, _prism_planes(inside, length / 2), inside=ring_points,
                  outside=_prism_planes(radius, length / 2))  # the faces of the prism around it


def sphere(radius: float) -> Convex:
    """Outside: the cube around it; inside: the cube in it (a scene's sphere is tested as polytopes)."""
    return Convex(_box_points(np.full(3, radius)), _box_planes(np.full(3, radius / math.sqrt(3))),
                  sphere=(np.zeros(3), radius), inside=np.zeros((1, 3)))


def _sphere_points() -> tuple[np.ndarray, float]:
    """Points of a unit sphere (rings every 30 degrees of latitude, 12 each, and the poles), and the distance
    from the centre to the nearest face of their hull: scaled by r / that, their hull contains the sphere of
    radius r."""
    from scipy.spatial import ConvexHull

    rings = []
    for k, lat in enumerate(np.radians([-60.0, -30.0, 0.0, 30.0, 60.0])):
        turn = 2 * np.pi * (np.arange(12) + 0.5 * (k % 2)) / 12
        rings.append(np.column_stack([np.cos(lat) * np.cos(turn), np.cos(lat) * np.sin(turn), np.full(12, np.sin(lat))]))
    unit = np.vstack([*rings, [[0.0, 0.0, 1.0], [0.0, 0.0, -1.0]]])
    return unit, float(np.min(-ConvexHull(unit).equations[:, 3]))


SPHERE_POINTS, SPHERE_INSCRIBED = _sphere_points()


def capsule(radius: float, length: float) -> Convex:
    """A capsule along z (pybullet's URDF extension): a cylinder of `length` between two half-spheres.

    Around it, as for a mesh of many corners (`hull`): the 26 faces of its k-DOP, each touching it (its
    box is the capsule's own), and behind them points on two spheres pushed out until their hull holds
    it (5.6 % of the radius out at most); inside it, the hull of points on its surface."""
    from scipy.spatial import ConvexHull

    ends = np.array([[0.0, 0.0, -length / 2], [0.0, 0.0, length / 2]])
    around = np.column_stack([DOP, np.max(ends @ DOP.T, axis=0) + radius])
    pushed = np.vstack([end + radius / SPHERE_INSCRIBED * SPHERE_POINTS for end in ends])
    faces = ConvexHull(pushed).equations
    inner = hull(np.vstack([end + radius * SPHERE_POINTS for end in ends]))
    return Convex(_corners(around, np.zeros(3)), inner.planes, inside=inner.inner_points(), outside=around,
                  exact=(pushed, _distinct(np.column_stack([faces[:, :3], -faces[:, 3]]))))


def hull(vertices: np.ndarray) -> Convex:
    """The convex hull of a mesh's vertices: what pybullet collides with for a mesh.

    A hull of many corners (a scanned or CAD mesh: hundreds) would make every test slow, so past
    `MAX_CORNERS` it is held as two simpler polytopes: around it, the 26 faces of its k-DOP (the
    tightest polytope with faces across the axes, the face and the body diagonals; its box is the
    hull's own) and that polytope's corners; inside it, the hull of `MAX_CORNERS` of its corners
    spread over it (every point of that lies in the hull)."""
    from scipy.spatial import ConvexHull

    found = ConvexHull(vertices)
    points = vertices[found.vertices]
    planes = np.column_stack([found.equations[:, :3], -found.equations[:, 3]])  # n.x + c <= 0 -> n.x <= -c
    if len(points) <= MAX_CORNERS:
        return Convex(points, planes)
    inside = points[_spread(points, INSIDE_CORNERS)]
    sub = ConvexHull(inside)
    around = np.column_stack([DOP, np.max(points @ DOP.T, axis=0)])
    return Convex(_corners(around, points.mean(axis=0)), np.column_stack([sub.equations[:, :3], -sub.equations[:, 3]]),
                  inside=inside, outside=around, exact=(points, _distinct(planes)))


MAX_CORNERS = 40     # a hull with more corners is held as a k-DOP around it and a smaller hull inside it
INSIDE_CORNERS = 24  # corners of that smaller hull
DOP = np.array([d for d in ([1, 0, 0], [0, 1, 0], [0, 0, 1], [1, 1, 0], [1, -1, 0], [1, 0, 1], [1, 0, -1], [0, 1, 1],
                            [0, 1, -1], [1, 1, 1], [1, 1, -1], [1, -1, 1], [-1, 1, 1])
                for d in (np.array(d) / np.linalg.norm(d), -np.array(d) / np.linalg.norm(d))])


def _distinct(planes: np.ndarray) -> np.ndarray:
    """The planes without repeats (a face cut into triangles is one face)."""
    _, first = np.unique(np.round(planes, 9), axis=0, return_index=True)
    return planes[np.sort(first)]


def _spread(points: np.ndarray, count: int) -> np.ndarray:
    """Indices of `count` points spread over the set (farthest-point sampling from the first)."""
    chosen = [0]
    gap = np.linalg.norm(points - points[0], axis=1)
    for _ in range(count - 1):
        chosen.append(int(np.argmax(gap)))
        gap = np.minimum(gap, np.linalg.norm(points - points[chosen[-1]], axis=1))
    return np.array(chosen)


def _corners(planes: np.ndarray, interior: np.ndarray) -> np.ndarray:
    """The corners of the polytope n.x <= d (rows (n, d)) around an interior point."""
    from scipy.spatial import HalfspaceIntersection

    found = HalfspaceIntersection(np.column_stack([planes[:, :3], -planes[:, 3]]), interior)
    return np.unique(np.round(found.intersections, 12), axis=0)


def _edges(points: np.ndarray) -> np.ndarray:
    """(E, 2) index pairs of the convex hull's edges (every pair for degenerate, flat point sets)."""
    from scipy.spatial import ConvexHull, QhullError

    try:
        simplices = ConvexHull(points).simplices
    except (QhullError, ValueError):
        k = len(points)
        return np.array([(a, b) for a in range(k) for b in range(a + 1, k)], dtype=int).reshape(-1, 2)
    pairs = np.vstack([simplices[:, [0, 1]], simplices[:, [1, 2]], simplices[:, [0, 2]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)


def cover(element: Convex) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(outer centres, outer radii, inner centres, inner radii) of one element, in its frame.

    Outer: the element cut into slabs along its longest axis (about as long as it is thick); each
    slab's piece is convex, so a sphere around its corners (the hull's points inside the slab and
    where the hull's edges cross the slab's faces) contains it. Inner: a sphere at each piece's
    mean point, as large as the inner half-spaces allow."""
    if element.sphere is not None:
        c, r = element.sphere
        return c[None], np.array([r + PAD]), c[None], np.array([r * 0.999])
    pts = element.points
    centre = pts.mean(axis=0)
    _, _, vt = np.linalg.svd(pts - centre, full_matrices=False)
    axis = vt[0]
    t = (pts - centre) @ axis
    length = float(t.max() - t.min())
    across = float(np.max(np.linalg.norm((pts - centre) - np.outer(t, axis), axis=1)))
    count = int(min(8, max(1, math.ceil(length / max(1.2 * across, 1e-6)))))
    cuts = np.linspace(t.min(), t.max(), count + 1)
    edges = _edges(pts)
    a, b = t[edges[:, 0]], t[edges[:, 1]]
    outer_c, outer_r, inner_c, inner_r = [], [], [], []
    for lo, hi in zip(cuts[:-1], cuts[1:]):
        piece = [pts[(t >= lo - 1e-12) & (t <= hi + 1e-12)]]
        for s in (lo, hi):
            crossing = (np.minimum(a, b) < s) & (np.maximum(a, b) > s)
            if crossing.any():
                e = edges[crossing]
                w = ((s - t[e[:, 0]]) / (t[e[:, 1]] - t[e[:, 0]]))[:, None]
                piece.append(pts[e[:, 0]] + w * (pts[e[:, 1]] - pts[e[:, 0]]))
        corners = np.vstack(piece)
        mid = (corners.min(axis=0) + corners.max(axis=0)) / 2
        outer_c.append(mid)
        outer_r.append(float(np.max(np.linalg.norm(corners - mid, axis=1))) + PAD)
        if len(element.planes):
            inside = corners.mean(axis=0)
            depth = float(np.min(element.planes[:, 3] - element.planes[:, :3] @ inside))
            if depth > SURE_DEPTH:
                inner_c.append(inside)
                inner_r.append(depth)
    return (np.array(outer_c), np.array(outer_r), np.array(inner_c).reshape(-1, 3), np.array(inner_r))


# --- the robot's links, from the URDF pybullet loaded ------------------------------------------------

def _origin_of(el: ET.Element) -> tuple[np.ndarray, np.ndarray]:
    origin = el.find("origin")
    xyz = [float(v) for v in (origin.get("xyz") or "0 0 0").split()] if origin is not None else [0.0] * 3
    rpy = [float(v) for v in (origin.get("rpy") or "0 0 0").split()] if origin is not None else [0.0] * 3
    return _rpy_matrix(tuple(rpy)), np.array(xyz)  # type: ignore[arg-type]


def _mesh_vertices(filename: str, urdf_dir: Path, packages) -> np.ndarray | None:
    import trimesh

    path, _ = resolve_uri(filename, urdf_dir, packages)
    if path is None:
        return None
    try:
        loaded = trimesh.load(str(path), force="mesh", process=False)
    except Exception:  # noqa: BLE001 - any format trimesh cannot read: the link falls back to pybullet's box
        return None
    vertices = np.asarray(getattr(loaded, "vertices", np.zeros((0, 3))), dtype=float)
    return vertices if len(vertices) >= 4 else None


def link_elements(urdf: Path, packages=None) -> dict[str, list[Convex] | None]:
    """Link name -> its collision elements in the link frame; None for a link with a shape not read here."""
    root = ET.fromstring(declared(urdf.read_text(encoding="utf-8", errors="replace")))
    out: dict[str, list[Convex] | None] = {}
    for link in root.iter("link"):
        elements: list[Convex] = []
        readable = True
        for col in link.findall("collision"):
            geometry = col.find("geometry")
            shape = geometry[0] if geometry is not None and len(geometry) else None
            element: Convex | None = None
            try:
                if shape is None:
                    continue
                if shape.tag == "box":
                    element = box([float(v) for v in shape.attrib["size"].split()])
                elif shape.tag == "cylinder":
                    element = cylinder(float(shape.attrib["radius"]), float(shape.attrib["length"]), PYBULLET_SIDES)
                elif shape.tag == "sphere":
                    element = sphere(float(shape.attrib["radius"]))
                elif shape.tag == "capsule":
                    element = capsule(float(shape.attrib["radius"]), float(shape.attrib["length"]))
                elif shape.tag == "mesh":
                    vertices = _mesh_vertices(shape.attrib["filename"], urdf.parent, packages)
                    scale = [float(v) for v in (shape.get("scale") or "1 1 1").split()]
                    element = hull(vertices * np.array(scale)) if vertices is not None else None
            except (KeyError, ValueError, IndexError):
                element = None
            except Exception:  # noqa: BLE001 - qhull on a flat mesh and the like: pybullet's box stands in
                element = None
            if element is None:
                readable = False
                break
            rot, pos = _origin_of(col)
            elements.append(element.moved(rot, pos))
        out[link.get("name", "")] = elements if readable else None
    return out


# --- the scene's bodies, from the pybullet world that holds them --------------------------------------

def _pose(pos, orn) -> tuple[np.ndarray, np.ndarray]:
    from scipy.spatial.transform import Rotation

    return Rotation.from_quat(orn).as_matrix(), np.asarray(pos, dtype=float)


def _aabb_box(lo, hi) -> Convex:
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    element = box(hi - lo).moved(np.eye(3), (lo + hi) / 2)
    return Convex(element.points, np.zeros((0, 4)))  # pybullet's box around it: nothing surely inside


def _aabb(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    return points.min(axis=0), points.max(axis=0)


def within(elements: list[Convex], lo, hi) -> bool:
    """Do these elements (world frame) lie inside pybullet's own AABB of them (grown by `MATCH`)?
    (pybullet's AABB of a turned hull is the box around its turned local box: often far larger.)"""
    if not elements:
        return True
    mine_lo, mine_hi = _aabb(np.vstack([e.points for e in elements]))
    return bool(np.all(mine_lo >= np.asarray(lo) - MATCH) and np.all(mine_hi <= np.asarray(hi) + MATCH))


def matches(elements: list[Convex], lo, hi) -> bool:
    """Do these elements (world frame) span pybullet's own AABB of them, within `MATCH` per side?"""
    if not elements:
        return bool(np.all(np.asarray(hi) - np.asarray(lo) < 2 * MATCH))
    mine_lo, mine_hi = _aabb(np.vstack([e.points for e in elements]))
    return bool(np.all(np.abs(mine_lo - lo) <= MATCH) and np.all(np.abs(mine_hi - hi) <= MATCH))


def scene_elements(pb, client: int, body: int) -> list[Convex]:
    """A scene body's collision elements in the world frame: its boxes, spheres and cylinders as pybullet
    holds them; any other shape, or a link whose shapes do not match pybullet's AABB, as that AABB. A scan
    (`scan_bodies`): its padded boxes, where pybullet holds their surface in a few big triangle meshes."""
    from tdgen.robot.scan_bodies import fast_elements

    known = fast_elements(pb, client, body)
    if known is not None:
        return [Convex(corners, planes, outside=planes) for corners, planes in known]
    out = []
    for link in range(-1, pb.getNumJoints(body, physicsClientId=client)):
        lo, hi = pb.getAABB(body, link, physicsClientId=client)
        shapes = pb.getCollisionShapeData(body, link, physicsClientId=client)
        if link == -1:
            frame = _pose(*pb.getBasePositionAndOrientation(body, physicsClientId=client))
        else:
            state = pb.getLinkState(body, link, physicsClientId=client)
            frame = _pose(state[0], state[1])
        elements: list[Convex] = []
        for shape in shapes if len(shapes) == 1 else []:  # several shapes: pybullet's frames are not reliable
            kind, dims = shape[2], shape[3]
            local = _pose(shape[5], shape[6])
            if kind == pb.GEOM_BOX:
                element = box(dims)
            elif kind == pb.GEOM_SPHERE:
                element = sphere(dims[0])
            elif kind == pb.GEOM_CYLINDER:
                element = cylinder(dims[1], dims[0])
            else:
                break
            rot = frame[0] @ local[0]
            elements.append(element.moved(rot, frame[0] @ local[1] + frame[1]))
        if not shapes:
            continue
        if len(elements) != len(shapes) or not matches(elements, lo, hi):
            elements = [_aabb_box(lo, hi)]
        out.extend(elements)
    return out


def outer_planes(element: Convex) -> np.ndarray:
    """(P, 4) half-spaces whose intersection contains the element (its points' convex hull)."""
    from scipy.spatial import ConvexHull, QhullError

    if element.outside is not None:
        return element.outside
    try:
        found = ConvexHull(element.points)
    except QhullError:  # flat, a line or a point (a URDF's zero-radius sphere): the faces of its bounding box
        lo, hi = element.points.min(axis=0), element.points.max(axis=0)
        return np.array([[1.0, 0, 0, hi[0]], [-1.0, 0, 0, -lo[0]], [0, 1.0, 0, hi[1]], [0, -1.0, 0, -lo[1]],
                         [0, 0, 1.0, hi[2]], [0, 0, -1.0, -lo[2]]])
    return _distinct(np.column_stack([found.equations[:, :3], -found.equations[:, 3]]))
