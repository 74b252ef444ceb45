"""Scene bodies from scans and CAD meshes, as pybullet collision shapes the exact test and the fast model read.

- A point cloud becomes the voxels its points fall in, merged into as few boxes as a greedy sweep
  along x, y then z finds, each grown by `PAD` so that nothing within `PAD` of a scanned point can be
  called free; a point never lies more than a voxel's diagonal plus `PAD` inside a box, so what
  keeps that far from every point is free.
- A closed mesh that is convex stays one hull; a closed non-convex one is split into convex hulls
  by CoACD; an open surface (a scanned room, one wall) stays a surface, a static
  triangle mesh, never filled to its hull.

pybullet gives a body at most `MAX_PARTS` links and a compound shape few children, so each body's
pieces are split into at most that many spatial groups (a k-d split along the widest axis), each
one link: a triangle mesh of its boxes' faces, a patch of the surface, or one hull. The fast model
(`spheres.scene_elements`) sees each link as the box around it and leaves what touches that box to
the exact test. Everything is made once per file content, voxel and scale, and kept under the cache
dir (`$TWINMESH_CACHE/scans`, or `~/.cache/twinmesh/scans`).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import time
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from tdgen.robot.errors import SceneError
from tdgen.robot.scan_io import content_digest, read_cloud, read_mesh

PAD = 0.006  # m each box grows: a sample within 5 mm of a scanned point collides (pybullet counts 0.1 mm deep)
DEFAULT_VOXEL = 0.02  # m
COACD_THRESHOLD = 0.05  # CoACD's concavity bound (of the mesh's size): lower makes more, tighter parts
MAX_PARTS = 128  # pybullet's links per created body (127) and its base
FORMAT = 5  # the cache entries' layout: a change makes old entries unused


@dataclass
class Prepared:
    """A scan or mesh body ready to build: its pieces in the body's own frame."""

    kind: str  # "voxels" (in the scene frame), "hull", "hulls" or "surface" (in the body's frame)
    parts: list[tuple[np.ndarray, np.ndarray]]  # per link: (vertices (V, 3), triangles (T, 3)); no triangles: a hull
    stats: dict[str, int] = field(default_factory=dict)  # points kept, voxels, boxes, hulls, triangles
    low: np.ndarray = field(default_factory=lambda: np.zeros(3))  # bounding box in the body frame (m)
    high: np.ndarray = field(default_factory=lambda: np.zeros(3))
    boxes: np.ndarray = field(default_factory=lambda: np.zeros((0, 2, 3)))  # voxels: the padded boxes (low, high)
    seconds: float = 0.0  # to read and prepare (or take from the cache)
    cached: bool = False
    key: str = ""  # its cache key: what a body built from it is marked with (`build`)
    fields: dict[tuple, Clearance] = field(default_factory=dict)  # voxels: its distance fields by region (`clearance`)


def cache_dir() -> Path:
    root = os.environ.get("TWINMESH_CACHE")
    return (Path(root).expanduser() if root else Path.home() / ".cache" / "twinmesh") / "scans"


_MEMORY: OrderedDict[str, Prepared] = OrderedDict()  # by cache key: the file's content and the parameters
KEPT = 8  # scans and meshes kept in memory, the last used (a depth camera's newest clouds); the rest on disk


def prepare_points(path: Path, voxel: float = DEFAULT_VOXEL, scale: float = 1.0,
                   position=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0)) -> Prepared:
    """The cloud in `path`, seen by a sensor at `position`/`rpy` (m, degrees fixed-axis), as padded voxel
    boxes in the scene frame: the grid is the scene's, so walls and floors along its axes merge into
    few boxes and each group's box is tight."""
    def make() -> Prepared:
        return _voxels(placed(read_cloud(path, scale), position, rpy), voxel)

    return _prepared(path, ("points", voxel, scale, tuple(position), tuple(rpy)), make)


