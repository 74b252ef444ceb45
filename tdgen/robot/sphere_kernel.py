"""The compiled loop of the fast collision model: one configuration per iteration, all cores.

numpy would hold N x sphere-pairs arrays and walk memory several times per test; this loop keeps
one configuration's link frames and spheres in a few hundred numbers (allocated once per block of
configurations) and stops at the first sure answer. Compiled once per machine and kept in the
user's cache directory (`cores`). The model's tables travel as one `Tables`
value, each table named once there; a verdict is FREE, COLLIDES or UNSURE (for the exact test).
See `fast_collision` for the model.
"""
from __future__ import annotations

from typing import Annotated, NamedTuple, get_type_hints

import numpy as np
import numpy.typing as npt

from tdgen.robot.cores import njit, prange

# verdicts; numba compiles module-level numbers in as constants
FREE, COLLIDES, UNSURE = 0, 1, 2

BLOCKS = 64  # blocks of configurations the cores share
# reordered and fused arithmetic (a fifth faster); never the flags that assume no infinities (the loops start
# from +-inf) or approximate functions (the joints' sines and cosines). The answers keep their margins (PAD,
# SURE_DEPTH: millimetres), far beyond what reordering changes (1e-16 relative).
FAST = {"contract", "reassoc", "nsz", "arcp"}


@njit(cache=True, inline="always", fastmath=FAST)
def _move(rot, pos, k, p, out, i):
    """out[i] = rot[k] @ p + pos[k]"""
    for r in range(3):
        out[i, r] = rot[k, r, 0] * p[0] + rot[k, r, 1] * p[1] + rot[k, r, 2] * p[2] + pos[k, r]


@njit(cache=True, inline="always", fastmath=FAST)
def _frames(values, parent, origin_r, origin_p, kind, axis, base_r, base_p, rot, pos, tmp):
    count = parent.shape[0]
    for r in range(3):  # element by element: no array copy, so no allocation (`_block` runs without numba's runtime)
        pos[0, r] = base_p[r]
        for c in range(3):
            rot[0, r, c] = base_r[r, c]
    for k in range(1, count):
        up = parent[k]
        for r in range(3):
            pos[k, r] = pos[up, r]
            for c in range(3):
                pos[k, r] += rot[up, r, c] * origin_p[k, c]
                tmp[r, c] = rot[up, r, 0] * origin_r[k, 0, c] + rot[up, r, 1] * origin_r[k, 1, c] \
                    + rot[up, r, 2] * origin_r[k, 2, c]
        if kind[k] == 1:
            x, y, z = axis[k, 0], axis[k, 1], axis[k, 2]
            c, s = np.cos(values[k]), np.sin(values[k])
            t = 1.0 - c
            m00, m01, m02 = t * x * x + c, t * x * y - s * z, t * x * z + s * y
            m10, m11, m12 = t * x * y + s * z, t * y * y + c, t * y * z - s * x
            m20, m21, m22 = t * x * z - s * y, t * y * z + s * x, t * z * z + c
            for r in range(3):
                a, b, d = tmp[r, 0], tmp[r, 1], tmp[r, 2]
                rot[k, r, 0] = a * m00 + b * m10 + d * m20
                rot[k, r, 1] = a * m01 + b * m11 + d * m21
                rot[k, r, 2] = a * m02 + b * m12 + d * m22
        else:
            for r in range(3):
                for c in range(3):
                    rot[k, r, c] = tmp[r, c]
            if kind[k] == 2:
                for r in range(3):
                    pos[k, r] += (tmp[r, 0] * axis[k, 0] + tmp[r, 1] * axis[k, 1] + tmp[r, 2] * axis[k, 2]) * values[k]


@njit(cache=True, inline="always", fastmath=FAST)
def _dist2(a, i, b, j):
    x, y, z = a[i, 0] - b[j, 0], a[i, 1] - b[j, 1], a[i, 2] - b[j, 2]
    return x * x + y * y + z * z


