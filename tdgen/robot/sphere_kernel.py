"""The compiled loop of the fast collision model: one configuration per iteration, all cores.

numpy would hold N x sphere-pairs arrays and walk memory several times per test; this loop keeps
one configuration's link frames and spheres in a few hundred numbers (allocated once per block of
configurations) and stops at the first sure answer. Compiled once per machine (numba caches it
beside this file, or in NUMBA_CACHE_DIR). Verdicts: 0 free, 1 colliding, 2 unsure (for the exact
test). See `fast_collision` for the model.
"""
from __future__ import annotations

import numpy as np
from numba import njit, prange

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
    rot[0] = base_r
    pos[0] = base_p
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
            rot[k] = tmp
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


@njit(cache=True, inline="always", fastmath=FAST)
def _spheres(rot, pos, k, outer_c, outer_n, inner_c, inner_n, ow, iw, moved):
    """Link k's spheres in the world, once per configuration and only for links a broad phase let through."""
    if moved[k]:
        return
    moved[k] = True
    for i in range(outer_n[k]):
        _move(rot, pos, k, outer_c[k, i], ow[k], i)
    for i in range(inner_n[k]):
        _move(rot, pos, k, inner_c[k, i], iw[k], i)


@njit(cache=True, inline="always", fastmath=FAST)
def _one(values, tables, pad, sure_depth, grow, rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved):
    """One configuration's verdict; `tables` in the order of TABLES (a tuple: a call of fifty arguments
    compiles to a call with *args, which numba cannot inline).

    `grow` (m, per link slot, then per self pair): each link's shapes taken that much larger in every proof
    that it is apart from the scene, each pair's in every proof that its two links are apart; none in the
    proofs that things collide. FREE then holds for every configuration whose links' points lie within their
    `grow` of these, and pairs' within theirs of each other (a stretch of a segment around a checked state);
    COLLIDES still speaks of this one."""
    (parent, origin_r, origin_p, kind, axis, base_r, base_p,
     outer_c, outer_r, outer_n, inner_c, inner_r, inner_n, bound_c, bound_r,
     hull_points, hull_np, hull_planes, hull_nj, hull_c, hull_r, link_hulls, link_nh,
     hull_in, hull_in_n, hull_in_planes, hull_in_nj,
     pairs, scene_links, el_outer, el_outer_n, el_inner, el_inner_n, el_c, el_r, touches,
     group_c, group_r, group_start, group_members, fine_points, fine_np, fine_planes, fine_nj, coarse,
     el_points, el_np, el_in, el_in_n) = tables
    count = parent.shape[0]
    _frames(values, parent, origin_r, origin_p, kind, axis, base_r, base_p, rot, pos, tmp)
    for k in range(count):
        _move(rot, pos, k, bound_c[k], bw, k)
        moved[k] = False
    maybe = False
    # the robot with the scene first: most colliding samples touch a body (a table), found out here
    for k in range(count):
        if not scene_links[k]:
            continue
        for g in range(group_c.shape[0]):
            if _dist2(bw, k, group_c, g) >= (bound_r[k] + grow[k] + group_r[g]) ** 2:
                continue
            for m in range(group_start[g], group_start[g + 1]):
                e = group_members[m]
                if not touches[k, e]:
                    continue
                if _dist2(bw, k, el_c, e) >= (bound_r[k] + grow[k] + el_r[e]) ** 2:
                    continue
                _spheres(rot, pos, k, outer_c, outer_n, inner_c, inner_n, ow, iw, moved)
                # outer spheres (around the link) that reach no face of the element: the two are apart, and the
                # tests of a sure collision below (shapes inside the link) need not run
                touch = False
                for i in range(outer_n[k]):
                    deepest = -np.inf
                    for j in range(el_outer_n[e]):
                        f = ow[k, i, 0] * el_outer[e, j, 0] + ow[k, i, 1] * el_outer[e, j, 1] \
                            + ow[k, i, 2] * el_outer[e, j, 2] - el_outer[e, j, 3]
                        if f > deepest:
                            deepest = f
                    if deepest < outer_r[k, i] + grow[k]:
                        touch = True
                        break
                if not touch:
                    continue
                if el_inner_n[e] > 0:
                    for i in range(inner_n[k]):
                        if inner_r[k, i] <= sure_depth:
                            continue
                        if _sphere_in(iw[k], i, inner_r[k, i], el_inner[e], el_inner_n[e], sure_depth):
                            return 1
                    for x in range(link_nh[k]):
                        h = link_hulls[k, x]
                        if _deep_inside(hull_in[h], hull_in_n[h], rot, pos, k, el_inner[e], el_inner_n[e], eye, zero,
                                        sure_depth):
                            return 1
                        # the other way round: a point surely in the element (a box's corner) deep inside the link
                        if _world_inside(el_in[e], el_in_n[e], hull_in_planes[h], hull_in_nj[h], rot[k], pos[k],
                                         sure_depth):
                            return 1
                if maybe:
                    continue
                if link_nh[k] == 0:
                    maybe = True
                    continue
                for x in range(link_nh[k]):
                    h = link_hulls[k, x]
                    if _beyond(el_outer[e], el_outer_n[e], eye, zero, hull_points[h], hull_np[h], rot[k], pos[k],
                               pad + grow[k]):
                        continue
                    if coarse[h] and _beyond(el_outer[e], el_outer_n[e], eye, zero, fine_points[h], fine_np[h], rot[k],
                                             pos[k], pad + grow[k]):
                        continue
                    # the other way round: the element's corners beyond a face of the link's hull
                    if _beyond(hull_planes[h], hull_nj[h], rot[k], pos[k], el_points[e], el_np[e], eye, zero,
                               pad + grow[k]):
                        continue
                    if coarse[h] and _beyond(fine_planes[h], fine_nj[h], rot[k], pos[k], el_points[e], el_np[e], eye,
                                             zero, pad + grow[k]):
                        continue
                    maybe = True
                    break
    # the robot with itself
    for p in range(pairs.shape[0]):
        a, b = pairs[p, 0], pairs[p, 1]
        if _dist2(bw, a, bw, b) >= (bound_r[a] + bound_r[b] + grow[count + p]) ** 2:
            continue
        _spheres(rot, pos, a, outer_c, outer_n, inner_c, inner_n, ow, iw, moved)
        _spheres(rot, pos, b, outer_c, outer_n, inner_c, inner_n, ow, iw, moved)
        touch = False  # no outer spheres touch: apart, and no sure collision to look for inside
        for i in range(outer_n[a]):
            reach = outer_r[a, i] + bound_r[b] + grow[count + p]
            if _dist2(ow[a], i, bw, b) >= reach * reach:
                continue
            for j in range(outer_n[b]):
                reach = outer_r[a, i] + outer_r[b, j] + grow[count + p]
                if _dist2(ow[a], i, ow[b], j) < reach * reach:
                    touch = True
                    break
            if touch:
                break
        if not touch:
            continue
        # a sphere of a that does not reach b's bounding sphere (deep enough) meets none of b's: skip its row
        for i in range(inner_n[a]):
            reach = inner_r[a, i] + bound_r[b] - sure_depth
            if reach <= 0 or _dist2(iw[a], i, bw, b) >= reach * reach:
                continue
            for j in range(inner_n[b]):
                reach = inner_r[a, i] + inner_r[b, j] - sure_depth
                if reach > 0 and _dist2(iw[a], i, iw[b], j) < reach * reach:
                    return 1
        if link_nh[a] == 0 or link_nh[b] == 0:
            maybe = True
            continue
        for x in range(link_nh[a]):
            ha = link_hulls[a, x]
            _move(rot, pos, a, hull_c[ha], hw, 0)
            for y in range(link_nh[b]):
                hb = link_hulls[b, y]
                _move(rot, pos, b, hull_c[hb], hw, 1)
                apart = pad + grow[count + p]
                if _dist2(hw, 0, hw, 1) >= (hull_r[ha] + hull_r[hb] + apart) ** 2:
                    continue
                if _deep_inside(hull_in[ha], hull_in_n[ha], rot, pos, a, hull_in_planes[hb], hull_in_nj[hb],
                                rot[b], pos[b], sure_depth) or \
                        _deep_inside(hull_in[hb], hull_in_n[hb], rot, pos, b, hull_in_planes[ha], hull_in_nj[ha],
                                     rot[a], pos[a], sure_depth):
                    return 1
                if maybe:
                    continue
                if _beyond(hull_planes[ha], hull_nj[ha], rot[a], pos[a], hull_points[hb], hull_np[hb], rot[b], pos[b],
                           apart):
                    continue
                if _beyond(hull_planes[hb], hull_nj[hb], rot[b], pos[b], hull_points[ha], hull_np[ha], rot[a], pos[a],
                           apart):
                    continue
                if (coarse[ha] or coarse[hb]) and (  # a k-DOP could not tell: the meshes' own hulls
                        _beyond(fine_planes[ha], fine_nj[ha], rot[a], pos[a], fine_points[hb], fine_np[hb], rot[b],
                                pos[b], apart)
                        or _beyond(fine_planes[hb], fine_nj[hb], rot[b], pos[b], fine_points[ha], fine_np[ha], rot[a],
                                   pos[a], apart)):
                    continue
                maybe = True
    return 2 if maybe else 0


