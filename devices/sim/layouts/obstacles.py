"""Obstacles a user adds to a running scene (a box put on the UR10's table, a CAD mesh, a depth camera's
latest scan), as the world Thing takes them.

One value, three uses: the world Thing's action input (`OBSTACLE_SCHEMA`, validated before the
handler runs), a static body in the pybullet world (`build`), and a body of the robots' tdgen
scene (`scene_body`), so that the collision checks and the regenerated workspace see exactly the
body the recorder draws. A `mesh` or `points` obstacle names a file on the lab's host (as a scene
file's `mesh` and `points` bodies do, `tdgen.robot.surroundings`); the world serves it beside its
scene.json to anyone who may read the world. So the file is taken only from the lab's scans folder
(`twinmesh up --scans DIR`): whoever may invoke `addObstacle` must not be able to make the lab read and
serve any other file of its host.
"""
from __future__ import annotations

import math
import os
from pathlib import Path
from typing import Any, Literal

import msgspec
import platformdirs
import pybullet as pb

from devices.sim.pybullet_world import static_box
from mesh.messages.scene_description import Body, Pose
from mesh.wot import units
from mesh.wot.problem import Refused
from tdgen.robot.surroundings import BoxBody, MeshBody, PointsBody, SceneError, Surroundings, build_into, prepare

PREFIX = "obstacle-"  # the body name of obstacle `name` in the scene: obstacle-<name>
COLOR = (0.95, 0.45, 0.1)
SCANS_ENV = "TWINMESH_SCANS"  # the default of `twinmesh up --scans`

_VEC3 = {"type": "array", "minItems": 3, "maxItems": 3}
OBSTACLE_SCHEMA: dict[str, Any] = {
    "type": "object", "required": ["name", "position"],
    "properties": {
        "name": {"type": "string", "pattern": "^[a-z0-9-]{1,40}$", "description": "Slug naming the obstacle."},
        "type": {"type": "string", "enum": ["box", "mesh", "points"], "description": "A box (default, `size` "
                 "needed), a CAD mesh or a scan (`file` needed; `position` and `rpy` the mesh's or the sensor's pose)."},
        "size": {**_VEC3, "items": {"type": "number", "minimum": 0.01, "maximum": 3, "unit": units.METRE},
                 "description": "A box's full extents x, y, z (m)."},
        "file": {"type": "string", "minLength": 1, "maxLength": 1024, "description": "A mesh or points obstacle's "
                 "file (STL, OBJ, PLY, glTF; PCD, PLY, XYZ) in the lab's scans folder (twinmesh up --scans DIR; "
                 "default: the scans folder of the lab host's twinmesh data directory), relative to that folder or "
                 "absolute inside it; any other file is refused (422, file-outside-scans). Adding a scan again "
                 "under its name replaces the previous one."},
        "rpy": {**_VEC3, "items": {"type": "number", "minimum": -360, "maximum": 360, "unit": units.DEGREE},
                "description": "A mesh or points obstacle's roll, pitch, yaw (fixed axes)."},
        "scale": {"type": "number", "exclusiveMinimum": 0, "maximum": 1000, "unit": units.UNITLESS,
                  "description": "A mesh or points file's units in metres (0.001 for millimetres)."},
        "voxel": {"type": "number", "minimum": 0.001, "maximum": 0.5, "unit": units.METRE,
                  "description": "A scan's resolution (m, default 0.02)."},
        "position": {**_VEC3, "items": {"type": "number", "minimum": -10, "maximum": 10, "unit": units.METRE},
                     "description": "Centre in the scene frame (m; z = 0 the floor)."},
        "yaw": {"type": "number", "minimum": -180, "maximum": 180, "unit": units.DEGREE, "description": "About z."},
        "color": {**_VEC3, "items": {"type": "number", "minimum": 0, "maximum": 1, "unit": units.UNITLESS},
                  "description": "sRGB 0..1 (default orange)."},
    },
}


class Obstacle(msgspec.Struct, kw_only=True, omit_defaults=True):
    name: str
    position: tuple[float, float, float]
    type: Literal["box", "mesh", "points"] = "box"
    size: tuple[float, float, float] | None = None  # a box's
    yaw: float = 0.0
    color: tuple[float, float, float] = COLOR
    file: str | None = None  # a mesh's or a scan's, absolute once taken in
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    scale: float = 1.0
    voxel: float | None = None

    @property
    def body_name(self) -> str:
        return PREFIX + self.name