@njit(cache=True, fastmath=FAST)
def _beyond(planes, n_planes, plane_rot, plane_pos, points, n_points, rot_b, pos_b, pad):
    """A face (half-spaces in the frame plane_rot, plane_pos) with every corner of a hull (its link's
    frame rot_b, pos_b) beyond it by more than `pad`: the two are apart."""
    for j in range(n_planes):
        nx = plane_rot[0, 0] * planes[j, 0] + plane_rot[0, 1] * planes[j, 1] + plane_rot[0, 2] * planes[j, 2]
        ny = plane_rot[1, 0] * planes[j, 0] + plane_rot[1, 1] * planes[j, 1] + plane_rot[1, 2] * planes[j, 2]
        nz = plane_rot[2, 0] * planes[j, 0] + plane_rot[2, 1] * planes[j, 1] + plane_rot[2, 2] * planes[j, 2]
        offset = planes[j, 3] + nx * plane_pos[0] + ny * plane_pos[1] + nz * plane_pos[2] + pad
        # the normal in the hull's frame: its corners need no moving
        lx = rot_b[0, 0] * nx + rot_b[1, 0] * ny + rot_b[2, 0] * nz
        ly = rot_b[0, 1] * nx + rot_b[1, 1] * ny + rot_b[2, 1] * nz
        lz = rot_b[0, 2] * nx + rot_b[1, 2] * ny + rot_b[2, 2] * nz
        lo = offset - (pos_b[0] * nx + pos_b[1] * ny + pos_b[2] * nz)
        apart = True
        for v in range(n_points):
            if points[v, 0] * lx + points[v, 1] * ly + points[v, 2] * lz <= lo:
                apart = False
                break
        if apart:
            return True
    return False


@njit(cache=True, inline="always", fastmath=FAST)
def _point_deep_in(wx, wy, wz, planes, n_planes, plane_rot, plane_pos, depth):
    """Is the point (world frame) deeper than `depth` inside half-spaces given in the frame (plane_rot,
    plane_pos)?"""
    x, y, z = wx - plane_pos[0], wy - plane_pos[1], wz - plane_pos[2]
    lx = plane_rot[0, 0] * x + plane_rot[1, 0] * y + plane_rot[2, 0] * z
    ly = plane_rot[0, 1] * x + plane_rot[1, 1] * y + plane_rot[2, 1] * z
    lz = plane_rot[0, 2] * x + plane_rot[1, 2] * y + plane_rot[2, 2] * z
    for j in range(n_planes):
        if lx * planes[j, 0] + ly * planes[j, 1] + lz * planes[j, 2] - planes[j, 3] >= -depth:
            return False
    return True


@njit(cache=True, fastmath=FAST)
def _deep_inside(points, n_points, rot, pos, k, planes, n_planes, plane_rot, plane_pos, depth):
    """A point of a hull of link k (its frame) deeper than `depth` inside half-spaces given in the frame
    (plane_rot, plane_pos): a point in both shapes that far from one's boundary: they interpenetrate."""
    if n_planes == 0:
        return False
    for v in range(n_points):
        wx = rot[k, 0, 0] * points[v, 0] + rot[k, 0, 1] * points[v, 1] + rot[k, 0, 2] * points[v, 2] + pos[k, 0]
        wy = rot[k, 1, 0] * points[v, 0] + rot[k, 1, 1] * points[v, 1] + rot[k, 1, 2] * points[v, 2] + pos[k, 1]
        wz = rot[k, 2, 0] * points[v, 0] + rot[k, 2, 1] * points[v, 1] + rot[k, 2, 2] * points[v, 2] + pos[k, 2]
        if _point_deep_in(wx, wy, wz, planes, n_planes, plane_rot, plane_pos, depth):
            return True
    return False


@njit(cache=True, fastmath=FAST)
def _world_inside(points, n_points, planes, n_planes, plane_rot, plane_pos, depth):
    """A point (world frame: a scene element's) deeper than `depth` inside half-spaces given in the frame
    (plane_rot, plane_pos)."""
    if n_planes == 0:
        return False
    for v in range(n_points):
        if _point_deep_in(points[v, 0], points[v, 1], points[v, 2], planes, n_planes, plane_rot, plane_pos, depth):
            return True
    return False


