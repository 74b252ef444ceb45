"""A robot twin's artefacts (its TD, points.csv, hull STL and scene) made for the tdgen service: generated
into a cache entry by the one pipeline of `twinmesh tdgen`, or made in memory by a live update.

The cache key (`artefact_key`) covers everything that shapes them, the URDF's meshes included when the
URDF is on this machine.
"""
from __future__ import annotations

import hashlib
import logging
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import msgspec

from mesh.messages.scene_description import TwinDescription
from tdgen.cache import ArtefactCache, cache_key
from tdgen.remote_scene_files import robot_paths

if TYPE_CHECKING:
    from tdgen.generate import GenerationResult
    from tdgen.live import LiveSamples
    from tdgen.robot.calibration import Calibration
    from tdgen.robot.model import Robot
    from tdgen.robot.points_csv import Flags
    from tdgen.robot.surroundings import Surroundings

    Artefact = bytes | bytearray | Flags  # a cache entry's file, in memory

log = logging.getLogger(__name__)
SMALL_RUN = 20_000  # samples up to which one process beats a pool (its start-up costs ~1 s per worker)


def load_robot(twin: TwinDescription) -> tuple[Robot, Calibration | None]:
    """The twin's robot (its URDF checked to be the robot's) and calibration."""
    from tdgen.robot.calibration import fit_calibration
    from tdgen.robot.model import Robot, RobotError, resolve_urdf

    path = resolve_urdf(twin.urdf)
    sha = hashlib.sha256(path.read_bytes()).hexdigest()
    if sha != twin.urdf_sha256:
        raise RobotError(f"{path}: its content differs from the robot's URDF (sha256 {sha[:12]} here, "
                         f"{twin.urdf_sha256[:12]} there): run tdgen where the robot's URDF and meshes are")
    robot = Robot.load(path, ee=twin.ee, base_link=twin.base_link, fixed=twin.fixed,
                       packages={k: Path(v) for k, v in twin.packages.items()},
                       allowed_collisions=twin.allowed_collisions)
    calibration = None
    if twin.calibration:
        import numpy as np

        rows = np.asarray(twin.calibration, dtype=float).reshape(-1, 6)
        calibration = fit_calibration(rows[:, :3], rows[:, 3:])
    return robot, calibration


def make_artefacts(twin: TwinDescription, cache: ArtefactCache, key: str, workers: int | None = None,
                   on_progress: Callable[[float], None] | None = None,
                   keep: Callable[[Robot, Calibration | None, GenerationResult], None] | None = None,
                   paths: Mapping[str, str] | None = None) -> Path:
    """Generate `twin`'s artefacts into the cache entry `key` (the one pipeline of `twinmesh tdgen`; a
    live update's are `live_artefacts`, written by `write_entry`). `keep` is handed a generation's robot
    and result (its samples and points.csv: the next live update's start). `paths`: scene files fetched from
    the robot (`tdgen.remote_scene_files`), copy -> the robot's path, which scene.json names."""
    from tdgen.generate import generate
    from tdgen.robot_td import robot_id

    robot, calibration = load_robot(twin)
    workers = workers or (1 if twin.samples <= SMALL_RUN else None)

    def fill(folder: Path) -> None:
        result = generate(robot, scene_of(twin), twin.samples, twin.seed, folder, calibration=calibration,
                          frame=twin.frame, name=twin.robot, thing_id=robot_id(twin.robot), workers=workers,
                          on_progress=on_progress, collision_model=twin.collision_model)
        (folder / "td.json").write_bytes(msgspec.json.encode(result.td))  # the TD the robot serves on the mesh
        if paths:
            (folder / "scene.json").write_bytes(robot_paths((folder / "scene.json").read_bytes(), paths))
        for warning in result.warnings:
            log.warning("%s: %s", twin.robot, warning)
        (folder / "twin.json").write_bytes(msgspec.json.encode(twin))
        if keep is not None:
            keep(robot, calibration, result)

    return cache.make(key, fill)


def live_artefacts(twin: TwinDescription, live: LiveSamples, robot: Robot,
                   calibration: Calibration | None, paths: Mapping[str, str] | None = None) -> dict[str, Artefact]:
    """A live update's cache entry in memory, file name -> content (its points.csv re-flagged when first
    written): the service serves it at once and writes it to the cache after. `paths` as for `make_artefacts`."""
    from tdgen.generate import Naming, write_artefacts
    from tdgen.robot_td import robot_id

    files: dict[str, Artefact] = {}
    result = write_artefacts(robot, live.scene, live.samples, Path(twin.robot), Naming(twin.robot, robot_id(twin.robot)),
                             twin.seed, calibration, twin.frame, points=live.flags, warnings=live.warnings(),
                             write=lambda path, content: files.__setitem__(path.name, content))
    files["td.json"] = msgspec.json.encode(result.td)  # the TD the robot serves on the mesh
    files["twin.json"] = msgspec.json.encode(twin)
    if paths:
        files["scene.json"] = robot_paths(bytes(files["scene.json"]), paths)  # type: ignore[arg-type]
    for warning in result.warnings:
        log.warning("%s: %s", twin.robot, warning)
    return files


def write_entry(cache: ArtefactCache, key: str, files: dict[str, Artefact]) -> Path:
    """`files` (`live_artefacts`) as the cache entry `key`."""
    from tdgen.generate import write_file

    def fill(folder: Path) -> None:
        for name, content in files.items():
            write_file(folder / name, content)

    return cache.make(key, fill)


def artefact_key(twin: TwinDescription, paths: Mapping[str, str] | None = None) -> str:
    """The cache key of `twin`'s artefacts, its URDF's meshes included when the URDF is here; with `paths`
    (scene files fetched from the robot, `make_artefacts`), the robot's paths too: its scene.json names them."""
    key = cache_key(twin, _urdf_here(twin))
    if not paths:
        return key
    return hashlib.sha256(msgspec.json.encode([key, paths], order="sorted")).hexdigest()[:32]


def _urdf_here(twin: TwinDescription) -> Path | None:
    """The twin's URDF on this machine, if it is here (its meshes are then part of the cache key)."""
    from tdgen.robot.model import RobotError, resolve_urdf

    try:
        return resolve_urdf(twin.urdf)
    except RobotError:
        return None


def user_errors() -> tuple[type[Exception], ...]:
    """Failures a robot's twin can cause (a bad URDF, scene or calibration, no workspace volume)."""
    from tdgen.robot.calibration import CalibrationError
    from tdgen.robot.model import RobotError
    from tdgen.robot.surroundings import SceneError
    from tdgen.robot.workspace import WorkspaceError

    return RobotError, SceneError, CalibrationError, WorkspaceError, msgspec.ValidationError


def scene_of(twin: TwinDescription) -> Surroundings:
    """The tdgen Surroundings of a twin: its bodies, with the robot standing at its base."""
    from tdgen.robot.surroundings import RobotPlacement, Surroundings

    placement = RobotPlacement.from_quaternion(tuple(twin.base.p), tuple(twin.base.q))  # type: ignore[arg-type]
    return msgspec.convert({"name": "scene", **twin.scene, "robot": msgspec.to_builtins(placement)}, Surroundings)