@njit(cache=True, inline="always", fastmath=FAST)
def _scratch(tables):
    """One core's working arrays for `_one`: link frames, spheres in the world, a few vectors."""
    count, outer, inner = tables[0].shape[0], tables[7].shape[1], tables[10].shape[1]
    return (np.empty((count, 3, 3)), np.empty((count, 3)), np.empty((3, 3)), np.empty((count, outer, 3)),
            np.empty((count, inner, 3)), np.empty((count, 3)), np.empty((2, 3)), np.eye(3), np.zeros(3),
            np.zeros(count, dtype=np.bool_))


@njit(cache=True, fastmath=FAST)
def verdict_one(values, tables, pad, sure_depth, grow):
    """One configuration's verdict without the threads' start-up: a planner's state check. `tables`: the
    model's tables in the order of TABLES."""
    rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved = _scratch(tables)
    return _one(values, tables, pad, sure_depth, grow, rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved)


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


@njit(cache=True, fastmath=FAST)
def _block(lo, hi, values, tables, pad, sure_depth, tip, tips_out, out):
    """Configurations lo..hi on one core: one call per block, the model inlined (a call per configuration
    passed fifty arrays, counting references to each: a third of the time of a configuration far from
    everything)."""
    rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved = _scratch(tables)
    still = np.zeros(tables[0].shape[0] + tables[27].shape[0])  # no growth: links, then self pairs
    for s in range(lo, hi):
        out[s] = _one(values[s], tables, pad, sure_depth, still, rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved)
        if tip >= 0:  # the tip's position from the same frames: the sampled points
            tips_out[s] = pos[tip]


