"""The files a served scene's mesh and points bodies name, served by the Thing beside the scene.

A scene names its CAD meshes and scans by paths on the host that loaded it. The scene a Thing serves
(`files/scene.json`) names each of them instead by the file name the Thing serves it under
(`files/<name>`), which is its href relative to scene.json: a consumer that downloads scene.json and the
files its TD links (`rel` `relations.SCENE_ASSET`) into one folder, or resolves the names against
scene.json's URL, rebuilds the same scene (`tdgen.robot.surroundings.load_scene`).

A file is read from disk for each request and handed to the mesh as it is (never kept in memory between
requests): how large it may be is up to Zenoh's largest message (1 GiB unless configured otherwise) and
the consumer's query timeout. A .gltf is the exception: it may name files beside it (`part.bin`, textures)
that its relative URIs would not find beside scene.json, so it is served as the GLB of it (`.glb`, packed
for each request from the .gltf and its files, `tdgen.robot.gltf_files`): one file, whole, whoever fetches it.
"""
from __future__ import annotations

import re
import threading
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from mesh.messages import relations
from mesh.messages.scene_description import FILE_BODIES
from mesh.wot.problem import NotFound
from mesh.wot.thing_description import Link
from tdgen.robot.errors import SceneError
from tdgen.robot.gltf_files import is_gltf, pack_glb

PREFIX = "scene-"  # served names never meet the Thing's other files (workspace.stl, scene.json, a URDF)
# IANA's registrations where there is one (as Debian's /etc/mime.types lists them); PLY and PCD have none
MEDIA_TYPES = {".stl": "model/stl", ".obj": "model/obj", ".gltf": "model/gltf+json", ".glb": "model/gltf-binary",
               ".dae": "model/vnd.collada+xml", ".e57": "model/e57", ".las": "application/vnd.las",
               ".laz": "application/vnd.laszip", ".csv": "text/csv", ".xyz": "text/plain", ".pts": "text/plain",
               ".txt": "text/plain", ".off": "text/plain"}
UNREGISTERED = "application/octet-stream"


def media_type(path: str | Path) -> str:
    return MEDIA_TYPES.get(Path(path).suffix.lower(), UNREGISTERED)


@dataclass(frozen=True)
class SceneAsset:
    """A file of the scene as served: `files/<name>`, read from `path` (a .gltf: packed as GLB)."""

    name: str
    path: Path
    media_type: str

    def read(self) -> bytes:
        try:
            return pack_glb(self.path) if is_gltf(self.path) else self.path.read_bytes()
        except OSError as e:  # moved or deleted since the scene was loaded: said, not a 5xx
            raise NotFound(f"{self.name}: the scene's file {self.path} cannot be read ({e.strerror})") from None
        except SceneError as e:  # a .gltf or a file it names gone or broken since: said, naming them
            raise NotFound(f"{self.name}: {e}") from None

    def link(self) -> Link:
        return Link(href=f"files/{self.name}", rel=relations.SCENE_ASSET, type=self.media_type)


class SceneAssets:
    """The files of a scene's mesh and points bodies, each with the name it is served under; names are
    kept for the Thing's life (a body that comes back is served under the name it had)."""

    def __init__(self, taken: Iterable[str] = ()):
        self._by_path: dict[str, SceneAsset] = {}
        self._taken = set(taken)
        self._lock = threading.Lock()

    def add(self, bodies: Iterable[Mapping[str, Any]]) -> list[SceneAsset]:
        """Name the files of `bodies` (tdgen scene bodies: `type`, `file`); returns the ones new here."""
        new = []
        with self._lock:
            for body in bodies:
                file = body.get("file")
                if body.get("type") in FILE_BODIES and isinstance(file, str) and file not in self._by_path:
                    served = Path(file).with_suffix(".glb") if is_gltf(file) else Path(file)  # packed, read()
                    asset = SceneAsset(self._name_for(served), Path(file), media_type(served))
                    self._by_path[file] = asset
                    self._taken.add(asset.name)
                    new.append(asset)
        return new

    def _name_for(self, path: Path) -> str:
        stem = re.sub(r"[^A-Za-z0-9_.-]+", "-", path.stem).strip("-.") or "file"
        suffix = re.sub(r"[^A-Za-z0-9]+", "", path.suffix)
        name, n = f"{PREFIX}{stem}", 1
        while (f"{name}.{suffix}" if suffix else name) in self._taken:
            n += 1
            name = f"{PREFIX}{stem}-{n}"
        return f"{name}.{suffix}" if suffix else name

    def names(self) -> dict[str, str]:
        """The scene's `file` (a path here) -> the name it is served under."""
        with self._lock:
            return {path: asset.name for path, asset in self._by_path.items()}

    def assets(self) -> list[SceneAsset]:
        with self._lock:
            return list(self._by_path.values())

    def named(self, name: str) -> SceneAsset | None:
        """The file served as `name`, if any."""
        with self._lock:
            return next((a for a in self._by_path.values() if a.name == name), None)

    def links(self, bodies: Iterable[Mapping[str, Any]]) -> list[Link]:
        """The TD links to the files `bodies` name (in their order, each once)."""
        names, seen, links = self.names(), set(), []
        for body in bodies:
            file = body.get("file")
            if body.get("type") in FILE_BODIES and file in names and file not in seen:
                seen.add(file)
                links.append(self._by_path[file].link())
        return links

    def relative(self, scene: Mapping[str, Any]) -> dict[str, Any]:
        """A copy of the tdgen scene `scene` whose mesh and points bodies name their files as served."""
        names = self.names()
        bodies = [{**body, "file": names[body["file"]]}
                  if body.get("type") in FILE_BODIES and body.get("file") in names else dict(body)
                  for body in scene.get("bodies") or []]
        return {**scene, "bodies": bodies}