def default_scans_dir() -> Path:
    """`$TWINMESH_SCANS`, else `scans` in the user's data directory (`$XDG_DATA_HOME/twinmesh/scans` on Linux,
    beside the secrets): a folder that holds only what someone put there to share, never the folder a lab
    happened to be started in (often a home directory)."""
    folder = os.environ.get(SCANS_ENV)
    return Path(folder) if folder else platformdirs.user_data_path("twinmesh") / "scans"


def in_scans(file: str, scans: Path) -> Path:
    """The real path of `file` (relative to `scans`, or absolute), refused unless it lies in `scans` once `..`
    and every symbolic link are followed."""
    folder = scans.resolve()
    path = (folder / file).resolve()  # an absolute `file` stays itself
    if not path.is_relative_to(folder):
        shown = f"{file!r}" if str(path) == file else f"{file!r} ({path})"
        raise Refused(f"file: {shown} is outside the lab's scans folder {folder}; only files in it are taken "
                      "(twinmesh up --scans DIR chooses the folder)", reason="file-outside-scans")
    return path


def from_input(value: object, scans: Path) -> Obstacle:
    """The obstacle of an `addObstacle` input (already checked against OBSTACLE_SCHEMA); a mesh or scan file
    is taken only from the folder `scans` and read now (cached), so that a bad one is refused here, before
    anything changes."""
    obstacle = msgspec.convert(value, Obstacle)
    if obstacle.type == "box":  # valid by the schema, which needs neither a size nor a file: a refusal (422)
        if obstacle.size is None:
            raise Refused("size: a box obstacle needs its full extents [x, y, z] (m)", reason="size-needed")
        return obstacle
    if obstacle.file is None:
        raise Refused(f"file: a {obstacle.type} obstacle needs its file", reason="file-needed")
    try:
        obstacle = msgspec.structs.replace(obstacle, file=str(in_scans(obstacle.file, scans)))
        prepare(scene_body(obstacle))  # type: ignore[arg-type]
    except SceneError as e:
        raise Refused(str(e), reason="unusable-file") from None
    except (OSError, ValueError, RuntimeError) as e:  # a path no file system takes (a NUL in it, ~nobody)
        raise Refused(f"{obstacle.file!r}: not a usable path ({e})", reason="unusable-file") from None
    return obstacle


def scene_body(obstacle: Obstacle) -> BoxBody | MeshBody | PointsBody:
    """The obstacle as a body of a tdgen scene (what robot checks and workspaces are computed with)."""
    rgba = (*obstacle.color, 1.0)
    if obstacle.type == "mesh":
        return MeshBody(name=obstacle.body_name, file=obstacle.file or "", scale=obstacle.scale,
                        position=obstacle.position, rpy=obstacle.rpy, rgba=rgba)
    if obstacle.type == "points":
        extra = {"voxel": obstacle.voxel} if obstacle.voxel is not None else {}
        return PointsBody(name=obstacle.body_name, file=obstacle.file or "", scale=obstacle.scale,
                          position=obstacle.position, rpy=obstacle.rpy, rgba=rgba, **extra)
    assert obstacle.size is not None, "from_input checked it"
    return BoxBody(name=obstacle.body_name, size=obstacle.size, position=obstacle.position,
                   rpy=(0.0, 0.0, obstacle.yaw), rgba=rgba)


def build(client: int, obstacle: Obstacle) -> int:
    """The obstacle as a static body in pybullet client `client` (stepping thread); returns its body id."""
    if obstacle.type != "box":
        body = scene_body(obstacle)
        return build_into(Surroundings(name=body.name, bodies=[body]), client)[0]
    assert obstacle.size is not None, "from_input checked it"
    orn = pb.getQuaternionFromEuler([0.0, 0.0, math.radians(obstacle.yaw)])
    return static_box(client, [s / 2 for s in obstacle.size], obstacle.position, orn, rgba=(*obstacle.color, 1.0))


def described(obstacle: Obstacle) -> Body:
    """A mesh or points obstacle as the world's scene.json describes it: its file (a path here, which the world
    Thing names as it serves it), its pose (a scan's: its sensor's) and the extents of what it was made into."""
    from scipy.spatial.transform import Rotation

    made = prepare(scene_body(obstacle))  # type: ignore[arg-type]  # from the cache: from_input made it
    q = Rotation.from_euler("xyz", obstacle.rpy, degrees=True).as_quat()
    return Body(name=obstacle.body_name, shape=obstacle.type, size=tuple(float(v) for v in made.high - made.low),
                pose=Pose(obstacle.position, tuple(float(v) for v in q)), color=obstacle.color,  # type: ignore[arg-type]
                file=obstacle.file, scale=obstacle.scale, voxel=obstacle.voxel)
