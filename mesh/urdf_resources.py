"""Where a URDF's mesh files are: `package://`, `file://` and relative URIs resolved as ROS does.

pybullet finds `package://NAME/rest` by searching upward from the URDF; ROS tools look NAME up in
ROS_PACKAGE_PATH (ROS 1: the package whose folder or package.xml says NAME) or AMENT_PREFIX_PATH
(`<prefix>/share/NAME`, ROS 2). Both are tried, after packages named explicitly (`NAME=DIR`), then
pybullet_data. Relative paths, `file://` ones included, are the URDF's folder's, never the current
directory's. A renderer that gets only the URDF's
text (the recorder gets it over the mesh) needs the file names made absolute this way.
"""
from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path
from urllib.parse import unquote

MESH_FILENAME = re.compile(r'(<mesh\b[^>]*?\bfilename\s*=\s*)(["\'])(.*?)\2', re.S)


PACKAGE_NAME = re.compile(r"<name>\s*([^<\s]+)\s*</name>")
SEARCH_DEPTH = 3  # how deep below a ROS_PACKAGE_PATH entry a package.xml is looked for (as rospack does)


def package_dirs(name: str, packages: Mapping[str, Path] | None = None) -> list[Path]:
    """Candidate roots of ROS package `name`, most specific first: a folder named explicitly, then a
    ROS_PACKAGE_PATH entry that is that package or holds it (a folder called `name`, or whose
    package.xml says `<name>name</name>`), then `<prefix>/share/name` of AMENT_PREFIX_PATH. A
    ROS_PACKAGE_PATH entry is never taken for a package it is not."""
    dirs = [Path(packages[name])] if packages and name in packages else []
    for root in map(Path, filter(None, os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep))):
        dirs += [d for d in _packages_under(root) if _package_name(d) == name]
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        dirs.append(Path(prefix) / "share" / name)
    return dirs


def _package_name(folder: Path) -> str:
    """The name a package folder declares in its package.xml (its folder name when it has none)."""
    try:
        found = PACKAGE_NAME.search((folder / "package.xml").read_text(encoding="utf-8", errors="replace"))
    except OSError:
        return folder.name
    return found.group(1) if found else folder.name


def _packages_under(root: Path, depth: int = SEARCH_DEPTH) -> list[Path]:
    """`root` and the folders below it (to `depth`) that are packages: they hold a package.xml, or
    (the root's direct children and the root itself) are plain folders someone named by package."""
    if not root.is_dir():
        return []
    found = [root]
    frontier = [root]
    for level in range(depth):
        below = []
        for folder in frontier:
            try:
                children = [c for c in folder.iterdir() if c.is_dir() and not c.name.startswith(".")]
            except OSError:
                continue
            for child in children:
                if level == 0 or (child / "package.xml").is_file():
                    found.append(child)
                if not (child / "package.xml").is_file():
                    below.append(child)
        frontier = below
    return found


def package_dir(name: str, near: Path | None, packages: Mapping[str, Path] | None = None) -> Path | None:
    """The directory of ROS package `name`: named, from the environment, or an ancestor of `near`
    (or a sibling of one) called `name`, as pybullet's upward search finds it."""
    ups = [near, *near.parents] if near else []
    candidates = package_dirs(name, packages) + [d for up in ups for d in ((up,) if up.name == name else (up / name,))]
    return next((c.resolve() for c in candidates if c.is_dir()), None)


def resolve_uri(uri: str, urdf_dir: Path | None, packages: Mapping[str, Path] | None = None) -> tuple[Path | None,
                                                                                                         list[Path]]:
    """(the file `uri` names, or None; every place looked at) for a mesh of a URDF in `urdf_dir`."""
    tried: list[Path] = []
    if uri.startswith("file://"):
        path = Path(unquote(uri[len("file://"):]))  # file:///abs is absolute; file://meshes/x is the URDF's
        candidates = [path] if path.is_absolute() else [urdf_dir / path] if urdf_dir else []
    elif uri.startswith("package://"):
        name, _, rest = uri[len("package://"):].partition("/")
        candidates = [d / rest for d in package_dirs(name, packages)]
        for up in ([urdf_dir, *urdf_dir.parents] if urdf_dir else []):  # pybullet's upward search
            candidates += [up / rest] if up.name == name else []
            candidates.append(up / name / rest)
        candidates += [d / name / rest for d in _pybullet_data()]
    else:
        path = Path(uri)
        candidates = [path] if path.is_absolute() else [d / path for d in [urdf_dir, *_pybullet_data()] if d]
    for c in candidates:
        tried.append(c)
        if c.is_file():
            return c.resolve(), tried
    return None, tried


def with_absolute_meshes(urdf: str, urdf_dir: Path | None,
                         packages: Mapping[str, Path] | None = None) -> tuple[str, list[str]]:
    """The URDF text with every mesh filename that can be found made absolute, and a sentence for each
    that cannot (naming the file and where it was looked for)."""
    missing: list[str] = []

    def absolute(m: re.Match) -> str:
        found, tried = resolve_uri(m.group(3), urdf_dir, packages)
        if found is None:
            where = ", ".join(str(t) for t in _unique(tried)[:4]) or "nowhere (no URDF location known)"
            missing.append(f"mesh {m.group(3)} not found (looked in {where})")
            return m.group(0)
        return f"{m.group(1)}{m.group(2)}{found}{m.group(2)}"

    return MESH_FILENAME.sub(absolute, urdf), _unique(missing)


def _pybullet_data() -> list[Path]:
    try:
        import pybullet_data
    except ImportError:  # pragma: no cover - pybullet is a dependency
        return []
    return [Path(pybullet_data.getDataPath())]


def _unique(items: Iterable) -> list:
    return list(dict.fromkeys(items))
