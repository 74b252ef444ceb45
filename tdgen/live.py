"""A generated workspace that follows its scene: a body added or removed re-checks only what it can change.

A robot's samples are random configurations drawn from its seed; a new scene changes none of them,
only their collision flags. A generation checks them in its scene, the base; what is added to the base
later (a box put on the table) can only make base-free samples collide, and only those it touches. So
each added body keeps the base-free samples it touches (found in a collision world holding only that
body: their self- and other collisions are known to be none), and a sample collides where it collided
in the base or touches an added body. Adding a body checks the base-free samples against it alone;
removing an added body checks nothing; moving one is a removal and an addition. A change to the base
itself (its table removed) needs a generation. The flags are those a generation from scratch finds
(the tests compare them), in a fraction of a generation's time (docs/benchmarks.md: live updates).
What each body was found to touch, and what collides with it, is kept by its content (`Worlds`): the
same body added again (a scan taken away and put back) checks nothing. The TD's warnings take what
collided in the base and what collides with each added body alone, so no world of the whole scene is
ever built (a scan's thousands of triangles in it would cost each pair asked there).
"""
from __future__ import annotations

import gc
from collections import Counter, OrderedDict
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import numpy as np

from tdgen.robot import points_csv
from tdgen.robot.collision import CollisionWorld, body_names
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import Body, Surroundings, content_key
from tdgen.sampling import Samples, random_configurations

if TYPE_CHECKING:
    from tdgen.robot.fast_collision import FastCollision


class NeedsGeneration(ValueError):
    """The change is not one a live update can follow (the robot moved, a body of the base went)."""


def changed_bodies(old: Surroundings, new: Surroundings) -> tuple[list[Body], list[Body]]:
    """(removed, added): bodies of `old` not in `new`, bodies of `new` not in `old` (as multisets)."""
    before, after = Counter(map(_key, old.bodies)), Counter(map(_key, new.bodies))
    return _take(old.bodies, before - after), _take(new.bodies, after - before)


def _key(body: Body) -> bytes:
    return msgspec.json.encode(body)


def _added(base: Surroundings, scene: Surroundings) -> list[tuple[int, Body]]:
    """The bodies of `scene` not in `base` (as multisets, `changed_bodies`), each with its place in `scene`."""
    left, out = Counter(map(_key, base.bodies)), []
    for k, body in enumerate(scene.bodies):
        if left[_key(body)] > 0:
            left[_key(body)] -= 1
        else:
            out.append((k, body))
    return out


def _take(bodies: list[Body], wanted: Counter[bytes]) -> list[Body]:
    left, out = Counter(wanted), []
    for body in bodies:
        if left[_key(body)] > 0:
            left[_key(body)] -= 1
            out.append(body)
    return out


KEPT = 16  # bodies whose answers a robot's worlds keep (a scan added again, a box put back)


class _Answers:
    """What is known of one body against the base samples: per sample, touching or not (-1: not asked
    yet), and the pairs that collide with it where asked."""

    def __init__(self, samples: int):
        self.touching = np.full(samples, -1, dtype=np.int8)
        self.pairs: dict[int, list[str]] = {}