@njit(cache=True, parallel=True, nogil=True, fastmath=FAST)
def verdicts(values, tables, pad, sure_depth, tip, tips_out):
    """(N, m) joint values -> (N,) verdicts on all cores; with `tip` >= 0, that link's origins into tips_out."""
    n = values.shape[0]
    out = np.zeros(n, dtype=np.int8)
    per_block = (n + BLOCKS - 1) // BLOCKS
    for block in prange(BLOCKS):
        _block(block * per_block, min(n, (block + 1) * per_block), values, tables, pad, sure_depth, tip, tips_out, out)
    return out


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


@njit(cache=True, fastmath=FAST)
def verdicts_packed(q, passive, main_map, passive_map, offsets, floats, ints, meta, pad, sure_depth, grow):
    """`verdict_packed` for the rows of q (and of passive, (N, p)) on this thread: a segment's states, the
    tables unpacked and the working arrays made once."""
    tables = _unpacked(floats, ints, meta)
    rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved = _scratch(tables)
    values = np.empty(offsets.shape[0])
    out = np.empty(q.shape[0], dtype=np.int8)
    for s in range(q.shape[0]):
        _values(q[s], passive[s], main_map, passive_map, offsets, values)
        out[s] = _one(values, tables, pad, sure_depth, grow, rot, pos, tmp, ow, iw, bw, hw, eye, zero, moved)
    return out


@njit(cache=True, fastmath=FAST)
def verdict_packed(q, passive, main_map, passive_map, offsets, floats, ints, meta, pad, sure_depth, grow):
    """One configuration's verdict with the tables packed in three arrays (`pack`) and the joint values
    made here (values = q . main_map + passive . passive_map + offsets): a call from Python costs a few
    microseconds instead of forty arguments' and a numpy product's worth (a planner's state check)."""
    values = np.empty(offsets.shape[0])
    _values(q, passive, main_map, passive_map, offsets, values)
    return verdict_one(values, _unpacked(floats, ints, meta), pad, sure_depth, grow)


