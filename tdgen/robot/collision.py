"""Collision checking: one pybullet world with the surroundings and the robot, asked "does q collide?".

What counts as a collision (penetration deeper than `CONTACT_TOLERANCE`):
- the robot with itself, except pairs of links that are rigidly joined or joined by one joint
  ("adjacent"; joints no configuration moves, such as a Panda's finger, count as rigid) and pairs
  in contact both at the home pose (q = 0 clipped to the limits) and at mid-range: meshes that
  overlap by design (a Panda's hand and link 6), not poses that happen to fold the arm;
- the robot with a scene body, except the links rigidly fixed to the base: a robot bolted onto a
  table touches it in every configuration, which says nothing about the configuration.
"""
from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from tdgen.robot.errors import RobotError
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import Body, Surroundings, build_into, content_key

CONTACT_TOLERANCE = 1e-4  # m: contacts shallower than this are touching, not colliding


class CollisionWorld:
    """One pybullet DIRECT client with the scene and the robot: answers "does q collide?"."""

    def __init__(self, robot: Robot, scene: Surroundings, part: bool = False):
        """`part`: `scene` holds only some bodies of the robot's scene (a live update's added or removed
        ones) and only contacts with them count: the robot's self-collision is not tested, and an allowed
        link/body pair may name a body that is not here."""
        import pybullet as pb

        self._pb = pb
        self.robot = robot
        self.scene, self.part = scene, part
        self.client = pb.connect(pb.DIRECT)
        try:
            ids = build_into(scene, self.client)
            self._ids = ids
            self._held_as = dict(zip(ids, map(content_key, scene.bodies)))  # what each was built from (`set_bodies`)
            self._scene_names = _names(ids, scene)
            self.body = robot.load_into(self.client, scene.robot.position, math.radians(scene.robot.yaw),
                                        base_orientation=scene.robot.quaternion(),
                                        flags=0 if part else pb.URDF_USE_SELF_COLLISION)
        except Exception:
            pb.disconnect(self.client)
            raise
        count = pb.getNumJoints(self.body, physicsClientId=self.client)
        if not any(pb.getCollisionShapeData(self.body, i, physicsClientId=self.client) for i in range(-1, count)):
            pb.disconnect(self.client)
            raise RobotError(f"{robot.source or robot.urdf_path}: no link has collision or visual geometry: every "
                             "configuration would count as free; give the links <collision> shapes")
        names = {pb.getJointInfo(self.body, i, physicsClientId=self.client)[1].decode(): i
                 for i in range(count)}
        drives = robot.drives()
        self._indices = [names[n] for n in drives]
        # every driven joint as multiplier * source + offset, vectorised (`Robot.joint_values`, without
        # its per-call bookkeeping: planners check one state at a time)
        self._kind = np.array([d.kind for d in drives.values()])
        self._source = np.array([max(d.index, 0) for d in drives.values()])
        self._mult = np.array([d.multiplier if d.kind != "const" else 0.0 for d in drives.values()])
        self._offset = np.array([d.offset for d in drives.values()])
        self._main_cols = np.where(self._kind == "main", self._source, 0)
        self._passive_mask = self._kind == "passive"
        self._passive_cols = np.where(self._passive_mask, self._source, 0)
        group = self._rigid_groups()
        self._fixed_to_base = {link for link, g in group.items() if g == group[-1]}
        self._excluded = self._adjacent_pairs(group)
        self._excluded |= self._touching_by_design()
        self._excluded |= self._allowed_pairs()
        self._allowed_bodies = self._allowed_body_pairs(ids, part)
        for a, b in self._excluded:  # contacts `_colliding` ignores need not be computed (a Panda checks ~1/3 faster)
            if a < b:
                pb.setCollisionFilterPair(self.body, self.body, a, b, 0, physicsClientId=self.client)

    def close(self) -> None:
        self._pb.disconnect(self.client)

    def set_bodies(self, bodies: list[Body], keys: list[bytes] | None = None) -> None:
        """Make the scene's bodies `bodies`, the robot where it stands: bodies gone are removed, new ones
        built, the rest kept (a live update changes a box without loading the robot and the room again); a
        scan or mesh whose file's content changed is a new one (`content_key`; `keys`: theirs, if known)."""
        import msgspec

        held: dict[bytes, list[int]] = {}
        for i in self._ids:
            held.setdefault(self._held_as[i], []).append(i)
        wanted = keys if keys is not None else [content_key(body) for body in bodies]
        kept = [held[key].pop() if held.get(key) else None for key in wanted]
        for gone in held.values():  # first: a scan replacing a scan is not quieted against it (`build_into`)
            for i in gone:
                self._pb.removeBody(i, physicsClientId=self.client)
        ids = [i if i is not None else build_into(msgspec.structs.replace(self.scene, bodies=[body]), self.client)[0]
               for body, i in zip(bodies, kept)]
        self.scene = msgspec.structs.replace(self.scene, bodies=list(bodies))
        self._held_as = dict(zip(ids, wanted))
        self._ids, self._scene_names = ids, _names(ids, self.scene)
        self._allowed_bodies = self._allowed_body_pairs(ids, self.part)

    def _values(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values -> (N, m) values of every driven pybullet joint."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        source = q[:, self._main_cols]
        if self._passive_mask.any() and self.robot.passive is not None:
            passive = np.atleast_2d(self.robot.passive(q))
            source = np.where(self._passive_mask, passive[:, self._passive_cols], source)
        return source * self._mult + self._offset

    def _set(self, values: np.ndarray) -> None:
        self._pb.resetJointStatesMultiDof(self.body, self._indices, [[float(v)] for v in values],
                                          physicsClientId=self.client)

    def _rigid_groups(self) -> dict[int, int]:
        """link index -> group: links joined by fixed (or never moved) joints share a group."""
        pb, moving = self._pb, set(self._indices)
        group = {-1: -1}
        for i in range(pb.getNumJoints(self.body, physicsClientId=self.client)):  # parents come first
            parent = pb.getJointInfo(self.body, i, physicsClientId=self.client)[16]
            group[i] = i if i in moving else group[parent]
        return group

    def _adjacent_pairs(self, group: dict[int, int]) -> set[tuple[int, int]]:
        """Link pairs in one rigid group or in two groups joined by one joint."""
        pb = self._pb
        joined = {(g, g) for g in group.values()}
        for i in self._indices:
            parent = pb.getJointInfo(self.body, i, physicsClientId=self.client)[16]
            joined |= {(group[i], group[parent]), (group[parent], group[i])}
        return {(a, b) for a in group for b in group if (group[a], group[b]) in joined}

    def _touching_by_design(self) -> set[tuple[int, int]]:
        """Self-contact pairs at both the home pose (q = 0 within the limits) and mid-range."""
        lows, highs = self.robot.lows(), self.robot.highs()
        pairs = []
        for q in (np.clip(np.zeros(len(lows)), lows, highs), (lows + highs) / 2):
            self._set(self._values(q[None])[0])
            pairs.append({p for (a, b), other in self._contacts() if other == self.body for p in ((a, b), (b, a))})
        return pairs[0] & pairs[1]

    def _allowed_pairs(self) -> set[tuple[int, int]]:
        """The robot's allowed collisions (`Robot.allowed_collisions`, by link name), both ways."""
        count = self._pb.getNumJoints(self.body, physicsClientId=self.client)
        index = {self._link_name(i): i for i in range(-1, count)}
        return {p for a, b in self.robot.allowed_collisions if a in index and b in index
                for p in ((index[a], index[b]), (index[b], index[a]))}

    def _allowed_body_pairs(self, ids: list[int], part: bool = False) -> set[tuple[int, int]]:
        """(robot link, scene body) pairs whose contact does not count (`--allow-collision LINK/BODY`: a
        link that touches the surface the robot is mounted on by design)."""
        count = self._pb.getNumJoints(self.body, physicsClientId=self.client)
        links = {self._link_name(i): i for i in range(-1, count)}
        bodies = {name: i for i, name in self._scene_names.items()}
        out = set()
        for a, b in self.robot.allowed_collisions:
            if a in links and b in links:
                continue
            link, body = (a, b) if a in links else (b, a)
            if body not in bodies:
                if part:
                    continue
                raise ValueError(f"no link or scene body named {body!r} for the allowed collision {a}/{b} (scene "
                                 f"bodies: {', '.join(sorted(bodies)) or 'none'})")
            out.add((links[link], bodies[body]))
        return out

    def _contacts(self) -> list[tuple[tuple[int, int], int]]:
        """((robot link, other link), other body) for every penetrating contact of the robot."""
        pb = self._pb
        pb.performCollisionDetection(physicsClientId=self.client)
        found = []
        for c in pb.getContactPoints(bodyA=self.body, physicsClientId=self.client):
            if c[8] < -CONTACT_TOLERANCE:
                if c[1] == self.body:
                    found.append(((c[3], c[4]), c[2]))
                else:
                    found.append(((c[4], c[3]), c[1]))
        return found

    def _colliding(self) -> bool:
        for (link, other_link), other in self._contacts():
            if other == self.body:
                if (link, other_link) not in self._excluded:
                    return True
            elif link not in self._fixed_to_base and (link, other) not in self._allowed_bodies:
                return True
        return False

    def sweep_radii(self) -> np.ndarray:
        """Per main joint, a bound on how far (m) any point of the robot moves per unit of that joint.

        A revolute joint turns every link after it about an axis through its frame origin, so no
        point moves further than |dq| times its distance from that origin; that distance is bounded
        by the link-frame-to-link-frame lengths down the tree plus each link's geometry radius
        (its AABB corners from its frame origin), which no configuration changes. A prismatic
        joint moves its links by |dq|. Mimic joints add their multiplier's share to the joint that
        drives them, passive joints (a linkage's map) the largest slope of the map. Along a
        straight joint-space segment dq, no point moves more than sum(|dq_i| * radius_i).
        """
        return self.link_sweep_radii()[0].max(axis=1)

    def link_sweep_radii(self, pairs: Sequence[tuple[int, int]] = ()) -> tuple[np.ndarray, np.ndarray]:
        """`sweep_radii` per link and per pair of links, (n main joints, pybullet links -1..count-1) and
        (n main joints, len(pairs)): column k + 1 bounds how far link k's points move per unit of each
        joint (links near the base move less); a pair's column, how far the two move relative to each
        other, which only the joints between them change (a wrist's two ends, not the shoulder)."""
        reach, up = self._reach()
        count = len(up)

        def chain(k: int) -> set[int]:  # the joints from the base to link k
            out = set()
            while k >= 0:
                out.add(k)
                k = up[k]
            return out

        relative = np.zeros((count, len(pairs)))
        for p, (a, b) in enumerate(pairs):
            to_a, to_b = chain(a), chain(b)
            for x in to_a - to_b:
                relative[x, p] += reach[x, a + 1]
            for x in to_b - to_a:
                relative[x, p] += reach[x, b + 1]
        return self._per_main_joint(reach), self._per_main_joint(relative)

    def _reach(self) -> tuple[np.ndarray, list[int]]:
        """reach[j, k + 1]: how far link k's points can be from the origin of joint j (its child link's frame,
        for the links after it); and each link's parent."""
        pb, body, client = self._pb, self.body, self.client
        count = pb.getNumJoints(body, physicsClientId=client)
        up = [pb.getJointInfo(body, i, physicsClientId=client)[16] for i in range(count)]
        origin = {-1: np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])}
        for i in range(count):
            origin[i] = np.array(pb.getLinkState(body, i, computeForwardKinematics=True,
                                                 physicsClientId=client)[4])
        radius = self._geometry_radii(count)
        reach = np.zeros((count, count + 1))
        for k in range(count):
            x, d = k, radius[k]
            while x >= 0:
                reach[x, k + 1] = d
                d += float(np.linalg.norm(origin[x] - origin[up[x]]))
                x = up[x]
        return reach, up

    def _per_main_joint(self, per_joint: np.ndarray) -> np.ndarray:
        """Rows per pybullet joint -> rows per main joint: mimic joints add their multiplier's share, passive
        joints the largest slope of their map; a prismatic joint moves its links by |dq|."""
        pb, body, client = self._pb, self.body, self.client
        infos = [pb.getJointInfo(body, i, physicsClientId=client) for i in range(len(per_joint))]
        rows = {info[1].decode(): (np.where(per_joint[i] > 0, 1.0, 0.0) if info[2] == pb.JOINT_PRISMATIC
                                   else per_joint[i]) for i, info in enumerate(infos)}
        radii = np.zeros((len(self.robot.joints), per_joint.shape[1]))
        slopes = self._passive_slopes()
        for name, drive in self.robot.drives().items():
            if drive.kind == "main":
                radii[drive.index] += abs(drive.multiplier) * rows[name]
            elif drive.kind == "passive":
                radii += abs(drive.multiplier) * slopes[drive.index][:, None] * rows[name][None, :]
        return radii

    def _geometry_radii(self, count: int, poses: int = 24) -> dict[int, float]:
        """Per link, a bound on its collision geometry's distance from the link frame's origin.

        Every world AABB contains the geometry, so the farthest AABB corner bounds it in every pose;
        the smallest such bound over a few random poses is still a bound, and a tighter one (an
        axis-aligned box around a turned link is much larger than the link)."""
        pb, body, client = self._pb, self.body, self.client
        rng = np.random.default_rng(0)
        lows, highs = self.robot.lows(), self.robot.highs()
        radius = {k: np.inf for k in range(-1, count)}
        for q in [np.clip(np.zeros(len(lows)), lows, highs), *rng.uniform(lows, highs, (poses, len(lows)))]:
            self._set(self._values(q[None])[0])
            for k in range(-1, count):
                if k == -1:
                    frame = np.array(pb.getBasePositionAndOrientation(body, physicsClientId=client)[0])
                else:
                    frame = np.array(pb.getLinkState(body, k, computeForwardKinematics=True,
                                                     physicsClientId=client)[4])
                lo, hi = (np.array(v) for v in pb.getAABB(body, k, physicsClientId=client))
                corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
                radius[k] = min(radius[k], float(np.max(np.linalg.norm(corners - frame, axis=1))))
        return radius

    def _passive_slopes(self, samples: int = 64) -> np.ndarray:
        """(n_passive, n_main): the largest |d passive / d main| seen over random configurations (x1.25)."""
        robot = self.robot
        if robot.passive is None or not robot.passive_names:
            return np.zeros((0, len(robot.joints)))
        rng = np.random.default_rng(0)
        q = rng.uniform(robot.lows(), robot.highs(), (samples, len(robot.joints)))
        h = 1e-4
        slopes = np.zeros((len(robot.passive_names), len(robot.joints)))
        base = np.atleast_2d(robot.passive(q))
        for i in range(len(robot.joints)):
            dq = q.copy()
            dq[:, i] += h
            slopes[:, i] = np.max(np.abs(np.atleast_2d(robot.passive(dq)) - base), axis=0) / h
        return slopes * 1.25

    def what_collides(self, q: np.ndarray) -> list[str]:
        """For one configuration (n,) SI, the colliding pairs in words: `forearm_link / table`."""
        self._set(self._values(np.asarray(q)[None])[0])
        found: list[str] = []
        for (link, other_link), other in self._contacts():
            if other == self.body and (link, other_link) in self._excluded:
                continue
            if other != self.body and (link in self._fixed_to_base or (link, other) in self._allowed_bodies):
                continue
            mine = self._link_name(link)
            theirs = self._link_name(other_link) if other == self.body else self._scene_names.get(other, f"body {other}")
            pair = f"{mine} / {theirs}"
            if pair not in found and f"{theirs} / {mine}" not in found:
                found.append(pair)
        return found

    def link_names(self) -> list[str]:
        """Every link's name in pybullet's order, the base (index -1) first."""
        count = self._pb.getNumJoints(self.body, physicsClientId=self.client)
        return [self._link_name(i) for i in range(-1, count)]

    def _link_name(self, link: int) -> str:
        if link == -1:
            return self._pb.getBodyInfo(self.body, physicsClientId=self.client)[0].decode()
        return self._pb.getJointInfo(self.body, link, physicsClientId=self.client)[12].decode()

    def collides(self, q: np.ndarray) -> bool:
        """One configuration (n,) SI: does it collide with the robot itself or the scene? (planners' hot path)"""
        if self._passive_mask.any():
            return bool(self.colliding(np.asarray(q)[None])[0])
        self._set(np.asarray(q, dtype=float)[self._main_cols] * self._mult + self._offset)
        return self._colliding()

    def colliding(self, q: np.ndarray) -> np.ndarray:
        """(N, n) main-joint values (SI) -> (N,) bool: collides with itself or the scene."""
        values = self._values(np.atleast_2d(q))
        out = np.empty(len(values), dtype=bool)
        for k, row in enumerate(values):
            self._set(row)
            out[k] = self._colliding()
        return out


def body_names(scene: Surroundings) -> list[str]:
    """The scene bodies' names as pairs name them (`body k` for the k-th if it has none), in the scene's order."""
    return [b.name or f"body {k}" for k, b in enumerate(scene.bodies)]


def _names(ids: list[int], scene: Surroundings) -> dict[int, str]:
    """pybullet body id -> the scene body's name (`body_names`)."""
    return dict(zip(ids, body_names(scene)))