@njit(cache=True, fastmath=FAST)
def _sphere_in(centres, i, radius, planes, n_planes, depth):
    """Does sphere i overlap the polytope by more than `depth`? Its centre inside, deep enough; or outside
    with the nearest point on the face it is beyond (its foot inside every other half-space) closer
    than radius - depth (then that is the true distance)."""
    deepest, face = -np.inf, 0
    for j in range(n_planes):
        f = centres[i, 0] * planes[j, 0] + centres[i, 1] * planes[j, 1] + centres[i, 2] * planes[j, 2] - planes[j, 3]
        if f > deepest:
            deepest, face = f, j
    if deepest < -depth:
        return True
    if deepest < 0.0 or deepest >= radius - depth:
        return False
    x = centres[i, 0] - deepest * planes[face, 0]
    y = centres[i, 1] - deepest * planes[face, 1]
    z = centres[i, 2] - deepest * planes[face, 2]
    for j in range(n_planes):
        if x * planes[j, 0] + y * planes[j, 1] + z * planes[j, 2] - planes[j, 3] > 1e-9:
            return False
    return True


# How `pack` stores each table: f float, i int; the number: its dimensions.
F1 = Annotated[npt.NDArray[np.float64], "f1"]
F2 = Annotated[npt.NDArray[np.float64], "f2"]
F3 = Annotated[npt.NDArray[np.float64], "f3"]
I1 = Annotated[npt.NDArray[np.int64], "i1"]
I2 = Annotated[npt.NDArray[np.int64], "i2"]


class Tables(NamedTuple):
    """The model's tables (`fast_collision.SphereModel`), one value: numba passes it whole and the kernel
    reads each table by name. Link slots first (k), then hulls (h), scene elements (e), self pairs (p)."""

    parent: I1             # k -> the slot of its parent link
    origin_r: F3           # k -> its joint's origin in the parent's frame: rotation, position
    origin_p: F2
    kind: I1               # k -> 0 fixed, 1 turning, 2 sliding
    axis: F2
    base_r: F2             # the robot's base in the world
    base_p: F1
    outer_c: F3            # k, i -> spheres around the link (centre in its frame, radius), how many
    outer_r: F2
    outer_n: I1
    inner_c: F3            # k, i -> spheres inside the link
    inner_r: F2
    inner_n: I1
    bound_c: F2            # k -> one sphere around its outer spheres: the broad phase
    bound_r: F1
    hull_points: F3        # h -> corners of a convex element of a link (link frame), how many
    hull_np: I1
    hull_planes: F3        # h -> half-spaces around it, how many
    hull_nj: I1
    hull_c: F2             # h -> a sphere around it
    hull_r: F1
    link_hulls: I2         # k, x -> its hulls, how many
    link_nh: I1
    hull_in: F3            # h -> points surely inside it, how many
    hull_in_n: I1
    hull_in_planes: F3     # h -> half-spaces inside it, how many
    hull_in_nj: I1
    pairs: I2              # p -> the two link slots the exact test checks against each other
    scene_links: I1        # k -> tested against the scene
    el_outer: F3           # e -> half-spaces around a scene element (world frame), how many
    el_outer_n: I1
    el_inner: F3           # e -> half-spaces inside it, how many
    el_inner_n: I1
    el_c: F2               # e -> a sphere around it
    el_r: F1
    touches: I2            # k, e -> does the exact test check this link against this element
    group_c: F2            # elements grouped by place: each group's sphere, its members
    group_r: F1
    group_start: I1
    group_members: I1
    fine_points: F3        # h -> a mesh hull's own corners and faces behind a k-DOP (`coarse`)
    fine_np: I1
    fine_planes: F3
    fine_nj: I1
    coarse: I1
    el_points: F3          # e -> its corners, how many
    el_np: I1
    el_in: F3              # e -> points surely inside it, how many
    el_in_n: I1


KINDS = tuple(hint.__metadata__[0] for hint in get_type_hints(Tables, include_extras=True).values())


class Scratch(NamedTuple):
    """One core's working arrays for one configuration at a time."""

    rot: np.ndarray    # (links, 3, 3) link frames in the world
    pos: np.ndarray    # (links, 3)
    tmp: np.ndarray    # (3, 3)
    ow: np.ndarray     # (links, outer, 3) outer spheres in the world
    iw: np.ndarray     # (links, inner, 3) inner spheres in the world
    bw: np.ndarray     # (links, 3) bounding spheres in the world
    hw: np.ndarray     # (2, 3) two hulls' centres in the world
    eye: np.ndarray    # the world's frame
    zero: np.ndarray
    moved: np.ndarray  # (links,) spheres already in the world for this configuration