@njit(cache=True, inline="always", fastmath=FAST)
def _values(q, passive, main_map, passive_map, offsets, values):
    for j in range(values.shape[0]):
        values[j] = offsets[j]
        for i in range(q.shape[0]):
            values[j] += q[i] * main_map[i, j]
        for i in range(passive.shape[0]):
            values[j] += passive[i] * passive_map[i, j]


@njit(cache=True, inline="always", fastmath=FAST)
def _unpacked(floats, ints, meta):
    """The tables of `pack`, as views in the order of TABLES."""
    return (_i1(ints, meta, 0), _f3(floats, meta, 1), _f2(floats, meta, 2),
            _i1(ints, meta, 3), _f2(floats, meta, 4), _f2(floats, meta, 5),
            _f1(floats, meta, 6), _f3(floats, meta, 7), _f2(floats, meta, 8),
            _i1(ints, meta, 9), _f3(floats, meta, 10), _f2(floats, meta, 11),
            _i1(ints, meta, 12), _f2(floats, meta, 13), _f1(floats, meta, 14),
            _f3(floats, meta, 15), _i1(ints, meta, 16), _f3(floats, meta, 17),
            _i1(ints, meta, 18), _f2(floats, meta, 19), _f1(floats, meta, 20),
            _i2(ints, meta, 21), _i1(ints, meta, 22), _f3(floats, meta, 23),
            _i1(ints, meta, 24), _f3(floats, meta, 25), _i1(ints, meta, 26),
            _i2(ints, meta, 27), _i1(ints, meta, 28), _f3(floats, meta, 29),
            _i1(ints, meta, 30), _f3(floats, meta, 31), _i1(ints, meta, 32),
            _f2(floats, meta, 33), _f1(floats, meta, 34), _i2(ints, meta, 35),
            _f2(floats, meta, 36), _f1(floats, meta, 37), _i1(ints, meta, 38),
            _i1(ints, meta, 39), _f3(floats, meta, 40), _i1(ints, meta, 41),
            _f3(floats, meta, 42), _i1(ints, meta, 43), _i1(ints, meta, 44),
            _f3(floats, meta, 45), _i1(ints, meta, 46), _f3(floats, meta, 47), _i1(ints, meta, 48))


# name:kind of verdict_one's tables, in order (f float, i int; the number: dimensions)
PACKING = [
    'parent:i1', 'origin_r:f3', 'origin_p:f2', 'kind:i1', 'axis:f2', 'base_r:f2', 'base_p:f1', 'outer_c:f3',
    'outer_r:f2', 'outer_n:i1', 'inner_c:f3', 'inner_r:f2', 'inner_n:i1', 'bound_c:f2', 'bound_r:f1',
    'hull_points:f3', 'hull_np:i1', 'hull_planes:f3', 'hull_nj:i1', 'hull_c:f2', 'hull_r:f1', 'link_hulls:i2',
    'link_nh:i1', 'hull_in:f3', 'hull_in_n:i1', 'hull_in_planes:f3', 'hull_in_nj:i1', 'pairs:i2',
    'scene_links:i1', 'el_outer:f3', 'el_outer_n:i1', 'el_inner:f3', 'el_inner_n:i1', 'el_c:f2', 'el_r:f1',
    'touches:i2', 'group_c:f2', 'group_r:f1', 'group_start:i1', 'group_members:i1', 'fine_points:f3', 'fine_np:i1',
    'fine_planes:f3', 'fine_nj:i1', 'coarse:i1', 'el_points:f3', 'el_np:i1', 'el_in:f3', 'el_in_n:i1',
]
TABLES = tuple(entry.split(":")[0] for entry in PACKING)  # the same names: the parallel loop's arguments


def pack(tables: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The tables as (floats, ints, meta): meta's row k holds table k's offset and shape."""
    floats, ints, meta = [], [], np.zeros((len(PACKING), 4), dtype=np.int64)
    f_at = i_at = 0
    for k, entry in enumerate(PACKING):
        name, kind = entry.split(":")
        array = np.ascontiguousarray(tables[name], dtype=np.float64 if kind[0] == "f" else np.int64)
        shape = list(array.shape) + [1] * (3 - array.ndim)
        if kind[0] == "f":
            meta[k] = (f_at, *shape)
            floats.append(array.ravel())
            f_at += array.size
        else:
            meta[k] = (i_at, *shape)
            ints.append(array.ravel())
            i_at += array.size
    return np.concatenate(floats), np.concatenate(ints), meta
