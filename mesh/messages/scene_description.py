"""What a simulated world tells the mesh about itself, for drawing and replay.

A scene's world runs as a Thing (`world`) with an observable property `poses` (a `Poses` value,
published at a modest rate while things move) and a linked file `files/scene.json` (a
`SceneDescription`: robots with their URDF files, static and moving bodies). The recorder draws
a lab from these alone, so it needs nothing from `devices/`.
"""
from __future__ import annotations

from typing import Any, Literal

import msgspec

from mesh.messages import relations

WORLD_THING = "world"
SCENE_FILE = "scene.json"
FILE_BODIES = ("mesh", "points")  # the scene body types that name a file (a CAD mesh, a scan)
POSES_PROPERTY = "poses"


class Pose(msgspec.Struct, array_like=True):
    """Position (m) and quaternion (x, y, z, w) in the scene frame."""

    p: tuple[float, float, float]
    q: tuple[float, float, float, float] = (0.0, 0.0, 0.0, 1.0)


class RobotModel(msgspec.Struct, omit_defaults=True):
    """A robot of the scene: its URDF (a file of the world Thing) and where its base stands."""

    name: str
    urdf: str                     # file name under the world Thing's files/, e.g. "uarm.urdf"
    base: Pose
    urdf_dir: str | None = None   # the URDF's folder on the world's host: where its meshes are found


class Body(msgspec.Struct, omit_defaults=True):
    """A body of the scene: static (tables, belts, walls) or moving (cubes), drawn as a primitive, or a
    CAD mesh or a scan from a file the world Thing serves beside scene.json."""

    name: str
    shape: Literal["box", "cylinder", "sphere", "mesh", "points"]
    size: tuple[float, ...]       # box: full extents (m); cylinder: (radius, length); sphere: (radius,);
                                  # mesh, points: the full extents of its bounding box in its own frame (m)
    pose: Pose
    color: tuple[float, float, float] = (0.6, 0.6, 0.6)  # sRGB 0..1
    opacity: float = 1.0          # 0..1; below 1 for virtual bodies (a safety wall) drawn see-through
    moving: bool = False
    shows: str | None = None      # a device of `Poses.states` whose {on, color} this body shows (a lamp's shade):
                                  # drawn in that colour while on, in `color` while off
    file: str | None = None       # mesh, points: the file, relative to scene.json (served as files/<file>)
    scale: float = 1.0            # mesh, points: the file's units to metres
    voxel: float | None = None    # points: the resolution its collision boxes were made with (m)


class SceneDescription(msgspec.Struct, omit_defaults=True):
    name: str
    robots: list[RobotModel] = []
    bodies: list[Body] = []


class Poses(msgspec.Struct, omit_defaults=True):
    """The state of what moves at one instant of simulated time."""

    time: float                                            # simulated seconds since the world started
    joints: dict[str, dict[str, float]] = {}               # robot -> joint -> rad or m
    bodies: dict[str, Pose] = {}                           # moving body -> pose
    states: dict[str, dict[str, Any]] = {}                 # device -> small state (belt speed, sensor reading)


# --- robots on the mesh (issue: robots as Things, TDs generated on the mesh) -----------------------
TWIN_FILE = "twin.json"
TWIN_CHANGED = "twinChanged"  # the event a robot Thing emits when its twin changed (the service regenerates)
DEFAULT_SAMPLES = 80_000  # random configurations a robot's workspace is sampled with, unless asked otherwise
CollisionModel = Literal["fast", "exact"]  # what decides collisions: the fast sphere model, or pybullet's exact test
TWIN_REL = relations.TWIN    # TD link to files/twin.json: what the tdgen service generates from
MODEL_REL = relations.MODEL  # TD link to the robot's URDF file (drawn by the recorder)


class TwinDescription(msgspec.Struct, omit_defaults=True, kw_only=True):
    """What a robot Thing tells the mesh about its twin, so that the tdgen service can generate
    its TD, points CSV, hull STL and scene file, and the recorder can draw it.

    `urdf` is resolvable on the lab's machines (a path, a name under tdgen/robots, or a pybullet_data
    path); `urdf_sha256` pins its content for the generation cache. `scene` is a tdgen scene
    (tdgen/robot/surroundings.py format: static bodies in the scene frame, metres) without the robot itself.
    """

    robot: str                                  # the robot Thing's name
    urdf: str
    urdf_sha256: str
    urdf_file: str = "robot.urdf"               # the same URDF served as files/<urdf_file>
    urdf_dir: str | None = None                 # the URDF's folder on the robot's host: where its meshes are found
    base: Pose                                  # the robot base in the scene frame (yaw in q)
    ee: str | None = None
    base_link: str | None = None                # where the arm chain starts (None: the URDF's root)
    fixed: dict[str, float] = {}                # joints held at a value, deg or mm
    packages: dict[str, str] = {}               # ROS package name -> directory, for package:// meshes
    allowed_collisions: list[tuple[str, str]] = []  # link pairs whose contact is no collision
    scene: dict[str, Any] = {}
    scene_files: dict[str, str] = {}            # a scene body's `file` (a path on the robot's host) -> the name the
                                                # robot serves it under (files/<name>, rel scene-asset)
    samples: int = DEFAULT_SAMPLES
    seed: int = 0
    calibration: list[list[float]] | None = None  # rows twin_x,twin_y,twin_z,real_x,real_y,real_z (mm)
    frame: Literal["twin", "real"] = "twin"
    collision_model: CollisionModel = "fast"  # what decides a sampled configuration's collision
    version: int = 0                            # bumped whenever the scene around the robot changes