@njit(cache=True, inline="always", fastmath=FAST)
def _scratch(t):
    count, outer, inner = t.parent.shape[0], t.outer_c.shape[1], t.inner_c.shape[1]
    return Scratch(np.empty((count, 3, 3)), np.empty((count, 3)), np.empty((3, 3)), np.empty((count, outer, 3)),
                   np.empty((count, inner, 3)), np.empty((count, 3)), np.empty((2, 3)), np.eye(3), np.zeros(3),
                   np.zeros(count, dtype=np.bool_))


@njit(cache=True, inline="always", fastmath=FAST)
def _spheres(t, s, k):
    """Link k's spheres in the world, once per configuration and only for links a broad phase let through."""
    if s.moved[k]:
        return
    s.moved[k] = True
    for i in range(t.outer_n[k]):
        _move(s.rot, s.pos, k, t.outer_c[k, i], s.ow[k], i)
    for i in range(t.inner_n[k]):
        _move(s.rot, s.pos, k, t.inner_c[k, i], s.iw[k], i)


@njit(cache=True, inline="always", fastmath=FAST)
def _place(values, t, s):
    """The forward kinematics: every link's frame and bounding sphere in the world; no sphere moved yet."""
    _frames(values, t.parent, t.origin_r, t.origin_p, t.kind, t.axis, t.base_r, t.base_p, s.rot, s.pos, s.tmp)
    for k in range(t.parent.shape[0]):
        _move(s.rot, s.pos, k, t.bound_c[k], s.bw, k)
        s.moved[k] = False


@njit(cache=True, inline="always", fastmath=FAST)
def _one(values, t, s, pad, sure_depth, grow):
    """One configuration's verdict.

    `grow` (m, per link slot, then per self pair): each link's shapes taken that much larger in every proof
    that it is apart from the scene, each pair's in every proof that its two links are apart; none in the
    proofs that things collide. FREE then holds for every configuration whose links' points lie within their
    `grow` of these, and pairs' within theirs of each other (a stretch of a segment around a checked state);
    COLLIDES still speaks of this one."""
    _place(values, t, s)
    verdict = _with_scene(t, s, pad, sure_depth, grow)
    if verdict == COLLIDES:
        return COLLIDES
    return _with_itself(t, s, pad, sure_depth, grow, verdict == UNSURE)


@njit(cache=True, inline="always", fastmath=FAST)
def _with_scene(t, s, pad, sure_depth, grow):
    """The robot with the scene, first: most colliding samples touch a body (a table), found out here.
    Elements far from a link (group by group, then one by one) are skipped."""
    verdict = FREE
    for k in range(t.parent.shape[0]):
        if not t.scene_links[k]:
            continue
        for g in range(t.group_c.shape[0]):
            if _dist2(s.bw, k, t.group_c, g) >= (t.bound_r[k] + grow[k] + t.group_r[g]) ** 2:
                continue
            for m in range(t.group_start[g], t.group_start[g + 1]):
                e = t.group_members[m]
                if not t.touches[k, e] or _dist2(s.bw, k, t.el_c, e) >= (t.bound_r[k] + grow[k] + t.el_r[e]) ** 2:
                    continue
                found = _link_with_element(t, s, k, e, pad, sure_depth, grow[k], verdict == UNSURE)
                if found == COLLIDES:
                    return COLLIDES
                if found == UNSURE:
                    verdict = UNSURE
    return verdict


@njit(cache=True, inline="always", fastmath=FAST)
def _link_with_element(t, s, k, e, pad, sure_depth, grow, unsure):
    """Link k with scene element e. `unsure`: the configuration is already UNSURE, so only a sure
    collision is worth looking for."""
    _spheres(t, s, k)
    if not _outer_reach_element(t, s, k, e, grow):
        return FREE  # apart, and no sure collision to look for inside
    if t.el_inner_n[e] > 0 and _deep_in_element(t, s, k, e, sure_depth):
        return COLLIDES
    if unsure or not _apart_from_element(t, s, k, e, pad + grow):
        return UNSURE
    return FREE


