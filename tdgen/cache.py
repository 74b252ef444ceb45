"""Generated robot artefacts on disk, keyed by everything they were made from.

A cache entry `cache_dir/<key>/` (td.json, points.csv, workspace.stl, scene.json, twin.json) is used
only when its key matches: the twin's inputs (URDF content, base, scene, samples, seed, end effector,
calibration, frame, name...), the content of every mesh file the URDF names and of every file the
scene's bodies name (a scan, a CAD mesh, a URDF: the same path with new content is a new key, a file
only touched is not), and the code that
makes workspaces and TDs (every module of `tdgen`, the parts of `mesh` it builds TDs with) with the
versions of the libraries it computes with. Nothing is bumped by hand: an edit to the TD-building
code, or a new pybullet, is a new key, so a stale TD is never served.
"""
from __future__ import annotations

import functools
import hashlib
import os
import shutil
import threading
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import Callable

import msgspec

import mesh.http.tdrewrite
import mesh.messages
import mesh.urdf_resources
import mesh.wot
from mesh.messages.scene_description import TwinDescription
from mesh.urdf_resources import MESH_FILENAME, resolve_uri
from tdgen.robot.cores import user_cache
from tdgen.robot.scan_io import content_digest
from tdgen.robot.surroundings import PYBULLET_DATA

DONE = "done"  # written last: an entry without it is not one
# what a workspace's numbers come from, besides our code
LIBRARIES = ("pybullet", "numpy", "scipy", "trimesh", "msgspec")


def artefacts_dir() -> Path:
    """`$TWINMESH_CACHE/tdgen`, else tdgen's folder in the user's cache directory (`$XDG_CACHE_HOME/twinmesh/tdgen`
    on Linux, by default `~/.cache/twinmesh/tdgen`), beside the compiled code (`cores.user_cache`)."""
    return user_cache() / "tdgen"


def _code_roots() -> list[Path]:
    here = Path(__file__).parent
    return [here, Path(mesh.wot.__file__).parent, Path(mesh.messages.__file__).parent,
            Path(mesh.http.tdrewrite.__file__), Path(mesh.urdf_resources.__file__)]


@functools.cache
def code_fingerprint() -> str:
    """A hash of the source of the code that makes workspaces and TDs, and of the library versions."""
    h = hashlib.sha256()
    for root in _code_roots():
        files = [root] if root.is_file() else sorted(p for p in root.rglob("*.py") if "__pycache__" not in p.parts)
        for f in files:
            h.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
    for lib in LIBRARIES:
        try:
            h.update(f"{lib}=={version(lib)}\0".encode())
        except PackageNotFoundError:
            h.update(f"{lib} absent\0".encode())
    return h.hexdigest()[:16]


def meshes_fingerprint(urdf: Path, packages: dict[str, str]) -> str:
    """A hash of the content of every mesh file the URDF names (missing ones by name): a mesh edited
    beside an unchanged URDF changes the collisions, so it changes the key."""
    h = hashlib.sha256()
    text = urdf.read_text(errors="replace")
    dirs = {k: Path(v) for k, v in packages.items()}
    found = {m.group(3): resolve_uri(m.group(3), urdf.parent, dirs)[0] for m in MESH_FILENAME.finditer(text)}
    for uri, path in sorted(found.items()):
        h.update(uri.encode() + b"\0")
        h.update(path.read_bytes() if path is not None else b"<missing>")
    return h.hexdigest()[:16]


def scene_files_fingerprint(scene: dict) -> str | None:
    """A hash of the content of every file the scene's bodies name (a `points` or `mesh` body's `file`, a
    `urdf` body's URDF; missing ones by name), None for a scene that names none: a room scanned again into
    the same file changes every flag, and its path says nothing of that. Paths relative to the working
    directory, as the scene is built (`tdgen.artefacts.scene_of`)."""
    named = [name for body in scene.get("bodies", []) if isinstance(body, dict)
             for name in (_named_file(body),) if name is not None]
    if not named:
        return None
    h = hashlib.sha256()
    for name in named:
        h.update(name.encode() + b"\0")
        path = Path(name).expanduser()
        h.update(content_digest(path).encode() if path.is_file() else b"<missing>")
    return h.hexdigest()[:16]


def _named_file(body: dict) -> str | None:
    """The file a scene body is made from, if it is one on this machine."""
    kind = body.get("type")
    name = body.get("file") if kind in ("mesh", "points") else body.get("urdf") if kind == "urdf" else None
    return name if isinstance(name, str) and not name.startswith(PYBULLET_DATA) else None


def twin_inputs(twin: TwinDescription) -> dict:
    """What of a twin shapes its artefacts (not its version number: a scene back to an earlier state is
    the earlier entry)."""
    return {"robot": twin.robot, "urdf_sha256": twin.urdf_sha256, "base": twin.base, "ee": twin.ee,
            "base_link": twin.base_link, "fixed": twin.fixed, "packages": twin.packages,
            "allowed_collisions": twin.allowed_collisions, "scene": twin.scene, "samples": twin.samples,
            "seed": twin.seed, "calibration": twin.calibration, "frame": twin.frame}


def cache_key(twin: TwinDescription, urdf: Path | None = None) -> str:
    """The key of `twin`'s artefacts: its inputs, its URDF's meshes (when the URDF is here), the files its
    scene's bodies name and the code."""
    inputs = {**twin_inputs(twin), "code": code_fingerprint(),
              "meshes": meshes_fingerprint(urdf, twin.packages) if urdf is not None else None,
              "scene_file_contents": scene_files_fingerprint(twin.scene)}
    return hashlib.sha256(msgspec.json.encode(inputs, order="sorted")).hexdigest()[:32]


class ArtefactCache:
    """`cache_dir/<key>/`: made whole in a temporary folder and renamed, so a stop or a crash leaves no
    half-written entry; two makers of the same key both end with one good entry."""

    def __init__(self, cache_dir: Path):
        self.dir = cache_dir

    def entry(self, key: str) -> Path:
        return self.dir / key

    def has(self, key: str) -> bool:
        return (self.dir / key / DONE).exists()

    def make(self, key: str, fill: Callable[[Path], None]) -> Path:
        """Run `fill(folder)` into a fresh folder and keep it as the entry for `key`."""
        out = self.dir / key
        self.dir.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.{os.getpid()}.{threading.get_ident()}")
        shutil.rmtree(tmp, ignore_errors=True)
        try:
            tmp.mkdir(parents=True)
            fill(tmp)
            (tmp / DONE).write_text(code_fingerprint() + "\n")
            try:
                tmp.rename(out)
            except OSError:  # another maker was first: theirs is as good
                if not (out / DONE).exists():
                    raise
        finally:
            shutil.rmtree(tmp, ignore_errors=True)
        return out
