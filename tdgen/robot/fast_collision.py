"""The fast collision model: "does q collide?" for thousands of configurations per compiled call
(`sphere_kernel`), with pybullet's exact test deciding only what the spheres cannot.

Every configuration gets one of three verdicts from the spheres (`tdgen.robot.spheres`): free (no
outer shapes of a pair that counts touch: the exact test cannot find a contact), colliding (inner
shapes overlap by more than `SURE_DEPTH`: it must find one), or unsure, which the exact test
(`CollisionWorld`) then decides. So the answer is the exact test's; only its cost changes. The pairs
that count are the exact test's own (`CollisionWorld`: adjacent and by-design pairs excluded, links
bolted to the base not tested against the scene, allowed link/body pairs).
"""
from __future__ import annotations

import functools
import os
import sys
import time
import weakref

import numpy as np

from tdgen.robot import sphere_kernel as kernel
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.cores import (
    COMPILING_LOCK,
    LAUNCH,
    LOCK_FD,
    compile_in_background,
    compiled,
    compiled_code_dir,
    compiled_stamp,
    compiles_everything,
    compiling_here,
)
from tdgen.robot.link_frames import LinkFrames
from tdgen.robot.model import Robot
from tdgen.robot.scan_bodies import fast_boxes
from tdgen.robot.sphere_kernel import COLLIDES, FREE, UNSURE
from tdgen.robot.spheres import PAD, SURE_DEPTH, Convex, cover, link_elements, outer_planes, scene_elements, within

__all__ = ["COLLIDES", "FREE", "UNSURE", "FastCollision", "SphereModel"]
CHUNK = 65536
LOOK_EVERY = 1.0  # s between a warm model's looks for compiled code that another process is making


