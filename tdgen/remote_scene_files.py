"""A robot's scans and CAD meshes fetched from the robot itself when they are not on the tdgen service's host.

A robot's twin names its scene's files by paths on the robot's host and serves each as `files/<name>`
(`TwinDescription.scene_files`). A file the service cannot read by that path is fetched from the robot into
a folder of the cache, named by its content digest; generation then reads the twin with those copies in
place of the robot's paths, so the cache key follows the content (a room scanned again into the same file
is a new key) and a live update sees an unchanged file as the same body. The scene.json made from it names
the robot's paths again (`robot_paths`): the robot maps those to the names it serves.
"""
from __future__ import annotations

import hashlib
import os
import tempfile
from collections.abc import Callable, Mapping
from pathlib import Path

import msgspec

from mesh.messages.scene_description import FILE_BODIES, TwinDescription
from mesh.wot.problem import Problem
from tdgen.robot.errors import SceneError


def fetched_twin(twin: TwinDescription, folder: Path,
                 fetch: Callable[[str], bytes]) -> tuple[TwinDescription, dict[str, str]]:
    """`twin` with each scene file that is not here replaced by its copy fetched from the robot
    (`fetch(name)`: the robot's `files/<name>`), and the copies' paths -> the robot's paths. A file the robot
    cannot serve is a SceneError naming it and why."""
    bodies = twin.scene.get("bodies") or []
    copies: dict[str, str] = {}  # the robot's path -> the copy here
    for body in bodies:
        file = body.get("file") if isinstance(body, dict) and body.get("type") in FILE_BODIES else None
        if not isinstance(file, str) or file in copies or Path(file).expanduser().is_file():
            continue
        copies[file] = str(_copy(twin, file, folder, fetch))
    if not copies:
        return twin, {}
    scene = {**twin.scene, "bodies": [{**body, "file": copies[body["file"]]}
                                      if isinstance(body, dict) and body.get("file") in copies else body
                                      for body in bodies]}
    return msgspec.structs.replace(twin, scene=scene), {copy: path for path, copy in copies.items()}


def _copy(twin: TwinDescription, file: str, folder: Path, fetch: Callable[[str], bytes]) -> Path:
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
    copy = folder / f"{hashlib.sha256(content).hexdigest()}{Path(file).suffix.lower()}"
    if not copy.is_file():  # whole or not at all: written aside and renamed
        folder.mkdir(parents=True, exist_ok=True)
        fd, part = tempfile.mkstemp(dir=folder, prefix=".fetching-")
        with os.fdopen(fd, "wb") as f:
            f.write(content)
        os.replace(part, copy)
    return copy


def robot_paths(scene_json: bytes, paths: Mapping[str, str]) -> bytes:
    """A generated scene.json naming the robot's paths where generation read the copies (`paths`: copy -> path)."""
    from tdgen.robot.surroundings import Surroundings, encode_scene

    if not paths:
        return scene_json
    scene = msgspec.json.decode(scene_json)
    scene["bodies"] = [{**body, "file": paths[body["file"]]} if body.get("file") in paths else body
                       for body in scene.get("bodies") or []]
    return encode_scene(msgspec.convert(scene, Surroundings))
