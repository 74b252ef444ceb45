"""A URDF file as pybullet and our parser can read it, whatever shape it comes in.

Labs publish URDFs with attributes in XML prefixes nobody declares (`drake:`, which urdfdom and
pybullet ignore and an XML parser refuses), with `package://` meshes that only ROS knows where to
find, or as `.xacro` sources. `loadable_urdf` gives the file pybullet should load (the URDF, or a
copy with every mesh made absolute and the prefixes declared); `expand_xacro` turns a `.xacro`
into URDF; `declared` makes the text parseable. Copies live under the temporary directory, named
by the hash of their content.
"""
from __future__ import annotations

import hashlib
import os
import re
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from pathlib import Path

from mesh.urdf_resources import package_dir, with_absolute_meshes
from tdgen.robot.errors import RobotError


def visual_collisions(text: str) -> tuple[str, list[str]]:
    """The URDF with a `<collision>` made from the `<visual>` of every link that has a visual mesh but no
    collision geometry (classic and hobby arms often ship so: counted as nothing, the arm went through
    the floor and itself unseen), and those links' names; where the URDF has no collision geometry at
    all, every visual counts, primitives too (elsewhere a lone sphere or box is a frame's marker).
    A URDF left without any collision geometry still loads (kinematics and IK need none); the collision
    test refuses it (`CollisionWorld`): every sample would be free."""
    root = ET.fromstring(text)
    borrowed = []
    anything = any(link.find("collision") is not None for link in root.iter("link"))
    for link in root.iter("link"):
        if link.find("collision") is not None:
            continue
        visuals = [v for v in link.findall("visual") if v.find("geometry") is not None]
        if anything:  # beside collision shapes, a primitive-only visual is a marker (a joint's sphere), not a body
            visuals = [v for v in visuals if v.find("geometry/mesh") is not None]
        for visual in visuals:
            collision = ET.SubElement(link, "collision")
            for part in ("origin", "geometry"):
                found = visual.find(part)
                if found is not None:
                    collision.append(found)
        if visuals:
            borrowed.append(link.get("name", "?"))
    if not borrowed:
        return text, []
    return ET.tostring(root, encoding="unicode"), borrowed


PYBULLET_MAX_LINKS = 128  # links one pybullet body can hold: beyond, its state queries fail (bullet3 #4621)


def without_bare_leaves(text: str, keep: set[str]) -> tuple[str, int, int]:
    """The URDF without the links that have no geometry and hang by a fixed joint with nothing below them
    (sensor, skin and DH frames: iCub has 150 of them), except `keep`; how many links it had, and how
    many went. They change no collision and no kinematics of the kept links."""
    root = ET.fromstring(text)
    links = {link.get("name", ""): link for link in root.findall("link")}
    below: dict[str, list[str]] = {name: [] for name in links}
    hung: dict[str, ET.Element] = {}  # child link -> its joint
    for joint in root.findall("joint"):
        parent, child = joint.find("parent"), joint.find("child")
        if parent is not None and child is not None:
            below.setdefault(parent.get("link", ""), []).append(child.get("link", ""))
            hung[child.get("link", "")] = joint
    gone: set[str] = set()
    changed = True
    while changed:
        changed = False
        for name, link in links.items():
            hanger = hung.get(name)
            if (name in gone or name in keep or hanger is None or hanger.get("type") != "fixed"
                    or link.find("visual") is not None or link.find("collision") is not None
                    or not all(c in gone for c in below.get(name, []))):
                continue
            gone.add(name)
            changed = True
    if not gone:
        return text, len(links), 0
    for name in gone:
        root.remove(links[name])
        root.remove(hung[name])
    return ET.tostring(root, encoding="unicode"), len(links), len(gone)


def loadable_urdf(path: Path, packages: Mapping[str, Path] | None = None, shown: Path | None = None,
                  keep: set[str] | None = None) -> tuple[Path, list[str]]:
    """The file pybullet should load for `path`, and the links whose visual geometry stands in for the
    collision geometry they lack (`visual_collisions`): `path` itself, or (where it has `package://` or
    `file://` meshes, undeclared XML prefixes or borrowed collisions) a copy with every mesh made absolute
    as ROS resolves it, the prefixes declared and the collisions added. A URDF of more links than a
    pybullet body holds loses its bare leaf frames (`without_bare_leaves`, never those in `keep`: the
    arm's chain), or is refused naming both counts. A mesh that cannot be found is a RobotError naming it
    and where it was looked for; messages name `shown` (the user's file) if given."""
    name = shown or path
    text = path.read_text(encoding="utf-8", errors="replace")
    resolved, missing = with_absolute_meshes(text, path.parent, packages)
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise RobotError(f"{name}: {missing[0]}{more}; name package directories with --package-path NAME=DIR, "
                         "ROS_PACKAGE_PATH or AMENT_PREFIX_PATH")
    try:
        complete, borrowed = visual_collisions(declared(resolved))
        count = len(ET.fromstring(complete).findall("link"))
        pruned = 0
        if count > PYBULLET_MAX_LINKS:
            complete, count, pruned = without_bare_leaves(complete, keep or set())
    except ET.ParseError as e:
        raise RobotError(f"{name}: not a URDF pybullet can read ({e})") from None
    if count - pruned > PYBULLET_MAX_LINKS:
        left = (f"{count - pruned} are left after dropping {pruned} frames without geometry or anything below them"
                if pruned else "none is a frame without geometry that could be dropped")
        raise RobotError(f"{name}: {count} links, and pybullet holds at most {PYBULLET_MAX_LINKS} in one body "
                         f"({left}); cut the URDF down to the arm and what it can touch")
    if not pruned and not borrowed and "package://" not in text and "file://" not in text and declared(text) == text:
        return path, []
    return _resolved_copy(path.name, complete if borrowed or pruned else declared(resolved)), borrowed


