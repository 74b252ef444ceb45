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
"""
from __future__ import annotations

from collections import Counter
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec
import numpy as np

from tdgen.robot import points_csv
from tdgen.robot.collision import CollisionWorld
from tdgen.robot.model import Robot
from tdgen.robot.surroundings import Body, Surroundings
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


def _take(bodies: list[Body], wanted: Counter[bytes]) -> list[Body]:
    left, out = Counter(wanted), []
    for body in bodies:
        if left[_key(body)] > 0:
            left[_key(body)] -= 1
            out.append(body)
    return out


class Worlds:
    """The collision worlds a robot's live updates ask, kept between updates (loading the robot and the
    room each time would be on every update's way): one with only the body being checked, without self-collision
    (`touching`), one of the whole scene now and one of the base (which pairs collide, for the TD's
    warnings)."""

    def __init__(self, robot: Robot, base: Surroundings):
        self.robot, self.base = robot, base
        self._part: CollisionWorld | None = None
        self._whole: CollisionWorld | None = None
        self._base: CollisionWorld | None = None
        self._base_pairs: dict[int, list[str]] = {}
        self._at_rest: list[str] | None = None
        self._part_model: tuple[bytes, FastCollision] | None = None  # the part world's, for the bodies it holds

    def part(self, bodies: list[Body]) -> CollisionWorld:
        if self._part is None:
            self._part = CollisionWorld(self.robot, msgspec.structs.replace(self.base, bodies=[]), part=True)
        self._part.set_bodies(bodies)
        return self._part

    def touching(self, bodies: list[Body], q: np.ndarray, model: str = "fast") -> np.ndarray:
        """`touching` in the part world holding `bodies`, its fast model kept while it holds them: an update
        asks it for the samples and again for its warnings (a scan's model is thousands of pieces)."""
        world = self.part(bodies)
        if model == "exact" or not len(q) or not bodies:
            return touching(world, q, model)
        held = msgspec.json.encode(bodies)
        if self._part_model is None or self._part_model[0] != held:
            from tdgen.robot.fast_collision import FastCollision

            self._part_model = (held, FastCollision(world))
        return self._part_model[1].colliding(q)

    def whole(self, scene: Surroundings) -> CollisionWorld:
        if self._whole is None:
            self._whole = CollisionWorld(self.robot, scene)
        else:
            self._whole.set_bodies(scene.bodies)
        return self._whole

    def base_pairs(self, row: int, q: np.ndarray) -> list[str]:
        """What collides in sample `row` (configuration q) in the base scene, asked once."""
        if row not in self._base_pairs:
            if self._base is None:
                self._base = CollisionWorld(self.robot, self.base)
            self._base_pairs[row] = self._base.what_collides(q)
        return self._base_pairs[row]

    def at_rest(self) -> list[str]:
        from tdgen.generate import robot_at_rest

        if self._at_rest is None:
            self._at_rest = robot_at_rest(self.robot, self.base)
        return self._at_rest

    def close(self) -> None:
        for world in (self._part, self._whole, self._base):
            if world is not None:
                world.close()
        self._part = self._whole = self._base = None
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
        self.worlds = worlds or Worlds(robot, base)
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
            hit = self.worlds.touching([body], self.base_samples.q[base_free], self.model)
            touches[key] = base_free[hit]
            checked += len(base_free)
        live = LiveSamples(self.robot, self.base, self.base_samples, self.base_flags, self.model, scene, touches,
                           self.worlds)
        return live, checked

    def warnings(self) -> list[str]:
        """`tdgen.generate.collision_warnings` of the samples in their scene. What collides in a sample is
        asked of the kept whole-scene world only where the added bodies can change it (a sample that
        collides because of them, or that collided in the base and touches them); elsewhere it is what
        collided in the base (kept from the first update on)."""
        from tdgen.generate import BY_DESIGN, PAIR_SAMPLES, collision_warnings

        if float(self.samples.collision.mean()) < BY_DESIGN:
            return []
        q = self.base_samples.q
        rows = np.flatnonzero(self.samples.collision)[:PAIR_SAMPLES]
        before = self.base_samples.collision[rows]
        kept, stale = rows[before], rows[~before]
        added = changed_bodies(self.base, self.scene)[1]
        if added and len(kept):
            hit = self.worlds.touching(added, q[kept], self.model)
            kept, stale = kept[~hit], np.concatenate([stale, kept[hit]])
        found = {int(i): self.worlds.base_pairs(int(i), q[i]) for i in kept}
        if len(stale):
            whole = self.worlds.whole(self.scene)
            found |= {int(i): whole.what_collides(q[i]) for i in stale}
        return collision_warnings(self.robot, self.scene, self.samples, self.worlds.at_rest(),
                                  [found[int(i)] for i in rows])

    def prepare(self) -> None:
        """Load the kept worlds, hash the samples and ask what collides in the base's first samples now,
        between updates, so that the first update does not wait for them."""
        from tdgen.generate import PAIR_SAMPLES

        self.base_flags.samples_sha  # noqa: B018 - hashed once here, not in the first update's digest
        for row in np.flatnonzero(self.base_samples.collision)[:PAIR_SAMPLES]:
            self.worlds.base_pairs(int(row), self.base_samples.q[row])
        self.worlds.at_rest()
        part = self.worlds.part([])
        if self.model == "fast":  # the robot's spheres for a world of parts, fitted once per robot
            from tdgen.robot.fast_collision import FastCollision

            FastCollision(part)
        self.worlds.whole(self.scene)

    def close(self) -> None:
        self.worlds.close()