@njit(cache=True, inline="always", fastmath=FAST)
def _outer_reach_element(t, s, k, e, grow):
    """Does an outer sphere of link k reach every face's plane of element e (grown by `grow`)?"""
    for i in range(t.outer_n[k]):
        deepest = -np.inf
        for j in range(t.el_outer_n[e]):
            f = s.ow[k, i, 0] * t.el_outer[e, j, 0] + s.ow[k, i, 1] * t.el_outer[e, j, 1] \
                + s.ow[k, i, 2] * t.el_outer[e, j, 2] - t.el_outer[e, j, 3]
            if f > deepest:
                deepest = f
        if deepest < t.outer_r[k, i] + grow:
            return True
    return False


@njit(cache=True, inline="always", fastmath=FAST)
def _deep_in_element(t, s, k, e, sure_depth):
    """A sure collision of link k with element e: an inner sphere, or a point surely in a hull of the link,
    deep inside the element; or a point surely in the element (a box's corner) deep inside the link."""
    for i in range(t.inner_n[k]):
        if t.inner_r[k, i] > sure_depth and _sphere_in(s.iw[k], i, t.inner_r[k, i], t.el_inner[e], t.el_inner_n[e],
                                                       sure_depth):
            return True
    for x in range(t.link_nh[k]):
        h = t.link_hulls[k, x]
        if _deep_inside(t.hull_in[h], t.hull_in_n[h], s.rot, s.pos, k, t.el_inner[e], t.el_inner_n[e], s.eye, s.zero,
                        sure_depth):
            return True
        if _world_inside(t.el_in[e], t.el_in_n[e], t.hull_in_planes[h], t.hull_in_nj[h], s.rot[k], s.pos[k],
                         sure_depth):
            return True
    return False


@njit(cache=True, inline="always", fastmath=FAST)
def _apart_from_element(t, s, k, e, apart):
    """Every hull of link k apart from element e by more than `apart`: a face of one with all corners of the
    other beyond it (a k-DOP that cannot tell: the mesh's own hull). A link without hulls: not proven."""
    if t.link_nh[k] == 0:
        return False
    for x in range(t.link_nh[k]):
        h = t.link_hulls[k, x]
        rot, pos = s.rot[k], s.pos[k]
        if _beyond(t.el_outer[e], t.el_outer_n[e], s.eye, s.zero, t.hull_points[h], t.hull_np[h], rot, pos, apart):
            continue
        if t.coarse[h] and _beyond(t.el_outer[e], t.el_outer_n[e], s.eye, s.zero, t.fine_points[h], t.fine_np[h],
                                   rot, pos, apart):
            continue
        # the other way round: the element's corners beyond a face of the link's hull
        if _beyond(t.hull_planes[h], t.hull_nj[h], rot, pos, t.el_points[e], t.el_np[e], s.eye, s.zero, apart):
            continue
        if t.coarse[h] and _beyond(t.fine_planes[h], t.fine_nj[h], rot, pos, t.el_points[e], t.el_np[e], s.eye,
                                   s.zero, apart):
            continue
        return False
    return True


@njit(cache=True, inline="always", fastmath=FAST)
def _with_itself(t, s, pad, sure_depth, grow, unsure):
    """The robot with itself, pair by pair (pairs whose bounding spheres are apart skipped). `unsure`:
    the scene left the configuration UNSURE."""
    count = t.parent.shape[0]
    for p in range(t.pairs.shape[0]):
        a, b = t.pairs[p, 0], t.pairs[p, 1]
        reach = grow[count + p]
        if _dist2(s.bw, a, s.bw, b) >= (t.bound_r[a] + t.bound_r[b] + reach) ** 2:
            continue
        found = _pair(t, s, a, b, pad, sure_depth, reach, unsure)
        if found == COLLIDES:
            return COLLIDES
        if found == UNSURE:
            unsure = True
    return UNSURE if unsure else FREE


@njit(cache=True, inline="always", fastmath=FAST)
def _pair(t, s, a, b, pad, sure_depth, grow, unsure):
    """Links a and b; `unsure` as in `_link_with_element`."""
    _spheres(t, s, a)
    _spheres(t, s, b)
    if not _outer_spheres_touch(t, s, a, b, grow):
        return FREE  # apart, and no sure collision to look for inside
    if _inner_spheres_overlap(t, s, a, b, sure_depth):
        return COLLIDES
    if t.link_nh[a] == 0 or t.link_nh[b] == 0:
        return UNSURE
    return _hull_pairs(t, s, a, b, pad + grow, sure_depth, unsure)