def placed(points: np.ndarray, position, rpy) -> np.ndarray:
    """Points (N, 3) in the sensor's frame -> the scene frame, the sensor at `position`/`rpy` (m, degrees
    fixed-axis). By einsum, not a matrix product: 300,000 rows wake BLAS's threads, which then spin on a
    core for a while after (a tenth of a second of CPU on a shared machine)."""
    from scipy.spatial.transform import Rotation

    turn = Rotation.from_euler("xyz", rpy, degrees=True).as_matrix()
    return np.einsum("nj,ij->ni", points, turn) + np.asarray(position, dtype=float)


def prepare_mesh(path: Path, scale: float = 1.0) -> Prepared:
    """The mesh in `path` as one hull, convex hulls (closed, non-convex) or a surface (open)."""
    return _prepared(path, ("mesh", scale), lambda: _mesh(read_mesh(path, scale)))


def _prepared(path: Path, params: tuple, make) -> Prepared:
    """`make()` once per file content and `params`: from memory, from the cache dir, or made and kept.
    Known by content, never by a file's time: a scan written again within the clock's tick is new."""
    start = time.perf_counter()
    digest = content_digest(path) if path.is_file() else ""
    key = hashlib.sha256(repr((FORMAT, digest, params)).encode()).hexdigest()[:32]
    if digest and key in _MEMORY:
        _MEMORY.move_to_end(key)
        return _MEMORY[key]
    entry = cache_dir() / f"{key}.npz"
    prepared = _load(entry) if digest else None
    if prepared is None:
        prepared = make()
        if digest:
            _store(entry, prepared)
    else:
        prepared.cached = True
    prepared.seconds = time.perf_counter() - start
    prepared.key = key
    _MEMORY[key] = prepared
    while len(_MEMORY) > KEPT:  # a body built from it keeps only its boxes (`_BUILT`): parts and fields go
        _, gone = _MEMORY.popitem(last=False)
        gone.parts, gone.fields = [], {}
    return prepared


def _store(entry: Path, p: Prepared) -> None:
    """The pieces as two arrays and their lengths, the stats as names and numbers: nothing pickled, so the entry
    is read with `allow_pickle=False` (a cache entry is data, never code)."""
    vertices = [v for v, _ in p.parts]
    triangles = [t for _, t in p.parts]
    arrays: dict[str, np.ndarray] = {
        "kind": np.array(p.kind), "low": p.low, "high": p.high, "boxes": p.boxes,
        "stat_names": np.array(list(p.stats), dtype=str), "stat_values": np.array(list(p.stats.values()), dtype=np.int64),
        "vertices": np.concatenate(vertices) if vertices else np.zeros((0, 3)),
        "triangles": np.concatenate(triangles) if triangles else np.zeros((0, 3), dtype=np.int64),
        "vertex_counts": np.array([len(v) for v in vertices], dtype=np.int64),
        "triangle_counts": np.array([len(t) for t in triangles], dtype=np.int64)}
    try:
        entry.parent.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=entry.parent, suffix=".npz", delete=False) as f:
            np.savez(f, **arrays)  # type: ignore[arg-type]
        os.replace(f.name, entry)  # whole or not at all
    except OSError:  # a read-only cache dir costs time, not correctness
        pass


def _load(entry: Path) -> Prepared | None:
    try:
        with np.load(entry, allow_pickle=False) as z:
            vertex_counts, triangle_counts = z["vertex_counts"], z["triangle_counts"]
            vertices = np.split(z["vertices"], np.cumsum(vertex_counts)[:-1]) if len(vertex_counts) else []
            triangles = np.split(z["triangles"], np.cumsum(triangle_counts)[:-1]) if len(triangle_counts) else []
            stats = {str(a): int(b) for a, b in zip(z["stat_names"], z["stat_values"])}
            return Prepared(str(z["kind"]), list(zip(vertices, triangles)), stats, z["low"], z["high"], z["boxes"])
    except (OSError, KeyError, ValueError):
        return None