class Worlds:
    """The collision worlds a robot's live updates ask and what they answered, kept between updates: one
    world with only the body being checked, without self-collision (`part`), one of the base (which pairs
    collide there, for the TD's warnings). Answers are kept per body and its file's content (`KEPT` of
    them): a scan added again, or a box put back where it was, asks no world."""

    def __init__(self, robot: Robot, base: Surroundings, q: np.ndarray):
        """`q`: the base samples' configurations, which every question names by row."""
        self.robot, self.base, self.q = robot, base, q
        self._part: CollisionWorld | None = None
        self._base: CollisionWorld | None = None
        self._base_pairs: dict[int, list[str]] = {}
        self._at_rest: list[str] | None = None
        self._part_model: tuple[bytes, FastCollision] | None = None  # the part world's, for the body it holds
        self._answers: OrderedDict[bytes, _Answers] = OrderedDict()

    def part(self, bodies: list[Body], keys: list[bytes] | None = None) -> CollisionWorld:
        """The part world holding `bodies` (their `content_key`s, if known)."""
        if self._part is None:
            self._part = CollisionWorld(self.robot, msgspec.structs.replace(self.base, bodies=[]), part=True)
        self._part.set_bodies(bodies, keys)
        return self._part

    def _of(self, key: bytes) -> _Answers:
        held = self._answers.get(key)
        if held is None:
            held = self._answers[key] = _Answers(len(self.q))
            while len(self._answers) > KEPT:
                self._answers.popitem(last=False)
        self._answers.move_to_end(key)
        return held

    def touching(self, body: Body, rows: np.ndarray, model: str = "fast",
                 key: bytes | None = None) -> tuple[np.ndarray, int]:
        """Which of the base samples `rows` touch `body` (`touching`), and how many were checked: only rows
        not asked before, in the part world holding it, whose fast model is kept while it holds the body (an
        update asks for the samples, then for its warnings; a scan's model is thousands of pieces). `key`:
        the body's `content_key`, if known (a scan written just now is hashed each time it is asked)."""
        key = key or content_key(body)
        answers = self._of(key)
        ask = rows[answers.touching[rows] < 0]
        if len(ask):
            world = self.part([body], [key])
            if model == "exact":
                hit = touching(world, self.q[ask], model)
            else:
                if self._part_model is None or self._part_model[0] != key:
                    from tdgen.robot.fast_collision import FastCollision

                    self._part_model = (key, FastCollision(world))
                hit = self._part_model[1].colliding(self.q[ask])
            answers.touching[ask] = hit
        return answers.touching[rows] == 1, len(ask)

    def pairs_with(self, body: Body, rows: np.ndarray, key: bytes | None = None) -> list[list[str]]:
        """What collides with `body` alone in each of the base samples `rows` (`CollisionWorld.what_collides`,
        the body named as a scene of it alone names it); `key` as for `touching`."""
        key = key or content_key(body)
        answers = self._of(key)
        ask = [int(row) for row in rows if int(row) not in answers.pairs]
        if ask:
            world = self.part([body], [key])
            answers.pairs |= {row: world.what_collides(self.q[row]) for row in ask}
        return [answers.pairs[int(row)] for row in rows]

    def base_pairs(self, row: int) -> list[str]:
        """What collides in sample `row` in the base scene, asked once."""
        if row not in self._base_pairs:
            if self._base is None:
                self._base = CollisionWorld(self.robot, self.base)
            self._base_pairs[row] = self._base.what_collides(self.q[row])
        return self._base_pairs[row]

    def at_rest(self) -> list[str]:
        from tdgen.generate import robot_at_rest

        if self._at_rest is None:
            self._at_rest = robot_at_rest(self.robot, self.base)
        return self._at_rest

    def close(self) -> None:
        for world in (self._part, self._base):
            if world is not None:
                world.close()
        self._part = self._base = None
        self._part_model = None


def touching(world: CollisionWorld, q: np.ndarray, model: str = "fast") -> np.ndarray:
    """Which of q touch the bodies of `world`, a world holding `part` of a scene (contacts with them only,
    by the collision rules of the whole scene: links bolted to the base and allowed pairs do not count)."""
    if not len(q) or not world.scene.bodies:
        return np.zeros(len(q), dtype=bool)
    if model == "exact":
        return world.colliding(q)
    from tdgen.robot.fast_collision import FastCollision

    return FastCollision(world).colliding(q)