@njit(cache=True, inline="always", fastmath=FAST)
def _outer_spheres_touch(t, s, a, b, grow):
    for i in range(t.outer_n[a]):
        reach = t.outer_r[a, i] + t.bound_r[b] + grow
        if _dist2(s.ow[a], i, s.bw, b) >= reach * reach:
            continue
        for j in range(t.outer_n[b]):
            reach = t.outer_r[a, i] + t.outer_r[b, j] + grow
            if _dist2(s.ow[a], i, s.ow[b], j) < reach * reach:
                return True
    return False


@njit(cache=True, inline="always", fastmath=FAST)
def _inner_spheres_overlap(t, s, a, b, sure_depth):
    """An inner sphere of a and one of b overlapping by more than `sure_depth`; a sphere of a that does not
    reach b's bounding sphere (deep enough) meets none of b's: its row is skipped."""
    for i in range(t.inner_n[a]):
        reach = t.inner_r[a, i] + t.bound_r[b] - sure_depth
        if reach <= 0 or _dist2(s.iw[a], i, s.bw, b) >= reach * reach:
            continue
        for j in range(t.inner_n[b]):
            reach = t.inner_r[a, i] + t.inner_r[b, j] - sure_depth
            if reach > 0 and _dist2(s.iw[a], i, s.iw[b], j) < reach * reach:
                return True
    return False


@njit(cache=True, inline="always", fastmath=FAST)
def _hull_pairs(t, s, a, b, apart, sure_depth, unsure):
    """Every hull of a with every hull of b: COLLIDES as soon as a point surely in one lies deep in the
    other; else UNSURE if a pair is not proven apart (a face of one with the other's corners beyond it)."""
    for x in range(t.link_nh[a]):
        ha = t.link_hulls[a, x]
        _move(s.rot, s.pos, a, t.hull_c[ha], s.hw, 0)
        for y in range(t.link_nh[b]):
            hb = t.link_hulls[b, y]
            _move(s.rot, s.pos, b, t.hull_c[hb], s.hw, 1)
            if _dist2(s.hw, 0, s.hw, 1) >= (t.hull_r[ha] + t.hull_r[hb] + apart) ** 2:
                continue
            if _deep_inside(t.hull_in[ha], t.hull_in_n[ha], s.rot, s.pos, a, t.hull_in_planes[hb], t.hull_in_nj[hb],
                            s.rot[b], s.pos[b], sure_depth) or \
                    _deep_inside(t.hull_in[hb], t.hull_in_n[hb], s.rot, s.pos, b, t.hull_in_planes[ha],
                                 t.hull_in_nj[ha], s.rot[a], s.pos[a], sure_depth):
                return COLLIDES
            if not unsure and not _hulls_apart(t, s, a, b, ha, hb, apart):
                unsure = True
    return UNSURE if unsure else FREE


@njit(cache=True, inline="always", fastmath=FAST)
def _hulls_apart(t, s, a, b, ha, hb, apart):
    ra, pa, rb, pb = s.rot[a], s.pos[a], s.rot[b], s.pos[b]
    if _beyond(t.hull_planes[ha], t.hull_nj[ha], ra, pa, t.hull_points[hb], t.hull_np[hb], rb, pb, apart) or \
            _beyond(t.hull_planes[hb], t.hull_nj[hb], rb, pb, t.hull_points[ha], t.hull_np[ha], ra, pa, apart):
        return True
    if t.coarse[ha] or t.coarse[hb]:  # a k-DOP could not tell: the meshes' own hulls
        return _beyond(t.fine_planes[ha], t.fine_nj[ha], ra, pa, t.fine_points[hb], t.fine_np[hb], rb, pb, apart) \
            or _beyond(t.fine_planes[hb], t.fine_nj[hb], rb, pb, t.fine_points[ha], t.fine_np[ha], ra, pa, apart)
    return False


@njit(cache=True, parallel=True, fastmath=FAST)
def tips(values, parent, origin_r, origin_p, kind, axis, base_r, base_p, tip):
    """(N, 3) world positions of link slot `tip`'s frame."""
    n = values.shape[0]
    count = parent.shape[0]
    out = np.empty((n, 3))
    per_block = (n + BLOCKS - 1) // BLOCKS
    for block in prange(BLOCKS):
        rot = np.empty((count, 3, 3))
        pos = np.empty((count, 3))
        tmp = np.empty((3, 3))
        for s in range(block * per_block, min(n, (block + 1) * per_block)):
            _frames(values[s], parent, origin_r, origin_p, kind, axis, base_r, base_p, rot, pos, tmp)
            out[s] = pos[tip]
    return out


