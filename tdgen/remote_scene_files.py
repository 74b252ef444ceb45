"""A robot's scans and CAD meshes fetched from the robot itself when they are not on the tdgen service's host.

A robot's twin names its scene's files by paths on the robot's host and serves each as `files/<name>`
(`TwinDescription.scene_files`). A file the service cannot read by that path is fetched from the robot into
a folder of the cache, named by its content digest; generation then reads the twin with those copies in
place of the robot's paths, so the cache key follows the content (a room scanned again into the same file
is a new key) and a live update sees an unchanged file as the same body. The scene.json made from it names
the robot's paths again (`robot_paths`): the robot maps those to the names it serves. A .gltf comes as the
GLB the robot packs of it (`devices.things.scene_files`), its copy named `.glb` as served.

The folder is bounded: a depth camera's cloud replaced every few seconds would fill the disk. Each use of a
copy marks it (its time); when a new copy is written, the copies the twin at hand uses stay, and of the rest
the last used are kept while they number fewer than `KEPT_COPIES` and fit in `KEPT_BYTES`; older ones go. A
copy that went and is needed again (another robot's, its scene changed back) is fetched again: the folder is
a cache, generation never reads a copy of another twin than the one it fetched for (one generation at a time).
"""
from __future__ import annotations

import hashlib
import os
import tempfile
import time
from collections.abc import Callable, Mapping
from pathlib import Path

import msgspec

from mesh.messages.scene_description import FILE_BODIES, TwinDescription
from mesh.wot.problem import Problem
from tdgen.robot.errors import SceneError
from tdgen.robot.gltf_files import check_whole, is_gltf

KEPT_COPIES = 32  # beside the twin's own: several robots' scans, a few of each, none fetched again at each change
KEPT_BYTES = 1 << 30
PARTS = ".fetching-"  # a copy being written: renamed when whole, removed when writing fails
STALE_PART_S = 3600.0  # a part this old was left by a service that died writing it: deleted with the copies


def fetched_twin(twin: TwinDescription, folder: Path,
                 fetch: Callable[[str], bytes]) -> tuple[TwinDescription, dict[str, str]]:
    """`twin` with each scene file that is not here replaced by its copy fetched from the robot
    (`fetch(name)`: the robot's `files/<name>`), and the copies' paths -> the robot's paths. A file the robot
    cannot serve is a SceneError naming it and why."""
    bodies = twin.scene.get("bodies") or []
    copies: dict[str, str] = {}  # the robot's path -> the copy here
    written = False
    for body in bodies:
        file = body.get("file") if isinstance(body, dict) and body.get("type") in FILE_BODIES else None
        if not isinstance(file, str) or file in copies or _here(Path(file).expanduser()):
            continue
        copy, new = _copy(twin, file, folder, fetch)
        copies[file], written = str(copy), written or new
    if written:
        prune(folder, keep={Path(copy) for copy in copies.values()})
    if not copies:
        return twin, {}
    scene = {**twin.scene, "bodies": [{**body, "file": copies[body["file"]]}
                                      if isinstance(body, dict) and body.get("file") in copies else body
                                      for body in bodies]}
    return msgspec.structs.replace(twin, scene=scene), {copy: path for path, copy in copies.items()}


def _here(path: Path) -> bool:
    """The file is on this host, whole (a .gltf with the files it names)."""
    if not path.is_file():
        return False
    if is_gltf(path):
        try:
            check_whole(path)
        except SceneError:
            return False
    return True


def _copy(twin: TwinDescription, file: str, folder: Path, fetch: Callable[[str], bytes]) -> tuple[Path, bool]:
    """The copy of the robot's `file` here, and whether it was written now (else found and marked used)."""
    name = twin.scene_files.get(file)
    if name is None:
        raise SceneError(f"{file}: not on the tdgen service's host, and {twin.robot} serves no file for it")
    try:
        content = bytes(fetch(name))
    except Problem as e:
        raise SceneError(f"{file}: not on the tdgen service's host, and {twin.robot} cannot serve it as "
                         f"files/{name} ({e})") from None
    if not content:
        raise SceneError(f"{file}: the file is empty (as {twin.robot} serves it, files/{name})")
    suffix = Path(name).suffix or Path(file).suffix  # the format as served (a .gltf comes as .glb)
    copy = folder / f"{hashlib.sha256(content).hexdigest()}{suffix.lower()}"
    if copy.is_file():
        os.utime(copy)  # used now: the last to go
        return copy, False
    folder.mkdir(parents=True, exist_ok=True)  # whole or not at all: written aside and renamed
    fd, part = tempfile.mkstemp(dir=folder, prefix=PARTS)
    try:
        with os.fdopen(fd, "wb") as f:
            f.write(content)
        os.replace(part, copy)
    except OSError as e:  # a full disk: said as this robot's failure, no part left behind
        Path(part).unlink(missing_ok=True)
        raise SceneError(f"{file}: its copy from {twin.robot} cannot be written in {folder} ({e.strerror})") from None
    return copy, True


def prune(folder: Path, keep: set[Path], copies: int = KEPT_COPIES, size: int = KEPT_BYTES) -> list[Path]:
    """Delete the copies in `folder` beyond the last used `copies` that fit in `size` bytes, never one of `keep`
    (the twin at hand's), and parts left by a service that died writing them; returns the deleted copies."""
    found = []
    for path in folder.iterdir():
        try:
            stat = path.stat()
        except FileNotFoundError:  # deleted meanwhile
            continue
        if path.name.startswith(PARTS):
            if time.time() - stat.st_mtime > STALE_PART_S:
                path.unlink(missing_ok=True)
        elif path not in keep and path.is_file():
            found.append((stat.st_mtime_ns, stat.st_size, path))
    found.sort(reverse=True)  # the last used first
    kept, held = 0, sum(p.stat().st_size for p in keep if p.is_file())
    for _, bytes_, _ in found:
        if kept == copies or held + bytes_ > size:
            break
        kept, held = kept + 1, held + bytes_
    for _, _, path in found[kept:]:
        path.unlink(missing_ok=True)
    return [path for _, _, path in found[kept:]]


def robot_paths(scene_json: bytes, paths: Mapping[str, str]) -> bytes:
    """A generated scene.json naming the robot's paths where generation read the copies (`paths`: copy -> path)."""
    from tdgen.robot.surroundings import Surroundings, encode_scene

    if not paths:
        return scene_json
    scene = msgspec.json.decode(scene_json)
    scene["bodies"] = [{**body, "file": paths[body["file"]]} if body.get("file") in paths else body
                       for body in scene.get("bodies") or []]
    return encode_scene(msgspec.convert(scene, Surroundings))