class LiveSamples:
    """One robot's generated samples and points file in its base scene, following the bodies added to it.
    Holds pybullet worlds: `close()` it when done."""

    def __init__(self, robot: Robot, base: Surroundings, samples: Samples, points: bytes | bytearray | points_csv.Flags,
                 model: str = "fast", scene: Surroundings | None = None,
                 touches: dict[bytes, np.ndarray] | None = None, worlds: Worlds | None = None):
        """`samples` and `points` as generated in `base`; `scene` (default: the base) and `touches` (per
        added body, the indices of the base-free samples it touches) as a live update left them."""
        self.robot, self.base, self.model = robot, base, model
        self.scene = scene or base
        self.base_samples = samples
        self.touches = touches or {}
        self.worlds = worlds or Worlds(robot, base, samples.q)
        collision = samples.collision.copy()
        for rows in self.touches.values():
            collision[rows] = True
        self.samples = Samples(samples.q, samples.positions, collision)
        flags = points if isinstance(points, points_csv.Flags) else points_csv.Flags(points)
        if len(flags.offsets) != len(samples.q):
            raise ValueError(f"points file of {len(flags.offsets)} rows for {len(samples.q)} samples")
        self.base_flags = flags
        self.flags = flags.reflagged(collision) if self.touches else flags

    @classmethod
    def from_file(cls, robot: Robot, scene: Surroundings, samples: int, seed: int | None, points: Path,
                  model: str = "fast") -> LiveSamples:
        """From a generation's points.csv: the configurations drawn again from the seed (the same draw
        `sample_workspace` made), the positions and flags as the file has them."""
        data = points.read_bytes()
        positions, collision = points_csv.read_bytes(data, str(points))
        q = random_configurations(robot, samples, seed)
        return cls(robot, scene, Samples(q, positions, collision), data, model)

    def rescene(self, scene: Surroundings) -> tuple[LiveSamples, int]:
        """The same samples in `scene`, and how many configurations were checked (the new one shares this
        one's worlds). NeedsGeneration when the robot moved or a body of the base is not in `scene`."""
        if scene.robot != self.base.robot:
            raise NeedsGeneration("the robot moved: its samples must be generated again")
        gone, added = changed_bodies(self.base, scene)
        if gone:
            raise NeedsGeneration(f"{len(gone)} bodies of the generated scene are gone (first {gone[0].name!r})")
        base_free = np.flatnonzero(~self.base_samples.collision)
        touches, checked = {}, 0
        for body in added:
            key = _key(body)
            if key in touches:
                continue
            if key in self.touches:
                touches[key] = self.touches[key]
                continue
            hit, asked = self.worlds.touching(body, base_free, self.model, content_key(body))
            touches[key] = base_free[hit]
            checked += asked
        live = LiveSamples(self.robot, self.base, self.base_samples, self.base_flags, self.model, scene, touches,
                           self.worlds)
        return live, checked

    def warnings(self) -> list[str]:
        """`tdgen.generate.collision_warnings` of the samples in their scene (`pairs`)."""
        from tdgen.generate import BY_DESIGN, collision_warnings

        if float(self.samples.collision.mean()) < BY_DESIGN:
            return []
        return collision_warnings(self.robot, self.scene, self.samples, self.worlds.at_rest(), self.pairs())

    def pairs(self) -> list[list[str]]:
        """What collides in each of the first `PAIR_SAMPLES` colliding samples, as a world of the whole scene
        names it: what collided in the base (kept from the first update on; nothing, in a sample free there),
        and what collides with each added body the sample touches, asked of a world holding that body alone
        (a scan is never built into a world of the whole scene, and its answers are kept with it)."""
        from tdgen.generate import PAIR_SAMPLES

        rows = np.flatnonzero(self.samples.collision)[:PAIR_SAMPLES]
        found = [list(self.worlds.base_pairs(int(i))) if self.base_samples.collision[i] else [] for i in rows]
        names = body_names(self.scene)
        for place, body in _added(self.base, self.scene):
            alone, key = body.name or "body 0", content_key(body)
            hit, _ = self.worlds.touching(body, rows, self.model, key)
            touched = np.flatnonzero(hit)
            for at, pairs in zip(touched, self.worlds.pairs_with(body, rows[touched], key)):
                for pair in pairs:
                    link, _, other = pair.rpartition(" / ")
                    pair = f"{link} / {names[place]}" if other == alone else pair
                    if pair not in found[at]:
                        found[at].append(pair)
        return found

    def prepare(self) -> None:
        """Load the kept worlds, hash the samples and ask what collides in the base's first samples now,
        between updates, so that the first update does not wait for them (nor for the module that makes a
        scan's distance field, nor for the garbage collector walking all of it)."""
        from scipy import ndimage  # noqa: F401 - imported once here, not in the first scan's update

        from tdgen.generate import PAIR_SAMPLES

        self.base_flags.samples_sha  # noqa: B018 - hashed once here, not in the first update's digest
        for row in np.flatnonzero(self.base_samples.collision)[:PAIR_SAMPLES]:
            self.worlds.base_pairs(int(row))
        self.worlds.at_rest()
        part = self.worlds.part([])
        if self.model == "fast":  # the robot's spheres for a world of parts, fitted once per robot
            from tdgen.robot.fast_collision import FastCollision

            FastCollision(part)
        gc.unfreeze()  # what an earlier prepare froze and has died since (a robot's worlds let go) is collected now
        gc.collect()
        gc.freeze()  # what is loaded by now lives as long as these worlds: the full collections that an update's
        # allocations (a scan's pybullet lists) set off no longer walk it, tens of ms each

    def close(self) -> None:
        self.worlds.close()