# The loops over configurations run without numba's reference counting (`_nrt=False`): the model's helpers take
# the tables and working arrays whole (`t`, `s`), and each such call would count a reference to each of their
# sixty arrays, twice, several times per configuration: four times the time of a configuration. The arrays are
# made and held by the callers, which count them once.
@njit(cache=True, fastmath=FAST, _nrt=False)
def _block(lo, hi, values, t, s, still, pad, sure_depth, tip, tips_out, out):
    """Configurations lo..hi on one core: one call per block, the model inlined."""
    for c in range(lo, hi):
        out[c] = _one(values[c], t, s, pad, sure_depth, still)
        if tip >= 0:  # the tip's position from the same frames: the sampled points
            for r in range(3):
                tips_out[c, r] = s.pos[tip, r]


@njit(cache=True, parallel=True, nogil=True, fastmath=FAST)
def verdicts(values, t, pad, sure_depth, tip, tips_out):
    """(N, m) joint values -> (N,) verdicts on all cores; with `tip` >= 0, that link's origins into tips_out."""
    n = values.shape[0]
    out = np.zeros(n, dtype=np.int8)
    per_block = (n + BLOCKS - 1) // BLOCKS
    for block in prange(BLOCKS):
        s = _scratch(t)
        still = np.zeros(t.parent.shape[0] + t.pairs.shape[0])  # no growth: links, then self pairs
        _block(block * per_block, min(n, (block + 1) * per_block), values, t, s, still, pad, sure_depth, tip, tips_out,
               out)
    return out


@njit(cache=True, parallel=True, nogil=True, fastmath=FAST)
def clear_of_field(values, t, centres, origin, cell):
    """(N, m) joint values -> (N,) whether every link that meets the scene keeps its outer spheres clear of
    what a distance field stands for (`scan_bodies.Clearance`, whose lookup this repeats): the link's
    bounding sphere first, its outer spheres where that one may touch."""
    n = values.shape[0]
    out = np.zeros(n, dtype=np.bool_)
    per_block = (n + BLOCKS - 1) // BLOCKS
    for block in prange(BLOCKS):
        s = _scratch(t)
        for c in range(block * per_block, min(n, (block + 1) * per_block)):
            _place(values[c], t, s)
            out[c] = _clear_of_field(t, s, centres, origin, cell)
    return out


@njit(cache=True, inline="always", fastmath=FAST)
def _clear_of_field(t, s, centres, origin, cell):
    for k in range(t.parent.shape[0]):
        if not t.scene_links[k]:
            continue
        if _field_distance(s.bw, k, centres, origin, cell) > t.bound_r[k] + 1e-6:
            continue
        _spheres(t, s, k)
        for i in range(t.outer_n[k]):
            if _field_distance(s.ow[k], i, centres, origin, cell) <= t.outer_r[k, i] + 1e-6:
                return False
    return True


@njit(cache=True, inline="always", fastmath=FAST)
def _field_distance(points, i, centres, origin, cell):
    """A lower bound of point i's distance to a distance field's boxes: its cell's (the nearest cell of the
    grid, for a point beyond it) less a cell's diagonal."""
    x = min(max((points[i, 0] - origin[0]) / cell, 0.0), centres.shape[0] - 1.0)
    y = min(max((points[i, 1] - origin[1]) / cell, 0.0), centres.shape[1] - 1.0)
    z = min(max((points[i, 2] - origin[2]) / cell, 0.0), centres.shape[2] - 1.0)
    return centres[int(x), int(y), int(z)] - cell * np.sqrt(3.0)


@njit(cache=True, inline="always", fastmath=FAST)
def _f1(floats, meta, k):
    return floats[meta[k, 0]:meta[k, 0] + meta[k, 1]]


@njit(cache=True, inline="always", fastmath=FAST)
def _f2(floats, meta, k):
    return floats[meta[k, 0]:meta[k, 0] + meta[k, 1] * meta[k, 2]].reshape((meta[k, 1], meta[k, 2]))