def _resolved_copy(name: str, text: str) -> Path:
    """`text` as a file called `name`, under the temporary directory, named by its content's hash."""
    digest = hashlib.sha256(text.encode()).hexdigest()[:16]
    out = Path(tempfile.gettempdir()) / "twinmesh-urdf" / digest / name
    if not out.is_file():
        out.parent.mkdir(parents=True, exist_ok=True)
        tmp = out.with_name(f".{out.name}.{os.getpid()}")
        tmp.write_text(text, encoding="utf-8")
        tmp.replace(out)
    return out


def expand_xacro(path: Path, packages: Mapping[str, Path] | None = None) -> Path:
    """A `.xacro` file expanded to URDF (with the `xacro` package, when installed): `$(find NAME)` is
    resolved as `package://NAME` is (explicit packages, ROS_PACKAGE_PATH, AMENT_PREFIX_PATH, then
    upward from the file). The URDF is written beside the other resolved copies and returned."""
    try:
        import xacro
        import xacro.substitution_args as substitution
    except ImportError:
        raise RobotError(f"{path}: a .xacro file needs the xacro package (pip install xacro), or expand it "
                         "first (xacro FILE > robot.urdf)") from None

    found_packages: dict[str, Path] = {}
    unfound: list[RobotError] = []  # xacro wraps what `find` raises in its own exception: said once, ours

    def find(name: str) -> str:
        found = package_dir(name, path.parent, packages)
        if found is None:
            unfound.append(RobotError(f"{path}: $(find {name}): no package {name!r} (looked in: "
                                      f"{_looked_in(name, path.parent, packages)}; name it with --package-path "
                                      f"{name}=DIR, ROS_PACKAGE_PATH or AMENT_PREFIX_PATH)"))
            raise unfound[-1]
        found_packages[name] = found
        return str(found)

    original = substitution._eval_find
    substitution._eval_find = find  # xacro asks ament_index; twinmesh answers as for package:// URIs
    try:
        text = xacro.process_file(str(path)).toprettyxml(indent="  ")
    except RobotError:
        raise
    except Exception as exc:  # xacro raises its own XacroException and plain errors alike
        if unfound:
            raise unfound[0] from None
        said = " ".join(str(exc).split())  # one line
        raise RobotError(f"{path}: xacro could not expand it ({type(exc).__name__}: {said})") from None
    finally:
        substitution._eval_find = original
    # the meshes as the xacro names them: relative ones from its own folder, package:// ones from where
    # its $(find ...) found the package (the expanded copy lives elsewhere and knows neither)
    text, missing = with_absolute_meshes(text, path.parent, {**(packages or {}), **found_packages})
    if missing:
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise RobotError(f"{path}: {missing[0]}{more}; name package directories with --package-path NAME=DIR, "
                         "ROS_PACKAGE_PATH or AMENT_PREFIX_PATH")
    return _resolved_copy(path.name.removesuffix(".xacro").removesuffix(".urdf") + ".urdf", text)


_PREFIXED_NAME = re.compile(r"[<\s/]([A-Za-z_][\w.-]*):[A-Za-z_][\w.-]*(?=[\s=/>])")


def declared(text: str) -> str:
    """The URDF with every undeclared XML namespace prefix (`drake:`, `gazebo:`) declared on <robot>:
    urdfdom and pybullet ignore them, an XML parser would refuse the file."""
    prefixes = {p for p in _PREFIXED_NAME.findall(text) if p not in ("xml", "xmlns")}
    undeclared = sorted(p for p in prefixes if f"xmlns:{p}=" not in text)
    if not undeclared:
        return text
    declarations = "".join(f' xmlns:{p}="urn:twinmesh:undeclared:{p}"' for p in undeclared)
    return re.sub(r"<robot\b", "<robot" + declarations, text, count=1)


def _looked_in(name: str, near: Path, packages: Mapping[str, Path] | None) -> str:
    """Where a package was looked for, for the message that says it was not found."""
    from mesh.urdf_resources import package_dirs

    places = [str(d) for d in package_dirs(name, packages)] + [f"upward from {near} for a folder {name}"]
    if not os.environ.get("ROS_PACKAGE_PATH"):
        places.append("ROS_PACKAGE_PATH (not set)")
    if not os.environ.get("AMENT_PREFIX_PATH"):
        places.append("AMENT_PREFIX_PATH (not set)")
    return ", ".join(places)
