"""Following robots' scenes live: each robot's samples kept (for up to LIVE_ROBOTS robots) so that a scene
change re-checks only the samples it can touch (`tdgen.live`) instead of generating again.

Used by the tdgen service's one generator thread: nothing here is locked.
"""
from __future__ import annotations

import logging
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec

from mesh.messages.scene_description import TwinDescription
from tdgen.artefacts import load_robot, scene_of

if TYPE_CHECKING:
    from tdgen.generate import GenerationResult
    from tdgen.live import LiveSamples
    from tdgen.robot.calibration import Calibration
    from tdgen.robot.model import Robot

log = logging.getLogger(__name__)
LIVE_ROBOTS = 8          # robots whose samples stay in memory to follow their scenes (~100 B per sample)
LIVE_SAMPLES = 2_000_000  # a robot sampled more than this is generated again when its scene changes


@dataclass
class Following:
    """A robot's samples kept to follow its scene (`tdgen.live`), with the twin they were made for."""

    twin: TwinDescription
    robot: Robot
    calibration: Calibration | None
    samples: LiveSamples

    def follows(self, twin: TwinDescription) -> bool:
        """Is `twin` this one with other surroundings only (what a live update can follow)?"""
        def unscened(t: TwinDescription) -> TwinDescription:  # the files a scene names go with it
            return msgspec.structs.replace(t, scene={}, scene_files={}, version=0)

        return unscened(self.twin) == unscened(twin)


class SceneFollower:
    """The samples of the robots whose scenes are followed live, least recently changed first."""

    def __init__(self, cache_dir: Path, enabled: bool = True):
        self.cache_dir, self.enabled = cache_dir, enabled
        self._following: OrderedDict[str, Following] = OrderedDict()

    def close(self) -> None:
        """Their pybullet worlds go."""
        for following in self._following.values():
            following.samples.close()
        self._following.clear()

    def held(self, twin: TwinDescription, robot: Robot, calibration: Calibration | None,
              result: GenerationResult) -> Following | None:
        """A generation's samples and points.csv as a live update starts from them, instead of reading the
        file back and drawing the configurations again (some 50 ms, which the first scene change waited for)."""
        from tdgen.live import LiveSamples

        if not self.enabled or twin.samples > LIVE_SAMPLES or result.sampled is None or result.points is None:
            return None
        try:
            samples = LiveSamples(robot, scene_of(twin), result.sampled, result.points, twin.collision_model)
        except ValueError:  # not a points file one can re-flag: read back from the cache entry, as after a hit
            return None
        return Following(twin, robot, calibration, samples)

    def live_update(self, twin: TwinDescription) -> Following | None:
        """The robot's samples in `twin`'s scene by a live update, if its previous twin differs in the scene only."""
        from tdgen.live import NeedsGeneration

        held = self._following.get(twin.robot)
        if not self.enabled or held is None or not held.follows(twin):
            return None
        try:
            samples, checked = held.samples.rescene(scene_of(twin))
        except NeedsGeneration as e:
            log.info("%s: generated again: %s", twin.robot, e)
            return None
        log.info("%s: scene followed live (%d configurations checked)", twin.robot, checked)
        return Following(twin, held.robot, held.calibration, samples)

    def follow(self, twin: TwinDescription, key: str, following: Following | None) -> Following | None:
        """Keep the robot's samples for its next scene change: after a cache hit, those held moved to the
        new scene (a box taken away: nothing to check), else read back from the cache entry; the least
        recently changed robots beyond LIVE_ROBOTS are let go. Returns the samples kept when they were at
        hand in memory (their points.csv's digest is then known without reading the file), else None."""
        from tdgen.live import LiveSamples

        if not self.enabled or twin.samples > LIVE_SAMPLES:
            return None
        if following is None:
            held = self._following.get(twin.robot)
            if held is not None and held.twin == twin:
                return None
            following = self.live_update(twin)
        if following is None:
            try:
                robot, calibration = load_robot(twin)
                samples = LiveSamples.from_file(robot, scene_of(twin), twin.samples, twin.seed,
                                                self.cache_dir / key / "points.csv", twin.collision_model)
            except Exception:  # noqa: BLE001 - without it, the next change is generated from scratch
                log.exception("%s: cannot keep its samples for live updates", twin.robot)
                return None
            following, in_memory = Following(twin, robot, calibration, samples), False
        else:
            in_memory = True
        before = self._following.get(twin.robot)
        if before is None or before.samples.worlds is not following.samples.worlds:
            if before is not None:
                before.samples.close()
            following.samples.prepare()  # new worlds: loaded now, not in the next change's update
        self._following[twin.robot] = following
        self._following.move_to_end(twin.robot)
        while len(self._following) > LIVE_ROBOTS:
            self._following.popitem(last=False)[1].samples.close()
        return following if in_memory else None