@njit(cache=True, inline="always", fastmath=FAST)
def _f3(floats, meta, k):
    size = meta[k, 1] * meta[k, 2] * meta[k, 3]
    return floats[meta[k, 0]:meta[k, 0] + size].reshape((meta[k, 1], meta[k, 2], meta[k, 3]))


@njit(cache=True, inline="always", fastmath=FAST)
def _i1(ints, meta, k):
    return ints[meta[k, 0]:meta[k, 0] + meta[k, 1]]


@njit(cache=True, inline="always", fastmath=FAST)
def _i2(ints, meta, k):
    return ints[meta[k, 0]:meta[k, 0] + meta[k, 1] * meta[k, 2]].reshape((meta[k, 1], meta[k, 2]))


def _unpacker():
    """`_unpacked(floats, ints, meta) -> Tables`: views of `pack`'s arrays. Written from `KINDS` (numba
    builds a tuple of arrays of different shapes only from code that names each), so a table added to
    `Tables` is packed and unpacked with nothing else to change."""
    views = ", ".join(f"_{kind}({'floats' if kind[0] == 'f' else 'ints'}, meta, {k})" for k, kind in enumerate(KINDS))
    scope = {"Tables": Tables, "_f1": _f1, "_f2": _f2, "_f3": _f3, "_i1": _i1, "_i2": _i2}
    exec(f"def _unpacked(floats, ints, meta):\n    return Tables({views})\n", scope)  # our own text, from KINDS
    return njit(inline="always", fastmath=FAST)(scope["_unpacked"])


_unpacked = _unpacker()


@njit(cache=True, fastmath=FAST)
def verdicts_packed(q, passive, main_map, passive_map, offsets, floats, ints, meta, pad, sure_depth, grow):
    """The verdicts of the rows of q (and of passive, (N, p)) on this thread, without the threads' start-up:
    a planner's state checks. The tables come packed in three arrays (`pack`) and the joint values are made
    here (values = q . main_map + passive . passive_map + offsets): a call from Python costs a few
    microseconds instead of fifty arrays' and a numpy product's worth. One state is one row: one piece of
    code to compile, not two."""
    t = _unpacked(floats, ints, meta)
    out = np.empty(q.shape[0], dtype=np.int8)
    _rows(q, passive, main_map, passive_map, offsets, t, _scratch(t), np.empty(offsets.shape[0]), pad, sure_depth,
          grow, out)
    return out


@njit(cache=True, fastmath=FAST, _nrt=False)
def _rows(q, passive, main_map, passive_map, offsets, t, s, values, pad, sure_depth, grow, out):
    """`verdicts_packed`'s loop, without reference counting (as `_block`)."""
    for c in range(q.shape[0]):
        _values(q[c], passive[c], main_map, passive_map, offsets, values)
        out[c] = _one(values, t, s, pad, sure_depth, grow)


@njit(cache=True, inline="always", fastmath=FAST)
def _values(q, passive, main_map, passive_map, offsets, values):
    for j in range(values.shape[0]):
        values[j] = offsets[j]
        for i in range(q.shape[0]):
            values[j] += q[i] * main_map[i, j]
        for i in range(passive.shape[0]):
            values[j] += passive[i] * passive_map[i, j]


def as_tables(named: dict[str, np.ndarray]) -> Tables:
    """The model's tables by name -> `Tables`, each array of the dtype the kernel compiles for (one
    specialisation: floats as float64, ints and flags as int64)."""
    return Tables._make(np.ascontiguousarray(named[name], dtype=np.float64 if kind[0] == "f" else np.int64)
                        for name, kind in zip(Tables._fields, KINDS))


def pack(t: Tables) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tables as (floats, ints, meta): meta's row k holds table k's offset and shape."""
    floats, ints, meta = [], [], np.zeros((len(KINDS), 4), dtype=np.int64)
    f_at = i_at = 0
    for k, (array, kind) in enumerate(zip(t, KINDS)):
        meta[k] = (f_at if kind[0] == "f" else i_at, *array.shape, *[1] * (3 - array.ndim))
        if kind[0] == "f":
            floats.append(array.ravel())
            f_at += array.size
        else:
            ints.append(array.ravel())
            i_at += array.size
    return np.concatenate(floats), np.concatenate(ints), meta