def _stacked(arrays: list[np.ndarray], trailing: tuple[int, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Arrays of different lengths as one zero-padded (K, W, *trailing) array, and their lengths."""
    lengths = np.array([len(a) for a in arrays], dtype=np.int64)
    if len(arrays) and lengths.min() == lengths.max() > 0:  # all alike (a scan's boxes): at once
        return np.stack(arrays).astype(float, copy=False).reshape(len(arrays), -1, *trailing), lengths
    width = max([len(a) for a in arrays] + [1])
    out = np.zeros((len(arrays), width, *trailing))
    for k, a in enumerate(arrays):
        out[k, :len(a)] = a
    return out, np.array([len(a) for a in arrays], dtype=np.int64)


def _planes(rows: list[np.ndarray]) -> np.ndarray:
    """(E, J, 4) half-spaces per element, padded by repeating a row (a max over rows is unchanged);
    an element with none gets 0.x <= -1 (nothing is ever inside it)."""
    lengths = [len(r) for r in rows]
    if rows and min(lengths) == max(lengths) > 0:  # all alike (a scan's boxes): at once
        return np.stack(rows).astype(float, copy=False)
    width = max(lengths + [1])
    out = np.zeros((len(rows), width, 4))
    for k, r in enumerate(rows):
        r = r if len(r) else np.array([[0.0, 0.0, 0.0, -1.0]])
        out[k, :len(r)], out[k, len(r):] = r, r[0]
    return out


_ROBOT_PARTS: dict[int, tuple[weakref.ref[Robot], dict[tuple[bytes, bool], tuple]]] = {}  # by id(robot)


def _robot_part(world: CollisionWorld) -> tuple:
    """`SphereModel.robot_part`, made once per robot, placement and kind of world: a live scene change
    builds a model of the same robot again (fitting its spheres is the slow part)."""
    import msgspec

    key = (msgspec.json.encode(world.scene.robot), world.part)
    held = _ROBOT_PARTS.get(id(world.robot))
    if held is None or held[0]() is not world.robot:  # a robot (Robot is a dataclass, not hashable) seen first
        for gone in [k for k, (ref, _) in _ROBOT_PARTS.items() if ref() is None]:
            del _ROBOT_PARTS[gone]
        held = _ROBOT_PARTS[id(world.robot)] = (weakref.ref(world.robot), {})
    per_robot = held[1]
    if key not in per_robot:
        per_robot[key] = SphereModel.robot_part(world)
    return per_robot[key]


def _element_tables(elements: list[Convex]) -> dict[str, np.ndarray]:
    """One body's elements as the scene tables' rows (`SphereModel._scene_tables`)."""
    outside = [outer_planes(e) for e in elements]
    corners, counts = _stacked([e.points for e in elements], (3,))
    inside, inside_counts = _stacked([e.inner_points() for e in elements], (3,))
    return {"el_points": corners, "el_np": counts, "el_in": inside, "el_in_n": inside_counts,
            "el_outer": _planes(outside), "el_outer_n": np.array([len(p) for p in outside], dtype=np.int64),
            "el_inner": _planes([e.planes for e in elements]),
            "el_inner_n": np.array([len(e.planes) for e in elements], dtype=np.int64)}


def _box_tables(corners: np.ndarray, planes: np.ndarray) -> dict[str, np.ndarray]:
    """A scan's boxes (`scan_bodies.fast_boxes`) as `_element_tables` makes them of `Convex(corners, planes,
    outside=planes)` each, without making them one by one."""
    eight, six = np.full(len(corners), 8, dtype=np.int64), np.full(len(corners), 6, dtype=np.int64)
    corners, planes = np.ascontiguousarray(corners, dtype=float), np.ascontiguousarray(planes, dtype=float)
    return {"el_points": corners, "el_np": eight, "el_in": corners, "el_in_n": eight,
            "el_outer": planes, "el_outer_n": six, "el_inner": planes, "el_inner_n": six}


def _widened(rows: np.ndarray, width: int, repeat: bool) -> np.ndarray:
    """(E, W, D) -> (E, width, D): padded with zeros, or (`repeat`) with each element's first row."""
    if rows.shape[1] == width:
        return rows
    fill = np.repeat(rows[:, :1], width - rows.shape[1], axis=1) if repeat and rows.shape[1] else \
        np.zeros((len(rows), width - rows.shape[1], rows.shape[2]))
    return np.concatenate([rows, fill], axis=1)


GROUP_CELL = 0.3  # m: scene elements are grouped by the cell of this size their centre is in (the broad phase)


def _groups(centres: np.ndarray, radii: np.ndarray) -> dict[str, np.ndarray]:
    """Elements grouped by grid cell, each group with one sphere around its members' spheres: a link
    far from a group's sphere skips all its members (a room of 600 boxes has a few dozen groups)."""
    cells = np.floor(centres / GROUP_CELL).astype(np.int64)
    _, group = np.unique(cells, axis=0, return_inverse=True)
    group = group.reshape(-1)
    order = np.argsort(group, kind="stable")
    counts = np.bincount(group, minlength=int(group.max()) + 1 if len(group) else 0)
    start = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
    if not len(counts):
        return {"group_c": np.zeros((0, 3)), "group_r": np.zeros(0), "group_start": start,
                "group_members": order.astype(np.int64)}
    c, r = centres[order], radii[order]  # members group by group, each group's run reduced at once
    lo = np.minimum.reduceat(c - r[:, None], start[:-1], axis=0)
    hi = np.maximum.reduceat(c + r[:, None], start[:-1], axis=0)
    group_c = (lo + hi) / 2
    group_r = np.maximum.reduceat(np.linalg.norm(c - group_c[group[order]], axis=1) + r, start[:-1])
    return {"group_c": group_c, "group_r": group_r, "group_start": start, "group_members": order.astype(np.int64)}


class SphereModel:
    """Spheres of the robot's links and convex scene bodies, built from (and checked against) a
    `CollisionWorld`; `verdicts(q)` classifies (N, n) configurations as FREE, COLLIDES or UNSURE."""

    def __init__(self, world: CollisionWorld):
        pb, client = world._pb, world.client
        self.frames, self.fallback, robot_tables, slot_of = _robot_part(world)
        self.slot_of = slot_of
        self._still = np.zeros(len(slot_of) + len(robot_tables["pairs"]))  # no growth (`verdicts_here`)
        links = list(slot_of)
        parts, element_body = [], []
        for b in world._scene_names:
            boxes = fast_boxes(pb, client, b)  # a scan's thousands of boxes: as arrays, not one by one
            part = _box_tables(*boxes) if boxes is not None else _element_tables(scene_elements(pb, client, b))
            parts.append(part)
            element_body += [b] * len(part["el_np"])
        element_body_ids = np.array(element_body, dtype=int)
        allowed = np.ones((len(links), len(element_body_ids)), dtype=bool)
        for link, other in world._allowed_bodies:
            allowed[slot_of[link], element_body_ids == other] = False
        scene_tables = self._scene_tables(parts)
        self.tables: kernel.Tables = kernel.as_tables({**robot_tables, **scene_tables, "touches": allowed})

    @classmethod
    def robot_part(cls, world: CollisionWorld) -> tuple[LinkFrames, set[int], dict[str, np.ndarray], dict[int, int]]:
        """What does not depend on the scene: the link frames, the links left to one sphere, the links'
        tables (spheres, hulls, self pairs, which links meet the scene), pybullet link -> slot."""
        pb, client, body, robot = world._pb, world.client, world.body, world.robot
        count = pb.getNumJoints(body, physicsClientId=client)
        links = list(range(-1, count))
        names = world.link_names()
        placement = world.scene.robot
        frames = LinkFrames(robot, placement.position, placement.quaternion(), names)
        elements = link_elements(robot.load_path or robot.urdf_path, robot.packages)
        shapes = {i: elements.get(name) for i, name in zip(links, names)}
        fallback = cls._check_against_pybullet(world, frames, links, shapes)
        radii = world._geometry_radii(count) if fallback else {}
        outer, inner, hulls = [], [], []
        for slot, i in enumerate(links):
            if i in fallback:  # one sphere around all pybullet has for the link, nothing sure inside
                outer.append((np.zeros((1, 3)), np.array([radii[i] + PAD])))
                inner.append((np.zeros((0, 3)), np.zeros(0)))
                continue
            parts = [cover(e) for e in shapes[i] or []]
            none = (np.zeros((0, 3)), np.zeros(0), np.zeros((0, 3)), np.zeros(0))
            outer.append((np.vstack([p[0] for p in parts] or [none[0]]), np.concatenate([p[1] for p in parts] or [none[1]])))
            inner.append((np.vstack([p[2] for p in parts] or [none[2]]), np.concatenate([p[3] for p in parts] or [none[3]])))
            hulls += [(slot, e) for e in shapes[i] or []]
        has = [len(r) > 0 for _, r in outer]
        slot_of = {i: k for k, i in enumerate(links)}
        pairs = [(slot_of[a], slot_of[b]) for a in links for b in links
                 if not world.part and a < b and (a, b) not in world._excluded and has[slot_of[a]] and has[slot_of[b]]]
        tables = {**frames.tables(), **cls._sphere_tables(outer, inner), **cls._hull_tables(hulls, len(links)),
                  "pairs": np.array(pairs, dtype=np.int64).reshape(-1, 2),
                  "scene_links": np.array([i not in world._fixed_to_base and has[k] for k, i in enumerate(links)])}
        return frames, fallback, tables, slot_of

    @staticmethod
    def _sphere_tables(outer, inner) -> dict[str, np.ndarray]:
        out: dict[str, np.ndarray] = {}
        for name, groups in (("outer", outer), ("inner", inner)):
            centres, counts = _stacked([c for c, _ in groups], (3,))
            out |= {f"{name}_c": centres, f"{name}_r": _stacked([r for _, r in groups], ())[0], f"{name}_n": counts}
        # per link, one sphere around its outer spheres: the broad phase
        bound_c, bound_r = np.zeros((len(outer), 3)), np.zeros(len(outer))
        for k, (c, r) in enumerate(outer):
            if len(r):
                bound_c[k] = (c.min(axis=0) + c.max(axis=0)) / 2
                bound_r[k] = np.max(np.linalg.norm(c - bound_c[k], axis=1) + r)
        return out | {"bound_c": bound_c, "bound_r": bound_r}

    @staticmethod
    def _hull_tables(elements: list[tuple[int, Convex]], links: int) -> dict[str, np.ndarray]:
        """Every element's corners and faces (link frame), where spheres cannot tell two shapes apart; and
        its points surely inside it, and half-spaces inside it, where spheres cannot tell they overlap."""
        points_in, counts_in = _stacked([e.inner_points() for _, e in elements], (3,))
        tables = {"hull_in": points_in, "hull_in_n": counts_in, "hull_in_planes": _planes([e.planes for _, e in elements]),
                  "hull_in_nj": np.array([len(e.planes) for _, e in elements], dtype=np.int64)}
        hulls = [(k, e.points) for k, e in elements]
        points, counts = _stacked([p for _, p in hulls], (3,))
        faces = [outer_planes(e) for _, e in elements]  # a box's, a prism's or a k-DOP's faces, else the hull's
        centres = np.array([(p.min(axis=0) + p.max(axis=0)) / 2 for _, p in hulls]).reshape(-1, 3)
        per_link = [[h for h, (k, _) in enumerate(hulls) if k == slot] for slot in range(links)]
        link_hulls = np.full((links, max([len(h) for h in per_link] + [1])), -1, dtype=np.int64)
        for slot, hs in enumerate(per_link):
            link_hulls[slot, :len(hs)] = hs
        exact = [e.exact if e.exact is not None else (e.points, f) for (_, e), f in zip(elements, faces)]
        exact_points, exact_counts = _stacked([p for p, _ in exact], (3,))
        tables |= {"fine_points": exact_points, "fine_np": exact_counts,
                   "fine_planes": _planes([f for _, f in exact]),
                   "fine_nj": np.array([len(f) for _, f in exact], dtype=np.int64),
                   "coarse": np.array([e.exact is not None for _, e in elements], dtype=np.int64)}
        return {"hull_points": points, "hull_np": counts,
                "hull_planes": _planes(faces), "hull_nj": np.array([len(f) for f in faces], dtype=np.int64),
                "hull_c": centres,
                "hull_r": np.array([np.max(np.linalg.norm(p - c, axis=1)) for (_, p), c in zip(hulls, centres)]),
                "link_hulls": link_hulls, "link_nh": np.array([len(h) for h in per_link], dtype=np.int64)} | tables

    @staticmethod
    def _scene_tables(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
        """The scene's elements, body by body (`_element_tables`, `_box_tables`), as one set of tables: each
        body's widened to the widest (points padded with zeros past their count, half-spaces by repeating one)."""
        out: dict[str, np.ndarray] = {}
        for name, pad_by_repeat in (("el_points", False), ("el_in", False), ("el_outer", True), ("el_inner", True)):
            width = max([p[name].shape[1] for p in parts] + [1])
            out[name] = np.concatenate([_widened(p[name], width, pad_by_repeat) for p in parts]
                                       or [np.zeros((0, width, 4 if pad_by_repeat else 3))])
        for name in ("el_np", "el_in_n", "el_outer_n", "el_inner_n"):
            out[name] = np.concatenate([p[name] for p in parts] or [np.zeros(0, dtype=np.int64)]).astype(np.int64)
        corners, counts = out["el_points"], out["el_np"]
        held = (np.arange(corners.shape[1]) < counts[:, None])[..., None]  # the padding left out
        centres = (np.where(held, corners, np.inf).min(axis=1) + np.where(held, corners, -np.inf).max(axis=1)) / 2
        radii = np.where(held[..., 0], np.linalg.norm(corners - centres[:, None], axis=2), 0.0).max(axis=1, initial=0.0)
        return _groups(centres, radii) | out | {"el_c": centres, "el_r": radii}

    @staticmethod
    def _check_against_pybullet(world: CollisionWorld, frames: LinkFrames, links: list[int],
                                shapes: dict[int, list[Convex] | None]) -> set[int]:
        """Links whose geometry as read here is not pybullet's: another number of shapes, or outside
        pybullet's AABB of the link at one of three poses."""
        pb, client, body, robot = world._pb, world.client, world.body, world.robot
        lows, highs = robot.lows(), robot.highs()
        rng = np.random.default_rng(7)
        poses = np.vstack([np.clip(np.zeros(len(lows)), lows, highs), rng.uniform(lows, highs, (2, len(lows)))])
        rot, pos = frames.frames(poses)
        bad = {i for i in links if shapes[i] is None
               or len(shapes[i] or []) != len(pb.getCollisionShapeData(body, i, physicsClientId=client))}
        for k, q in enumerate(poses):
            world._set(world._values(q[None])[0])
            for slot, i in enumerate(links):
                if i in bad:
                    continue
                lo, hi = pb.getAABB(body, i, physicsClientId=client)
                if not within([e.moved(rot[k, slot], pos[k, slot]) for e in shapes[i] or []], lo, hi):
                    bad.add(i)
        return bad

    def verdicts(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values (SI) -> (N,) FREE, COLLIDES or UNSURE; memory grows with CHUNK, not N."""
        return self._run(q, -1)[0]

    def verdicts_and_tips(self, q: np.ndarray, tip: str) -> tuple[np.ndarray, np.ndarray]:
        """`verdicts`, and link `tip`'s origins in the robot's base frame (m) from the same pass."""
        out, tips = self._run(q, self.frames.names.index(tip))
        return out, self.frames.to_base(tips)

    def verdicts_of_values(self, values: np.ndarray, tip: str, tips: np.ndarray) -> np.ndarray:
        """`verdicts` of joint values made beforehand (`frames.values`), link `tip`'s origins into `tips`
        (world frame: `frames.to_base` them): nothing but the compiled loop, which holds no GIL, so it runs
        at full speed on a thread beside Python work (numpy's steps in `verdicts` wait for the GIL behind
        a busy thread)."""
        slot = self.frames.names.index(tip)
        out = np.empty(len(values), dtype=np.int8)
        for start in range(0, len(values), CHUNK):
            out[start:start + CHUNK] = self._loop(values[start:start + CHUNK], slot, tips[start:start + CHUNK])
        return out

    def _run(self, q: np.ndarray, slot: int) -> tuple[np.ndarray, np.ndarray]:
        q = np.atleast_2d(np.asarray(q, dtype=float))
        out = np.empty(len(q), dtype=np.int8)
        tips = np.empty((len(q) if slot >= 0 else 1, 3))
        for start in range(0, len(q), CHUNK):
            where = tips[start:start + CHUNK] if slot >= 0 else tips
            out[start:start + CHUNK] = self._loop(self.frames.values(q[start:start + CHUNK]), slot, where)
        return out, tips

    def _loop(self, values: np.ndarray, slot: int, tips: np.ndarray) -> np.ndarray:
        """The compiled loop over one chunk, on all cores (one launch at a time in a process)."""
        with LAUNCH:
            return kernel.verdicts(values, self.tables, PAD, SURE_DEPTH, slot, tips)

    def verdicts_here(self, q: np.ndarray, grow: np.ndarray | None = None) -> np.ndarray:
        """`verdicts` on this thread, without the cores' start-up: for a few dozen states (a segment).

        `grow` (m, per link slot, then per self pair: `FastCollision.grow_radii`): FREE then also holds for
        every configuration whose links lie within that of their place here, and pairs of links within that
        of where they stand to each other (the stretch of a segment around it); COLLIDES and UNSURE speak of
        the state."""
        q = np.ascontiguousarray(np.atleast_2d(q), dtype=float)
        robot = self.frames.robot
        passive = np.ascontiguousarray(np.atleast_2d(robot.passive(q)) if robot.passive is not None
                                       else np.zeros((len(q), 0)), dtype=float)
        grow = self._still if grow is None else np.asarray(grow, dtype=float)
        return kernel.verdicts_packed(q, passive, *self._packed, PAD, SURE_DEPTH, grow)

    @functools.cached_property
    def _packed(self) -> tuple:
        """The joint-value maps and the tables packed in three arrays: the one-thread loops' arguments."""
        return (*self.frames.value_maps(), *kernel.pack(self.tables))

    def verdict(self, q: np.ndarray) -> int:
        """One configuration (n,) SI -> FREE, COLLIDES or UNSURE, on this thread (a planner's hot path)."""
        return int(self.verdicts_here(np.asarray(q, dtype=float)[None])[0])


REACH_POSES = 2000  # random configurations that show where a robot's links reach (`ScanClearance.reach`)
REACH_MARGIN = 0.1  # m beyond that which a scan's distance field covers


class ScanClearance:
    """The configurations a world of scans alone surely does not touch, found in a few numpy steps: each
    link's spheres looked up in the scans' distance fields (`scan_bodies.clearance`), the sphere around
    the link first, its outer spheres where that one may touch. Such a configuration is one the sphere
    model would find free (its outer spheres reach no padded box); the rest go on to it."""

    def __init__(self, model: SphereModel, fields: list):
        self.model, self.fields = model, fields

    @classmethod
    def of(cls, world: CollisionWorld, model: SphereModel) -> ScanClearance | None:
        """For a world holding `part` of a scene (no self pairs) whose bodies are all scans, else None."""
        from tdgen.robot.scan_bodies import clearance, scan_of

        if not world.part or not world._scene_names:
            return None
        scans = [scan_of(world._pb, world.client, body) for body in world._scene_names]
        if any(scan is None for scan in scans):
            return None
        within = cls.reach(world, model)
        return cls(model, [clearance(scan, within) for scan in scans if scan is not None])

    @staticmethod
    def reach(world: CollisionWorld, model: SphereModel) -> tuple[np.ndarray, np.ndarray]:
        """A box around what the robot's links reach where it stands, as far as `REACH_POSES` random
        configurations show (and `REACH_MARGIN` more): a field need not be made further out. An estimate is
        enough: a sphere beyond the box is never cleared, so a box too small costs time, not safety."""
        robot, t = world.robot, model.tables
        q = np.random.default_rng(0).uniform(robot.lows(), robot.highs(), (REACH_POSES, len(robot.joints)))
        rot, pos = model.frames.frames(q)
        centres = np.einsum("nkij,kj->nki", rot, t.bound_c) + pos  # each link's sphere around its spheres
        base = np.asarray(world.scene.robot.position, dtype=float)
        meets = np.asarray(t.scene_links, dtype=bool)
        far = np.linalg.norm(centres[:, meets] - base, axis=2) + t.bound_r[meets]
        radius = float(far.max(initial=0.0)) + REACH_MARGIN
        return base - radius, base + radius

    def clear(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values -> (N,) bool: surely touching no scan."""
        out = np.ones(len(q), dtype=bool)
        for start in range(0, len(q), CHUNK):
            values = self.model.frames.values(q[start:start + CHUNK])
            for field in self.fields:
                with LAUNCH:
                    out[start:start + CHUNK] &= kernel.clear_of_field(values, self.model.tables, field.centres,
                                                                      field.origin, field.cell)
        return out


class FastCollision:
    """The exact test's answers at the sphere model's speed: a `CollisionWorld` and its `SphereModel`."""

    def __init__(self, world: CollisionWorld, warm: bool = False):
        """`warm`: a planner's model, whose checks have a time budget: the one-state code loaded now, not in
        a first check. On a machine that has not compiled it yet (`cores.compiled()`), a warm model does
        not compile here (every other Thing of its process would wait): it answers with the
        exact test (the same answers, slower) while the code compiles in a process of its own
        (`cores.compile_in_background`), and loads the compiled code at its first check after that.
        A world that holds `part` of a scene has no self pairs (`CollisionWorld`)."""
        self.world = world
        self.spheres = SphereModel(world)
        self.scans = ScanClearance.of(world, self.spheres)  # a world of scans: most samples cleared at once
        self.unsure = 0  # configurations left to the exact test so far (a figure for the benchmark)
        self._exact_until = 0.0 if not warm or compiled() else time.monotonic()  # when to look for the code again
        if self._exact_until:
            compile_in_background(sys.modules[__name__])
        elif warm:
            self.load()

    def load(self) -> None:
        """Load (or compile, where it is not on disk) the one-state code."""
        home = np.clip(np.zeros(len(self.world.robot.joints)), self.world.robot.lows(), self.world.robot.highs())
        self.spheres.verdict(home)
        self.spheres.verdicts_here(home[None])

    @property
    def exact_only(self) -> bool:
        """Whether this model answers with the exact test alone, the compiled code not on disk yet (a warm
        model on a machine compiling it): looked for at most every `LOOK_EVERY` seconds."""
        if not self._exact_until or time.monotonic() < self._exact_until:
            return bool(self._exact_until)
        if not compiled():
            self._exact_until = time.monotonic() + LOOK_EVERY
            return True
        self._exact_until = 0.0
        self.load()
        return False

    def colliding(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values (SI) -> (N,) bool, as `CollisionWorld.colliding` answers."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        if self.exact_only:
            return self.world.colliding(q)
        if self.scans is not None and len(q):
            out = np.zeros(len(q), dtype=bool)
            rest = np.flatnonzero(~self.scans.clear(q))
            if len(rest):
                out[rest] = self._colliding(q[rest])
            return out
        return self._colliding(q)

    def _colliding(self, q: np.ndarray) -> np.ndarray:
        verdict = self.spheres.verdicts(q)
        out = verdict == COLLIDES
        unsure = np.flatnonzero(verdict == UNSURE)
        self.unsure += len(unsure)
        if len(unsure):
            out[unsure] = self.world.colliding(q[unsure])
        return out

    def collides(self, q: np.ndarray) -> bool:
        """One configuration (n,) SI: as `CollisionWorld.collides` answers (planners' hot path)."""
        if self.exact_only:
            return self.world.collides(q)
        verdict = self.spheres.verdict(q)
        if verdict == UNSURE:
            self.unsure += 1
            return self.world.collides(q)
        return verdict == COLLIDES

    def first_collision(self, states: np.ndarray) -> bool:
        """Does any of these states (K, n) collide? The spheres judge all at once on this thread; the
        exact test then the unsure ones in the order given (a segment's bisection order), to the first."""
        if self.exact_only:
            return any(self.world.collides(state) for state in states)
        unsure = []
        start, size = 0, 4
        while start < len(states):  # growing slices: a colliding segment is usually found out in the first
            verdict = self.spheres.verdicts_here(states[start:start + size])
            if np.any(verdict == COLLIDES):
                return True
            unsure += [start + k for k in np.flatnonzero(verdict == UNSURE)]
            start, size = start + size, size * 4
        for k in unsure:
            self.unsure += 1
            if self.world.collides(states[k]):
                return True
        return False

    def covering(self, states: np.ndarray, grow: np.ndarray) -> np.ndarray | None:
        """Which states (K, n) the spheres find free with each link and pair grown by its `grow` (m, in the
        order of `grow_radii`): each such one vouches for every configuration whose links and pairs lie within
        that of their place in it; None as soon as one surely collides. Judged in growing slices in the order
        given, on this thread. The exact test alone (`exact_only`) vouches for none."""
        covered = np.zeros(len(states), dtype=bool)
        if self.exact_only:
            return covered
        start, size = 0, 4
        while start < len(states):
            verdict = self.spheres.verdicts_here(states[start:start + size], grow)
            if np.any(verdict == COLLIDES):
                return None
            covered[start:start + size] = verdict == FREE
            start, size = start + size, size * 4
        return covered

    def what_collides(self, q: np.ndarray) -> list[str]:
        return self.world.what_collides(q)

    def sweep_radii(self) -> np.ndarray:
        return self.world.sweep_radii()

    def grow_radii(self) -> np.ndarray:
        """Per main joint, how far (m per unit) what each of the model's grown shapes stands for moves:
        (n, link slots + self pairs), each link in the world, each pair of links relative to each other
        (`CollisionWorld.link_sweep_radii`); the order of `covering`'s `grow`."""
        slot_of = self.spheres.slot_of
        link_of = {slot: link for link, slot in slot_of.items()}
        pairs = [(link_of[int(a)], link_of[int(b)]) for a, b in self.spheres.tables.pairs]
        per_link, per_pair = self.world.link_sweep_radii(pairs)
        out = np.zeros((len(per_link), len(slot_of)))
        for link, slot in slot_of.items():
            out[:, slot] = per_link[:, link + 1]
        return np.hstack([out, per_pair])

    def close(self) -> None:
        self.world.close()


def compile_all(wait: bool = True) -> None:
    """Compile (or load) every compiled function a lab runs, on a UR10 in table-and-wall (one specialisation
    serves every robot and scene: `sphere_kernel.as_tables`), then write `cores.compiled_stamp()`. Another
    process already at it (a lock on the stamp's folder): wait for it (then load), or with `wait` false
    leave it to that one."""
    import fcntl

    from tdgen.robot import points_csv
    from tdgen.robot.kinematics import ForwardKinematics
    from tdgen.robot.surroundings import load_scene

    compiling_here()
    folder = compiled_code_dir()
    folder.mkdir(parents=True, exist_ok=True)
    handed = os.environ.pop(LOCK_FD, None)  # held already: taken by the process that started this one
    with open(int(handed), "w") if handed else open(folder / COMPILING_LOCK, "w") as lock:
        try:
            if not handed:
                fcntl.flock(lock, fcntl.LOCK_EX | (0 if wait else fcntl.LOCK_NB))
        except BlockingIOError:
            return
        robot = Robot.load("ur10.urdf")
        world = CollisionWorld(robot, load_scene("table-and-wall"))
        try:
            fast = FastCollision(world)
            fast.load()  # the one-thread loop
            q = np.random.default_rng(0).uniform(robot.lows(), robot.highs(), (64, len(robot.joints)))
            verdict, tips = fast.spheres.verdicts_and_tips(q, robot.ee_link)  # the loop on all cores
            fast.spheres.frames.positions(q, robot.ee_link)  # the tips alone (the exact model's points)
            kernel.clear_of_field(fast.spheres.frames.values(q), fast.spheres.tables,  # a scan's distance field
                                  np.zeros((1, 1, 1), dtype=np.float32), np.zeros(3), 1.0)
            points_csv.encode(robot, tips * 1000.0, verdict == COLLIDES, q, compile_here=True)
            ForwardKinematics(robot).positions(q[0])
        finally:
            world.close()
        compiled_stamp().touch()


compiles_everything(sys.modules[__name__])  # kinematics, below us, starts the compile without importing us


if __name__ == "__main__":  # `cores.compile_in_background`
    compile_all(wait=False)
