"""A scene's CAD meshes and scans as the recorder draws them: the cloud as points, the mesh as a mesh.

A scene body of type `mesh` or `points` names a file its Thing serves beside the scene (a robot's
twin.json maps each to its name, `TwinDescription.scene_files`; the world's scene.json names it as
served). The recorder's fetcher reads the file (`read_asset`) and the drawer logs it
(`asset_archetype`) under the body's entity, placed by the body's pose: a scan's points are in its
sensor's frame, the pose being the sensor's.

A cloud is drawn with at most `MAX_POINTS` of its points (an even random choice, the same every time:
a 300,000-point scan would cost the viewer more than it shows); NaN points (an organized cloud's holes)
are left out. Formats: PCD, PLY, XYZ text, and LAS/LAZ and E57 where laspy and pye57 are installed
(`mesh.cloud_files`, as tdgen reads them), STL, OBJ, OFF, glTF/GLB, DAE (trimesh).
"""
from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass, field
from pathlib import PurePosixPath
from typing import Literal

import numpy as np
import rerun as rr

from mesh.cloud_files import CloudFileError, read_cloud_bytes

MAX_POINTS = 100_000
POINT_RADIUS = rr.Radius.ui_points(2.0)  # on screen, whatever the zoom
MESH_FILES = (".stl", ".obj", ".ply", ".glb", ".gltf", ".off", ".dae")


@dataclass(frozen=True)
class Asset:
    """A mesh or points body's file as drawn, in the body's own frame, in metres (its `scale` applied).

    Two assets are equal when they come from the same bytes and scale (their arrays are not compared)."""

    kind: Literal["points", "mesh"]
    digest: str
    points: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32), compare=False)  # (N, 3)
    total: int = 0  # points in the file (finite ones), before the choice drawn
    vertices: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32), compare=False)
    triangles: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.uint32), compare=False)
    normals: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.float32), compare=False)


def read_asset(kind: str, name: str, data: bytes, scale: float = 1.0, max_points: int = MAX_POINTS) -> Asset:
    """The file `name` (its suffix says the format) of a `kind` body ("mesh" or "points"), read for
    drawing; ValueError naming what is wrong."""
    try:
        return _read(kind, name, data, scale, max_points)
    except CloudFileError as e:
        raise ValueError(f"{name}: {e}") from None
    except ValueError:
        raise
    except Exception as e:  # each library fails in its own way on a broken file
        raise ValueError(f"{name}: cannot read it ({type(e).__name__}: {str(e)[:160]})") from None


def _read(kind: str, name: str, data: bytes, scale: float, max_points: int) -> Asset:
    suffix = PurePosixPath(name).suffix.lower()
    h = hashlib.sha256(data)
    h.update(f"|{kind}|{scale!r}".encode())
    digest = h.hexdigest()
    if kind == "points":
        cloud = read_cloud_bytes(suffix, data)
        cloud = cloud[np.isfinite(cloud).all(axis=1)] * scale
        if not len(cloud):
            raise ValueError(f"{name}: no finite point")
        total = len(cloud)
        if total > max_points:
            cloud = cloud[np.sort(np.random.default_rng(0).choice(total, max_points, replace=False))]
        return Asset("points", digest, points=cloud.astype(np.float32), total=total)
    if kind == "mesh":
        import trimesh

        if suffix not in MESH_FILES:
            raise ValueError(f"{name}: {suffix or 'no extension'} is not a mesh format drawn here")
        mesh = trimesh.load(io.BytesIO(data), file_type=suffix[1:], force="mesh", process=False)  # drawn as it is
        if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
            raise ValueError(f"{name}: the mesh has no faces")
        mesh.apply_scale(scale)
        faces = np.asarray(mesh.faces)
        if len(mesh.vertices) == faces.size and (faces.ravel() == np.arange(faces.size)).all():  # STL: none shared
            normals = np.repeat(mesh.face_normals, 3, axis=0)  # what trimesh's vertex normals come to, cheaply
        else:
            normals = mesh.vertex_normals
        return Asset("mesh", digest, vertices=np.asarray(mesh.vertices, np.float32),
                     triangles=faces.astype(np.uint32), normals=np.asarray(normals, np.float32))
    raise ValueError(f"{name}: a {kind!r} body names no file to draw")


def asset_archetype(asset: Asset, rgba: tuple[float, ...]) -> rr.Points3D | rr.Mesh3D:
    """The points or the mesh, in `rgba` (0..1)."""
    colour = [round(min(max(c, 0.0), 1.0) * 255) for c in rgba]
    if asset.kind == "points":
        return rr.Points3D(asset.points, colors=[colour], radii=[POINT_RADIUS])  # type: ignore[arg-type]
    return rr.Mesh3D(vertex_positions=asset.vertices, triangle_indices=asset.triangles, vertex_normals=asset.normals,
                     albedo_factor=colour)
