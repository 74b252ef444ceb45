"""Reading a scene's scans and CAD meshes: every file format a `points` or `mesh` body may name.

Clouds come back as (N, 3) float arrays in the file's own frame (the sensor's), NaN points (an
organized cloud's holes) dropped; meshes as trimesh meshes. Each problem is one `SceneError` naming
the file and what is wrong with it, so a lab refuses a bad scene before it starts anything.

PCD goes through pypcd4 (ascii, binary and LZF binary_compressed, any extra fields such as `label`
or `rgba`): small, pure Python with a C LZF codec, where open3d would bring a few hundred MB for one
reader. PLY, STL, OBJ and glTF go through trimesh; LAS/LAZ through laspy and E57 through pye57 when
installed (neither is needed for the other formats). Clouds are read by `mesh.cloud_files`, as the
recorder reads them. A .gltf is the file and the files it names (`gltf_files`): all must be there, and its
content is all of theirs.
"""
from __future__ import annotations

import hashlib
import time
from pathlib import Path

import numpy as np

from mesh.cloud_files import SUFFIXES as CLOUD_FILES
from mesh.cloud_files import CloudFileError, read_cloud_file
from tdgen.robot import gltf_files
from tdgen.robot.errors import SceneError

CLOUD_SUFFIXES = CLOUD_FILES
MESH_SUFFIXES = (".stl", ".obj", ".ply", ".glb", ".gltf", ".off", ".dae")
LARGEST_EXTENT = 100.0  # m: a scan wider than this is taken for millimetres given as metres


def read_cloud(path: Path, scale: float = 1.0) -> np.ndarray:
    """The finite points of the cloud in `path` (m, the file's frame, times `scale`)."""
    suffix = path.suffix.lower()
    if suffix not in CLOUD_SUFFIXES:
        raise SceneError(f"{path}: unknown point cloud format {suffix or '(no extension)'!r} "
                         f"(known: {', '.join(CLOUD_SUFFIXES)})")
    _readable(path)
    try:
        raw = _cloud_file(path)
    except SceneError:
        raise
    except Exception as exc:  # each library fails in its own way on a broken file
        raise SceneError(f"{path}: cannot read the point cloud ({_first_line(exc)})") from None
    points = np.asarray(raw, dtype=float).reshape(-1, 3)
    if not len(points):
        raise SceneError(f"{path}: the point cloud holds no points")
    finite = np.isfinite(points).all(axis=1)
    if not finite.all():  # a copy only where there are holes, and a product only for a scale: 300,000 rows each
        points = points[finite]
    if scale != 1.0:
        points = points * scale
    if not len(points):
        raise SceneError(f"{path}: every point of the cloud is NaN or infinite (an organized cloud with no return)")
    extent = max(float(np.ptp(points[:, k])) for k in range(3))  # by column: numpy reduces (N, 3) rows 25x slower
    if extent > LARGEST_EXTENT:
        raise SceneError(f"{path}: the cloud is {extent:,.0f} m across: millimetres given as metres? "
                         "(give the body \"scale\": 0.001)")
    return points


def read_mesh(path: Path, scale: float = 1.0):
    """The mesh in `path` (trimesh.Trimesh, every part of a glTF scene in one, times `scale`)."""
    import trimesh

    suffix = path.suffix.lower()
    if suffix not in MESH_SUFFIXES:
        raise SceneError(f"{path}: unknown mesh format {suffix or '(no extension)'!r} (known: {', '.join(MESH_SUFFIXES)})")
    _readable(path)
    if gltf_files.is_gltf(path):  # said here, naming both files, not as the loader's FileNotFoundError
        gltf_files.check_whole(path)
    elif suffix == ".glb":
        gltf_files.check_glb_alone(path)
    try:
        mesh = trimesh.load(str(path), force="mesh", process=True)
    except Exception as exc:
        raise SceneError(f"{path}: cannot read the mesh ({_first_line(exc)})") from None
    if not isinstance(mesh, trimesh.Trimesh) or not len(mesh.faces):
        raise SceneError(f"{path}: the mesh has no faces (a point cloud? use a \"points\" body)")
    if not np.isfinite(mesh.vertices).all():
        raise SceneError(f"{path}: the mesh has NaN or infinite vertices")
    mesh.apply_scale(scale)
    extent = float(np.max(mesh.extents))
    if extent > LARGEST_EXTENT:
        raise SceneError(f"{path}: the mesh is {extent:,.0f} m across: millimetres given as metres? "
                         "(give the body \"scale\": 0.001)")
    return mesh


SETTLED = 2.0  # s: a file unchanged this long is known by its size, times and inode until they change
_DIGESTS: dict[str, tuple[tuple[int, int, int, int], str]] = {}
_NAMED: dict[str, tuple[str, list[tuple[str, Path]]]] = {}  # a .gltf's path -> its digest, the files it names


def content_digest(path: Path) -> str:
    """The sha256 of the file's content (hex): what a scan or mesh is known by in the caches, never its path or
    time. A .gltf's covers the files it names (a part.bin written again is a new mesh). Hashed again whenever
    its size, times or inode differ from the last hash; a file changed within `SETTLED` of its hash is hashed
    every time (a write within the clock's tick leaves its times as they were)."""
    digest = _file_digest(path)
    if not gltf_files.is_gltf(path):
        return digest
    held = _NAMED.get(str(path))
    if held is not None and held[0] == digest:
        named = held[1]
    else:
        try:
            named = gltf_files.named_files(path)
        except SceneError:  # said when the mesh is read; known by its own bytes until then
            named = []
        _NAMED[str(path)] = (digest, named)  # parsed once per content: a .gltf of data: URIs may be large
    if not named:
        return digest
    h = hashlib.sha256(digest.encode())
    for uri, file in named:
        h.update(b"\0" + uri.encode() + b"\0" + (_file_digest(file).encode() if file.is_file() else b"<missing>"))
    return h.hexdigest()


def _file_digest(path: Path) -> str:
    stat = path.stat()
    mark = (stat.st_size, stat.st_mtime_ns, stat.st_ctime_ns, stat.st_ino)
    held = _DIGESTS.get(str(path))
    if held is not None and held[0] == mark:
        return held[1]
    with path.open("rb") as f:
        digest = hashlib.file_digest(f, "sha256").hexdigest()
    if time.time_ns() - max(stat.st_mtime_ns, stat.st_ctime_ns) > SETTLED * 1e9:
        _DIGESTS[str(path)] = (mark, digest)
    return digest


def _first_line(exc: Exception) -> str:
    """A library's error in one line: pydantic and others write a page."""
    text = (str(exc).strip().splitlines() or [""])[0][:160]
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _readable(path: Path) -> None:
    if not path.is_file():
        raise SceneError(f"{path}: file not found")
    if path.stat().st_size == 0:
        raise SceneError(f"{path}: the file is empty")


def _cloud_file(path: Path) -> np.ndarray:
    """Any cloud format, read as the recorder reads it (`mesh.cloud_files`)."""
    try:
        return read_cloud_file(path)
    except CloudFileError as e:
        raise SceneError(f"{path}: {e}") from None