def _voxels(points: np.ndarray, voxel: float) -> Prepared:
    """The occupied voxels' outer faces (faces between an occupied and an empty voxel), merged into
    rectangles, each pushed out by `PAD` and widened by `PAD` on every side: the padded voxels' surface
    with few triangles (pybullet's cost grows with the triangles a link overlaps)."""
    raw = np.floor(points / voxel).astype(np.int64)
    low = _column_min(raw) - 1  # a neighbour's key stays in range
    occupied = np.unique(_packed(raw - low))  # sorted: the cells in x, y, z order
    cells = _unpacked(occupied) + low
    box_lo, box_hi = merge_cells(cells)
    boxes = np.stack([box_lo * voxel - PAD, (box_hi + 1) * voxel + PAD], axis=1)
    rects_lo, rects_hi = [], []
    for axis in range(3):
        step = np.zeros(3, dtype=np.int64)
        step[axis] = 1
        for sign in (1, -1):
            neighbour = _packed(cells - low + sign * step)
            at = np.minimum(np.searchsorted(occupied, neighbour), len(occupied) - 1)
            faces = cells[occupied[at] != neighbour]  # the side towards an empty voxel
            if not len(faces):
                continue
            lo, hi = merge_cells(faces, [a for a in range(3) if a != axis])
            lo_m, hi_m = lo * voxel - PAD, (hi + 1) * voxel + PAD  # widened in the face's plane
            plane = (lo[:, axis] + (1 if sign > 0 else 0)) * voxel + sign * PAD
            lo_m[:, axis] = hi_m[:, axis] = plane
            rects_lo.append(lo_m)
            rects_hi.append(hi_m)
    lows, highs = np.vstack(rects_lo), np.vstack(rects_hi)
    parts = [_rect_mesh(lows[g], highs[g]) for g in _split((lows + highs) / 2, MAX_PARTS)]
    stats = {"points": len(points), "voxels": len(cells), "boxes": len(boxes), "faces": len(lows)}
    return Prepared("voxels", parts, stats, _column_min(lows), _column_max(highs), boxes)


_BITS = 21  # per axis in a cell's key: 2 million voxels across


def _packed(cells: np.ndarray) -> np.ndarray:
    """Cells (N, 3) of non-negative coordinates as one int64 each, in the order of their coordinates: sorting
    and looking up 300,000 cells as numbers, not as rows or tuples."""
    if len(cells) and int(cells.max()) >= 1 << _BITS:
        raise SceneError(f"a scan more than {1 << _BITS:,} voxels across: give it a larger voxel")
    return (cells[:, 0] << (2 * _BITS)) | (cells[:, 1] << _BITS) | cells[:, 2]


def _unpacked(keys: np.ndarray) -> np.ndarray:
    mask = (1 << _BITS) - 1
    return np.column_stack([keys >> (2 * _BITS), (keys >> _BITS) & mask, keys & mask])


def merge_cells(cells: np.ndarray, axes=(0, 1, 2)) -> tuple[np.ndarray, np.ndarray]:
    """Occupied integer cells (N, 3) -> boxes (lowest cell, highest cell), (B, 3) each, covering exactly
    them: runs along the first of `axes`, then runs of equal runs along the next, and so on."""
    lo, hi = cells.copy(), cells.copy()
    for axis in axes:
        others = [a for a in range(3) if a != axis]
        # boxes that agree on everything but `axis` and touch along it are one
        keys = np.column_stack([lo[:, others], hi[:, others]])
        packed = _row_keys(np.column_stack([keys, lo[:, axis]]))
        if packed is None:  # too wide for one int64: sorted as rows
            order = np.lexsort((lo[:, axis], *keys.T[::-1]))
            lo, hi, keys = lo[order], hi[order], keys[order]
            agree = np.all(keys[1:] == keys[:-1], axis=1)
        else:  # the same order (no two boxes share their other sides and their low end: they would overlap)
            order = np.argsort(packed)
            lo, hi, packed = lo[order], hi[order], packed[order]
            group = packed >> _bits(lo[:, axis])
            agree = group[1:] == group[:-1]
        same = agree & (lo[1:, axis] == hi[:-1, axis] + 1)
        starts = np.flatnonzero(np.concatenate([[True], ~same]))
        ends = np.concatenate([starts[1:], [len(lo)]]) - 1
        new_hi = hi[starts].copy()
        new_hi[:, axis] = hi[ends, axis]
        lo, hi = lo[starts], new_hi
    return lo, hi


