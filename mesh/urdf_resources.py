"""Where a URDF's mesh files are: `package://`, `file://` and relative URIs resolved as ROS does.

pybullet finds `package://NAME/rest` by searching upward from the URDF; ROS tools look NAME up in
ROS_PACKAGE_PATH (ROS 1) or AMENT_PREFIX_PATH (`<prefix>/share/NAME`, ROS 2). Both are tried, after
packages named explicitly (`NAME=DIR`), then pybullet_data. A renderer that gets only the URDF's
text (the recorder gets it over the mesh) needs the file names made absolute this way.
"""
from __future__ import annotations

import os
import re
from collections.abc import Iterable, Mapping
from pathlib import Path

MESH_FILENAME = re.compile(r'(<mesh\b[^>]*?\bfilename\s*=\s*)(["\'])(.*?)\2', re.S)


def package_dirs(name: str, packages: Mapping[str, Path] | None = None) -> list[Path]:
    """Candidate roots of ROS package `name`, most specific first."""
    dirs = [Path(packages[name])] if packages and name in packages else []
    for root in filter(None, os.environ.get("ROS_PACKAGE_PATH", "").split(os.pathsep)):
        dirs += [Path(root) / name, Path(root)] if Path(root).name != name else [Path(root)]
    for prefix in filter(None, os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep)):
        dirs.append(Path(prefix) / "share" / name)
    return dirs


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
        candidates = [Path(uri[len("file://"):])]
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