def _column_min(rows: np.ndarray) -> np.ndarray:
    """`rows.min(axis=0)` column by column: numpy reduces a few columns of many rows an order slower."""
    return np.array([rows[:, k].min() for k in range(rows.shape[1])], dtype=rows.dtype)


def _column_max(rows: np.ndarray) -> np.ndarray:
    """`rows.max(axis=0)`, as `_column_min`."""
    return np.array([rows[:, k].max() for k in range(rows.shape[1])], dtype=rows.dtype)


def _bits(column: np.ndarray) -> int:
    return int(column.max() - column.min()).bit_length() if len(column) else 0


def _row_keys(rows: np.ndarray) -> np.ndarray | None:
    """Integer rows (N, k) as one int64 each, ordered and equal as the rows are (the last column lowest), or
    None when their spans need more than 63 bits: one sort of numbers, not a sort by k columns."""
    if not len(rows):
        return np.zeros(0, dtype=np.int64)
    spans = rows - _column_min(rows)
    widths = [_bits(spans[:, k]) for k in range(rows.shape[1])]
    if sum(widths) > 63:
        return None
    packed = np.zeros(len(rows), dtype=np.int64)
    for k, width in enumerate(widths):
        packed = (packed << width) | spans[:, k]
    return packed


def _rect_mesh(lows: np.ndarray, highs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Axis-aligned rectangles (flat along one axis: low == high there), two triangles each."""
    flat = np.argmax(lows == highs, axis=1)
    u, v = (flat + 1) % 3, (flat + 2) % 3
    rows = np.arange(len(lows))
    verts = np.repeat(lows[:, None, :], 4, axis=1)
    for k, (du, dv) in enumerate(((0, 0), (1, 0), (1, 1), (0, 1))):
        if du:
            verts[rows, k, u] = highs[rows, u]
        if dv:
            verts[rows, k, v] = highs[rows, v]
    faces = np.array([[0, 1, 2], [0, 2, 3]])[None] + 4 * rows[:, None, None]
    return verts.reshape(-1, 3), faces.reshape(-1, 3)


def _split(centres: np.ndarray, groups: int) -> list[np.ndarray]:
    """Indices of `centres` in at most `groups` spatial groups, halved along the widest axis in turn."""
    pending = [np.arange(len(centres))]
    while len(pending) < groups:
        k = max(range(len(pending)), key=lambda i: len(pending[i]))
        idx = pending[k]
        if len(idx) < 2:
            break
        pts = centres[idx]
        axis = int(np.argmax(_column_max(pts) - _column_min(pts)))
        half = len(idx) // 2
        order = idx[np.argpartition(pts[:, axis], half)]  # the lower half first, each half in no order
        pending[k:k + 1] = [order[:half], order[half:]]
    return [p for p in pending if len(p)]


def _mesh(mesh) -> Prepared:
    stats = {"triangles": len(mesh.faces)}
    low, high = mesh.bounds
    if not mesh.is_watertight:  # an open surface: patches of its own triangles
        centres = mesh.triangles_center
        parts = []
        for group in _split(centres, MAX_PARTS):
            sub = mesh.submesh([group], append=True, repair=False)
            parts.append((np.asarray(sub.vertices), np.asarray(sub.faces)))
        return Prepared("surface", parts, stats, low, high)
    if mesh.is_convex:
        return Prepared("hull", [(np.asarray(mesh.vertices), np.zeros((0, 3), dtype=np.int64))],
                        stats | {"hulls": 1}, low, high)
    hulls = decompose(mesh)
    return Prepared("hulls", [(h, np.zeros((0, 3), dtype=np.int64)) for h in hulls],
                    stats | {"hulls": len(hulls)}, low, high)


def decompose(mesh) -> list[np.ndarray]:
    """A closed mesh's convex parts (each its corners), at most `MAX_PARTS`, by CoACD (collision-aware:
    a ring's hole stays open), which is several times quicker here than pybullet's V-HACD."""
    import coacd
    import trimesh

    coacd.set_log_level("error")
    parts = coacd.run_coacd(coacd.Mesh(np.asarray(mesh.vertices), np.asarray(mesh.faces)), threshold=COACD_THRESHOLD,
                            max_convex_hull=MAX_PARTS, preprocess_mode="off", resolution=1000, mcts_iterations=50,
                            mcts_max_depth=2, seed=0)
    hulls = [np.asarray(v) for v, _ in parts if len(v) >= 4]
    if not hulls:  # nothing found: the whole hull, which is too much but never too little
        return [np.asarray(trimesh.convex.convex_hull(mesh.vertices).vertices)]
    return hulls


BUILT_FROM = "twinmesh-built-from"  # a built body's pybullet user data: the key of what it was built from
_BUILT: dict[str, Prepared] = {}  # by that key


def boxes_of(pb, client: int, body: int) -> np.ndarray | None:
    """The padded boxes (B, 2, 3), scene frame, of a scan body built here, else None: what the fast
    model can take for it instead of the box around each group of faces. Known by the body's own mark,
    which goes with it: pybullet gives a removed body's id to the next one made."""
    held = scan_of(pb, client, body)
    return held.boxes if held is not None else None


def fast_elements(pb, client: int, body: int) -> list[tuple[np.ndarray, np.ndarray]] | None:
    """`fast_boxes` one element at a time: (corners, half-spaces) per box."""
    boxes = fast_boxes(pb, client, body)
    return None if boxes is None else list(zip(*boxes))


def fast_boxes(pb, client: int, body: int) -> tuple[np.ndarray, np.ndarray] | None:
    """A scan body's padded boxes as the fast model's elements (scene frame), all at once: corners (B, 8, 3)
    and half-spaces (B, 6, 4), for `spheres.Convex(corners, planes, outside=planes)` each; None for any other
    body. Solid boxes where pybullet holds their padded union's surface: a link overlaps a box deeper than
    the fast model's sure depth only through that surface, as scanned shells are a voxel or two thick.
    Boxes longer than `FAST_PIECE` are cut into pieces: the model skips a box that a sphere around it keeps
    from a link's sphere, and the sphere around a run the length of the floor meets every link."""
    boxes = boxes_of(pb, client, body)
    if boxes is None:
        return None
    lo, hi = _pieces(boxes[:, 0], boxes[:, 1], FAST_PIECE)
    signs = np.array([[i, j, k] for i in (0, 1) for j in (0, 1) for k in (0, 1)])
    corners = np.where(signs[None].astype(bool), hi[:, None, :], lo[:, None, :])  # (B, 8, 3)
    normals = np.array([[-1.0, 0, 0], [1.0, 0, 0], [0, -1.0, 0], [0, 1.0, 0], [0, 0, -1.0], [0, 0, 1.0]])
    offsets = np.stack([-lo[:, 0], hi[:, 0], -lo[:, 1], hi[:, 1], -lo[:, 2], hi[:, 2]], axis=1)  # n.x <= d
    planes = np.concatenate([np.broadcast_to(normals, (len(lo), 6, 3)), offsets[..., None]], axis=2)
    return corners, planes


FAST_PIECE = 0.3  # m: the longest side of a box as the fast model takes it (its broad phase's cell)
FIELD_CELL = 0.02  # m: the distance field's cell, unless the scan's extent needs larger ones
FIELD_CELLS = 8_000_000  # at most, in a distance field (float32: 32 MB)


@dataclass
class Clearance:
    """How far every place is from a scan's padded boxes, on a grid: one lookup per sphere instead of
    a sphere against thousands of boxes. Conservative: `distance` is never more than the true one."""

    origin: np.ndarray  # (3,) the grid's low corner, scene frame (m)
    cell: float  # m
    centres: np.ndarray  # (X, Y, Z) float32: at most the distance from each cell's centre to the nearest occupied one's (m)

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(..., 3) points, scene frame -> (...) a lower bound of their distance to the boxes (m; <= 0: may
        touch). A point outside the grid is taken at its nearest place on it, which is no further from
        any box (all are on the grid); a point and a box's point may each lie anywhere in their cells, so
        a cell's diagonal comes off the centres' distance."""
        shape = np.asarray(self.centres.shape)
        at = np.floor((points - self.origin) / self.cell).astype(np.int64)
        np.clip(at, 0, shape - 1, out=at)
        return self.centres[at[..., 0], at[..., 1], at[..., 2]] - self.cell * np.sqrt(3.0)


def clearance(prepared: Prepared, within: tuple[np.ndarray, np.ndarray] | None = None) -> Clearance:
    """The distance field of a scan's padded boxes, made once per scan and region (held with it): every
    cell that any box reaches into is occupied, and each cell gets its chessboard distance (in cells, times
    the cell) to the nearest occupied one, which is never more than the Euclidean one between their centres.
    scipy's chamfer transform makes it several times quicker than its exact Euclidean one, and clears
    nearly as many samples: a link's spheres near the scan are near it by either measure.

    `within` (low, high corners, scene frame): the only region asked about (where a robot reaches): the
    grid ends there, each box pulled in onto it (no nearer to a place inside than it was), and the grid's
    outer layer on a side where boxes were cut is occupied, so that a place beyond the region is never
    cleared. Only what is asked gets quicker; what is answered stays a lower bound everywhere."""
    lo, hi = prepared.boxes[:, 0], prepared.boxes[:, 1]
    low, high = lo.min(axis=0), hi.max(axis=0)
    cut_low = cut_high = np.zeros(3, dtype=bool)
    if within is not None:
        w_lo, w_hi = (np.asarray(v, dtype=float) for v in within)
        if np.all(np.maximum(low, w_lo) < np.minimum(high, w_hi)):  # else the whole scan: it lies beyond the region
            cut_low, cut_high = low < w_lo, high > w_hi
            lo, hi = np.clip(lo, w_lo, w_hi), np.clip(hi, w_lo, w_hi)
            low, high = np.maximum(low, w_lo), np.minimum(high, w_hi)
    key = (*np.round(low, 4), *np.round(high, 4), *cut_low, *cut_high)
    if key in prepared.fields:
        return prepared.fields[key]
    from scipy.ndimage import distance_transform_cdt

    cell = max(FIELD_CELL, float(np.cbrt(np.prod(high - low + 2 * FIELD_CELL) / FIELD_CELLS)) * 1.01)
    origin = low - cell  # a free layer all round: the field is measured from inside the grid
    shape = np.floor((high - origin) / cell).astype(np.int64) + 2
    first = np.floor((lo - origin) / cell).astype(np.int64)  # the cells a box's points can lie in
    last = np.floor((hi - origin) / cell).astype(np.int64) + 1
    free = np.ones(tuple(shape), dtype=bool)
    for (a, b, c), (x, y, z) in zip(first, last):
        free[a:x, b:y, c:z] = False
    for axis in range(3):  # beyond a cut side: never cleared
        if cut_low[axis]:
            free[(slice(None),) * axis + (0,)] = False
        if cut_high[axis]:
            free[(slice(None),) * axis + (-1,)] = False
    steps = distance_transform_cdt(free, metric="chessboard")  # exact for this metric: 26 neighbours, each 1
    centres = steps.astype(np.float32)
    centres *= np.float32(cell)
    prepared.fields[key] = Clearance(origin, cell, centres)
    return prepared.fields[key]


def scan_of(pb, client: int, body: int) -> Prepared | None:
    """The prepared scan a body was built from (`build`), else None (any other body)."""
    try:
        mark = pb.getUserDataId(body, BUILT_FROM, physicsClientId=client)
        if mark < 0:
            return None
        key = pb.getUserData(mark, physicsClientId=client)
    except pb.error:  # a client since closed
        return None
    held = _BUILT.get(key.decode() if isinstance(key, bytes) else str(key))
    return held if held is not None and held.kind == "voxels" else None


def _pieces(lo: np.ndarray, hi: np.ndarray, longest: float) -> tuple[np.ndarray, np.ndarray]:
    """Boxes (low, high corners, (B, 3) each) cut into equal pieces no longer than `longest` along any axis,
    which tile them exactly (a cut is the same number on both of its sides)."""
    parts = np.maximum(1, np.ceil((hi - lo) / longest)).astype(np.int64)  # (B, 3) pieces per axis
    counts = parts.prod(axis=1)
    box = np.repeat(np.arange(len(lo)), counts)
    k = np.arange(int(counts.sum())) - np.repeat(np.cumsum(counts) - counts, counts)  # the piece within its box
    n = parts[box]
    at = np.column_stack([k // (n[:, 1] * n[:, 2]), (k // n[:, 2]) % n[:, 1], k % n[:, 2]])
    step = (hi - lo)[box] / n
    return lo[box] + at * step, np.where(at + 1 == n, hi[box], lo[box] + (at + 1) * step)


_LISTS: tuple[Prepared, list[tuple[list, list]]] | None = None
"""The last built body's parts as pybullet takes them: a generation builds a scan into two worlds in a row.
Only the last: a scan's lists are ~100,000 Python lists, which every full garbage collection walks."""


def build(prepared: Prepared, position, orientation, client: int) -> int:
    """The body in pybullet client `client`: a static body whose links are the prepared parts."""
    import pybullet as pb

    global _LISTS
    if _LISTS is None or _LISTS[0] is not prepared:
        _LISTS = (prepared, [(verts.tolist(), tris.reshape(-1).tolist()) for verts, tris in prepared.parts])
    shapes = []
    for verts, tris in _LISTS[1]:
        if len(tris):
            shapes.append(pb.createCollisionShape(pb.GEOM_MESH, vertices=verts, indices=tris,
                                                  flags=pb.GEOM_FORCE_CONCAVE_TRIMESH, physicsClientId=client))
        else:
            shapes.append(pb.createCollisionShape(pb.GEOM_MESH, vertices=verts, physicsClientId=client))
    base, links = shapes[0], shapes[1:]
    n = len(links)
    body = pb.createMultiBody(0.0, base, -1, list(position), list(orientation), linkMasses=[0.0] * n,
                              linkCollisionShapeIndices=links, linkVisualShapeIndices=[-1] * n,
                              linkPositions=[[0.0, 0.0, 0.0]] * n, linkOrientations=[[0.0, 0.0, 0.0, 1.0]] * n,
                              linkInertialFramePositions=[[0.0, 0.0, 0.0]] * n,
                              linkInertialFrameOrientations=[[0.0, 0.0, 0.0, 1.0]] * n, linkParentIndices=[0] * n,
                              linkJointTypes=[pb.JOINT_FIXED] * n, linkJointAxis=[[0.0, 0.0, 1.0]] * n,
                              physicsClientId=client)
    key = prepared.key or f"unkept-{id(prepared)}"
    _BUILT[key] = prepared
    pb.addUserData(body, BUILT_FROM, key, physicsClientId=client)
    return body
