"""The one `Robot`: a URDF, its main joints, its end effector and how passive joints follow.

Everything in tdgen (kinematics, IK, sampling, workspace, TD) takes a `Robot` instead of
reloading the URDF itself, so joint order, limits and units are decided here once.

Choices a user should know about:
- Units are SI inside (rad, m); `info()` and `to_user_units` give deg for revolute/continuous
  joints and mm for prismatic joints, as the TD does.
- Continuous joints get the limits -pi..pi (one full turn, every orientation once).
- Main joints are the actuated joints on the chain from the base link (default: the URDF's root
  link) to the end effector, minus URDF <mimic> joints, the joints named passive and the joints
  held at a value (`fixed=`, e.g. a torso lift). Joints above the base link are held (at 0 unless
  `fixed` says otherwise); branches off the chain (a Panda's finger joints) stay at 0.
- The automatic end effector is where the arm ends: among the chains from the base link, those
  with the most arm joints win, where a chain stops before a tool joint (named like a gripper,
  finger, jaw, claw, thumb or knuckle joint, or a mimic of one; a parallelogram's mimic of
  an arm joint belongs to the arm). From the last arm joint it
  follows the only fixed child, as long as there is exactly one (the Panda's `panda_grasptarget`;
  a UR's `wrist_3_link`, which has two). Where equally long chains split into three or more
  branches, or into short ones (4 arm joints at most), they are a hand's fingers and the arm ends
  at the split (Tiago's palm); two equally long arms (Baxter's, the PR2's) are an error listing
  them: pass `ee=` to pick one.
- The end-effector position is the origin of the URDF link frame (pybullet's
  `worldLinkFramePosition`), not the link's centre of mass.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from tdgen.robot.errors import RobotError
from tdgen.robot.urdf_files import declared, expand_xacro, loadable_urdf

ROBOTS_DIR = Path(__file__).parent / "models"  # the shipped URDFs
MOVABLE = ("revolute", "prismatic", "continuous")
TOOL_WORDS = re.compile(r"finger|gripper|jaw|claw|thumb|knuckle|grasp|suction|tool_?changer")


@dataclass(frozen=True)
class Joint:
    name: str
    type: str          # "revolute" | "prismatic" | "continuous"
    index: int         # pybullet joint index
    lower: float       # SI: rad or m; continuous joints: -pi
    upper: float       # continuous joints: +pi
    max_velocity: float  # rad/s or m/s; 1.0 when the URDF gives 0 or nothing


PassiveMap = Callable[[np.ndarray], np.ndarray]  # (N, n_main) -> (N, n_passive), vectorised


@dataclass(frozen=True)
class UrdfJoint:
    """One <joint> as the URDF states it (SI), for kinematics that must match the file exactly."""

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float | None
    upper: float | None
    velocity: float | None
    mimic: tuple[str, float, float] | None  # (joint, multiplier, offset)


@dataclass(frozen=True)
class Drive:
    """How a movable joint's value follows the main joints: multiplier * source + offset.

    `kind` is "main" or "passive" (source = column `index` of q or of passive(q)), or "const"
    (a mimic of a joint nobody moves: the value is just `offset`).
    """

    kind: str
    index: int
    multiplier: float = 1.0
    offset: float = 0.0


@dataclass
class Robot:
    urdf_path: Path
    name: str
    joints: list[Joint]
    passive_names: list[str]
    ee_link: str
    ee_index: int
    passive: PassiveMap | None
    _urdf_joints: dict[str, UrdfJoint] = field(default_factory=dict, repr=False, compare=False)
    _indices: dict[str, int] = field(default_factory=dict, repr=False, compare=False)
    root_link: str = ""                     # the URDF's root: the frame of every position
    base_link: str = ""                     # where the arm chain starts (the root unless told)
    held: dict[str, float] = field(default_factory=dict)   # joints held at a value (SI), not moved
    load_path: Path | None = None           # what pybullet loads: the URDF, or a copy with meshes resolved
    packages: dict[str, str] = field(default_factory=dict)  # ROS package directories it was loaded with
    allowed_collisions: tuple[tuple[str, str], ...] = ()    # link pairs whose contact is not a collision
    visual_collisions: tuple[str, ...] = ()  # links without collision geometry: their visual geometry is used
    source: Path | None = None               # the user's file (a .xacro, not its expansion): what messages name

    @classmethod
    def load(cls, urdf: str | Path, ee: str | None = None, passive_joints: Sequence[str] = (),
             passive: PassiveMap | None = None, *, base_link: str | None = None,
             fixed: Mapping[str, float] | None = None, packages: Mapping[str, Path] | None = None,
             allowed_collisions: Sequence[tuple[str, str]] = ()) -> "Robot":
        """Read the URDF (xml for structure, a private pybullet client for joint indices).

        `base_link` starts the arm chain elsewhere than the root link; `fixed` holds joints at a
        value (deg or mm, as the TD's units); `packages` names the directories of ROS packages
        (`package://NAME/...`); `allowed_collisions` lists link pairs whose contact does not count (as
        an SRDF's disabled collisions do: meshes that overlap by design).
        """
        path = source = resolve_urdf(urdf)  # messages name `source`, the user's file, not an expanded copy
        if path.suffix == ".xacro":
            path = expand_xacro(path, packages)
        name, root, ujoints = _parse_urdf(path)
        by_child = {j.child: j for j in ujoints.values()}
        links = {root} | set(by_child)
        for what, link in (("base link", base_link), ("end-effector link", ee)):
            if link is not None and link not in links:
                raise RobotError(f"{source}: no link named {link!r} for the {what} (links: {', '.join(sorted(links))})")
        unknown = [n for n in (fixed or {}) if n not in ujoints or ujoints[n].type not in MOVABLE]
        if unknown:
            raise RobotError(f"{source}: cannot hold {', '.join(unknown)}: not movable joints of the URDF "
                             f"(movable: {', '.join(n for n, j in ujoints.items() if j.type in MOVABLE)})")
        held = {n: v / 1000.0 if ujoints[n].type == "prismatic" else math.radians(v) for n, v in (fixed or {}).items()}
        allowed = tuple((str(a), str(b)) for a, b in allowed_collisions)
        strangers = sorted({a if a not in links else b for a, b in allowed if a not in links and b not in links}
                           | {n for a, b in allowed if a not in links and b not in links for n in (a, b)})
        if strangers:  # a pair of a link and a scene body (LINK/mounting-surface) is checked with the scene
            raise RobotError(f"{source}: no link named {', '.join(map(repr, strangers))} for an allowed collision "
                             f"(a pair names a link, and a link or a scene body; links: {', '.join(sorted(links))})")
        base = base_link or root
        if ee is None:
            ee = _auto_ee(path, base, ujoints, set(held))
        above = _path_to(base, by_child)
        chain = _path_to(ee, by_child)
        if chain[:len(above)] != above or (base != root and not any(j.parent == base for j in chain)):
            raise RobotError(f"{source}: the end-effector link {ee!r} is not below the base link {base!r}")
        held.update({j.name: 0.0 for j in above if j.type in MOVABLE and j.mimic is None and j.name not in held})
        passive_names = list(passive_joints)
        unknown = [n for n in passive_names if n not in ujoints or ujoints[n].type not in MOVABLE]
        if unknown:
            raise RobotError(f"{source}: passive joints {unknown} are not movable joints of the URDF")
        if passive_names and passive is None:
            raise RobotError(f"{source}: passive joints {passive_names} need a passive map")
        main = [j for j in chain[len(above):] if j.type in MOVABLE and j.mimic is None
                and j.name not in passive_names and j.name not in held]
        if not main:
            raise RobotError(f"{source}: no actuated joint between the base link {base!r} and {ee!r} "
                             "(pick the arm's links with --base-link and --ee)")
        keep = {root, base, ee, *(j.child for j in chain), *(j.parent for j in chain), *(n for p in allowed for n in p)}
        load_path, borrowed = loadable_urdf(path, packages, shown=source, keep=keep)
        indices, link_indices = _pybullet_indices(load_path)
        joints = [Joint(j.name, j.type, indices[j.name], *_limits(j), _velocity(j)) for j in main]
        return cls(path, name, joints, passive_names, ee, link_indices[ee], passive, ujoints, indices,
                   root_link=root, base_link=base, held=held, load_path=load_path,
                   packages={k: str(v) for k, v in (packages or {}).items()}, allowed_collisions=allowed,
                   visual_collisions=tuple(borrowed), source=source)

    # --- limits and units -------------------------------------------------------------------
    def lows(self) -> np.ndarray:
        return np.array([j.lower for j in self.joints])

    def highs(self) -> np.ndarray:
        return np.array([j.upper for j in self.joints])

    def _user_scale(self) -> np.ndarray:
        return np.array([1000.0 if j.type == "prismatic" else 180.0 / math.pi for j in self.joints])

    def to_user_units(self, q: np.ndarray) -> np.ndarray:
        """rad -> deg, m -> mm per joint; works on (n,) and (N, n)."""
        return np.asarray(q, dtype=float) * self._user_scale()

    def from_user_units(self, q: np.ndarray) -> np.ndarray:
        return np.asarray(q, dtype=float) / self._user_scale()

    def info(self) -> dict:
        """The TD's robot info: main joints only, limits in deg / mm."""
        return {
            "robotName": self.name,
            "jointAmount": len(self.joints),
            "jointNames": [j.name for j in self.joints],
            "jointTypes": [j.type for j in self.joints],
            "jointLimitLows": self.to_user_units(self.lows()).tolist(),
            "jointLimitHighs": self.to_user_units(self.highs()).tolist(),
            "baseLink": self.base_link,
            "tipLink": self.ee_link,
            "rootLink": self.root_link,
            "heldJoints": {n: self._user_value(n, v) for n, v in self.held.items()},
        }

    def _user_value(self, joint: str, value: float) -> float:
        """deg for a revolute or continuous joint, mm for a prismatic one."""
        return value * 1000.0 if self._urdf_joints[joint].type == "prismatic" else math.degrees(value)

    def notes(self) -> list[str]:
        """What a user should know about how the URDF was taken (said once, on stderr or in the log)."""
        if not self.visual_collisions:
            return []
        return [f"{len(self.visual_collisions)} link(s) have no collision geometry; their visual geometry is "
                f"used for collision: {', '.join(self.visual_collisions)}"]

    def describe_chain(self) -> str:
        """The chain in one line, for people: base and tip links, the joints in between, held joints."""
        held = (f"; held: {', '.join(f'{n}={self._user_value(n, v):g}' for n, v in self.held.items())}"
                if self.held else "")
        return (f"arm chain {self.base_link} -> {self.ee_link}: {len(self.joints)} joints "
                f"({', '.join(j.name for j in self.joints)}){held}")

    # --- joint values -----------------------------------------------------------------------
    def chain(self) -> list[UrdfJoint]:
        """The URDF joints (fixed ones included) from the root link to the end effector."""
        return _path_to(self.ee_link, {j.child: j for j in self._urdf_joints.values()})

    def slide_along(self, a: str, b: str) -> bool:
        """Whether links a and b are joined by prismatic joints (and fixed ones) only: nested parts of a
        telescope or a lift, which slide along each other, their convex hulls overlapping by design."""
        by_child = {j.child: j for j in self._urdf_joints.values()}
        up_a, up_b = _path_to(a, by_child), _path_to(b, by_child)
        shared = 0
        while shared < min(len(up_a), len(up_b)) and up_a[shared] is up_b[shared]:
            shared += 1
        between = up_a[shared:] + up_b[shared:]
        return (any(j.type == "prismatic" for j in between)
                and all(j.type in ("prismatic", "fixed") for j in between))

    def reach(self) -> float:
        """An upper bound of how far the tip gets from the base link (m): the chain's joint offsets end to
        end, each prismatic joint at its longest."""
        total = 0.0
        for j in self.chain():
            total += math.dist(j.xyz, (0.0, 0.0, 0.0))
            if j.type == "prismatic":
                total += max(abs(j.lower or 0.0), abs(j.upper or 0.0))
        return total

    def drives(self) -> dict[str, Drive]:
        """How every main, passive and mimic joint of the URDF gets its value."""
        main = {j.name: k for k, j in enumerate(self.joints)}
        passive = {n: k for k, n in enumerate(self.passive_names)}

        def drive(name: str, depth: int = 0) -> Drive:
            if name in main:
                return Drive("main", main[name])
            if name in passive:
                return Drive("passive", passive[name])
            if name in self.held:
                return Drive("const", -1, 0.0, self.held[name])
            uj = self._urdf_joints.get(name)
            if uj is None or uj.mimic is None or depth > len(self._urdf_joints):
                return Drive("const", -1, 0.0, 0.0)
            src = drive(uj.mimic[0], depth + 1)
            m, off = uj.mimic[1], uj.mimic[2]
            return Drive(src.kind, src.index, m * src.multiplier, m * src.offset + off)

        mimics = [n for n, j in self._urdf_joints.items() if j.mimic and n not in main and n not in passive]
        return {n: drive(n) for n in dict.fromkeys([*main, *passive, *self.held, *mimics])}

    def joint_values(self, q: np.ndarray) -> dict[str, np.ndarray]:
        """Values of main, passive and mimic joints for (N, n) main-joint values, vectorised."""
        q = np.atleast_2d(np.asarray(q, dtype=float))
        p = self.passive(q) if self.passive is not None else np.zeros((len(q), 0))
        sources = {"main": q, "passive": np.atleast_2d(p)}
        out = {}
        for name, d in self.drives().items():
            base = sources[d.kind][:, d.index] if d.kind != "const" else np.zeros(len(q))
            out[name] = d.multiplier * base + d.offset
        return out

    def full_joint_values(self, q: np.ndarray) -> dict[int, float]:
        """pybullet joint index -> value for main, passive and mimic joints (for resetJointState)."""
        return {self._indices[n]: float(v[0]) for n, v in self.joint_values(np.asarray(q)[None]).items()}

    # --- pybullet ---------------------------------------------------------------------------
    def load_into(self, client: int, base_position=(0, 0, 0), base_yaw: float = 0.0, flags: int = 0,
                  base_orientation: Sequence[float] | None = None) -> int:
        """Load the robot with a fixed base into pybullet client `client`; returns the body id.
        `base_orientation` (a quaternion x, y, z, w) replaces `base_yaw` (rad) for a tilted mount."""
        import pybullet as pb

        orn = list(base_orientation) if base_orientation is not None else pb.getQuaternionFromEuler([0.0, 0.0, base_yaw])
        try:
            body = pb.loadURDF(str(self.load_path or self.urdf_path), list(base_position), orn, useFixedBase=True,
                               flags=flags, physicsClientId=client)
        except pb.error as exc:
            raise RobotError(f"{self.urdf_path}: pybullet cannot load it ({exc})") from None
        if pb.getNumJoints(body, physicsClientId=client) != len(self._indices):
            pb.removeBody(body, physicsClientId=client)
            raise RobotError(f"{self.urdf_path}: flags {flags} change the link structure, "
                             "so the joint indices would not match")
        return body


def resolve_urdf(urdf: str | Path) -> Path:
    """Find a URDF as given, among tdgen's robots, or in pybullet_data (`franka_panda/panda.urdf`)."""
    import pybullet_data

    given = Path(urdf).expanduser()
    for candidate in (given, ROBOTS_DIR / given, Path(pybullet_data.getDataPath()) / given):
        if candidate.is_file():
            return candidate.resolve()
    raise RobotError(f"{urdf}: URDF file not found (looked here, in {ROBOTS_DIR} and in pybullet_data)")


def _floats(text: str | None, default: tuple[float, float, float], what: str = "") -> tuple[float, float, float]:
    """Three numbers of a URDF attribute (xyz, rpy, axis), separated by spaces as urdfdom reads them."""
    if not text:
        return default
    try:
        x, y, z = (float(v) for v in text.split())
    except ValueError:
        raise ValueError(f'{what}="{text}" is not three numbers separated by spaces') from None
    return x, y, z


def _child(el: ET.Element, tag: str) -> ET.Element:
    found = el.find(tag)
    if found is None:
        raise KeyError(f"no <{tag}>")
    return found


def _parse_urdf(path: Path) -> tuple[str, str, dict[str, UrdfJoint]]:
    """(robot name, root link, joints by name) straight from the XML, as tolerant as urdfdom of
    attributes and elements in prefixes it does not declare."""
    try:
        root_el = ET.fromstring(declared(path.read_text(encoding="utf-8", errors="replace")))
    except ET.ParseError as exc:
        raise RobotError(f"{path}: broken XML ({exc})") from None
    if root_el.tag != "robot":
        raise RobotError(f"{path}: not a URDF (root element <{root_el.tag}>, expected <robot>)")
    joints: dict[str, UrdfJoint] = {}
    el = None
    try:
        for el in root_el.findall("joint"):
            origin, axis, limit, mimic = (el.find(t) for t in ("origin", "axis", "limit", "mimic"))
            lim = limit.attrib if limit is not None else {}
            joints[el.attrib["name"]] = UrdfJoint(
                name=el.attrib["name"], type=el.attrib["type"],
                parent=_child(el, "parent").attrib["link"], child=_child(el, "child").attrib["link"],
                xyz=_floats(origin.get("xyz") if origin is not None else None, (0.0, 0.0, 0.0), "<origin> xyz"),
                rpy=_floats(origin.get("rpy") if origin is not None else None, (0.0, 0.0, 0.0), "<origin> rpy"),
                axis=_floats(axis.get("xyz") if axis is not None else None, (1.0, 0.0, 0.0), "<axis> xyz"),
                lower=float(lim["lower"]) if "lower" in lim else None,
                upper=float(lim["upper"]) if "upper" in lim else None,
                velocity=float(lim["velocity"]) if "velocity" in lim else None,
                mimic=(mimic.attrib["joint"], float(mimic.get("multiplier", 1)), float(mimic.get("offset", 0)))
                if mimic is not None else None)
    except (KeyError, AttributeError, ValueError) as exc:
        named = f" {el.get('name')!r}" if el is not None and el.get("name") else ""
        raise RobotError(f"{path}: malformed <joint>{named} ({type(exc).__name__}: {exc})") from None
    links = [el.attrib["name"] for el in root_el.findall("link") if "name" in el.attrib]
    roots = [n for n in links if n not in {j.child for j in joints.values()}]
    if len(roots) != 1:
        raise RobotError(f"{path}: expected one root link, found {roots or 'none'}")
    return root_el.get("name", path.stem), roots[0], joints


def _path_to(link: str, by_child: dict[str, UrdfJoint]) -> list[UrdfJoint]:
    chain = []
    while link in by_child:
        chain.append(by_child[link])
        link = by_child[link].parent
    return chain[::-1]


def is_tool_joint(j: UrdfJoint, joints: Mapping[str, UrdfJoint], depth: int = 0) -> bool:
    """A joint of the tool rather than the arm: named like a gripper's, or a mimic of such a joint
    (a parallelogram's mimic of an arm joint is part of the arm)."""
    if TOOL_WORDS.search(j.name.lower()):  # the joint's name: a wrist may well turn a link called `gripper`
        return True
    source = joints.get(j.mimic[0]) if j.mimic else None
    return source is not None and depth < len(joints) and is_tool_joint(source, joints, depth + 1)


def _auto_ee(path: Path, base: str, joints: dict[str, UrdfJoint], held: set[str]) -> str:
    """Where the arm from `base` ends (see the module's notes); several equal arms are an error."""
    children: dict[str, list[UrdfJoint]] = {}
    for j in joints.values():
        children.setdefault(j.parent, []).append(j)

    def arm(j: UrdfJoint) -> bool:
        return j.type in MOVABLE and j.name not in held and not is_tool_joint(j, joints)

    ends: dict[str, int] = {}  # the link after an arm's last arm joint -> its arm joints

    def walk(link: str, count: int, last: str | None) -> None:
        onward = [j for j in children.get(link, []) if j.type not in MOVABLE or j.name in held or arm(j)]
        if not onward and last is not None:
            ends[last] = max(ends.get(last, 0), count)
        for j in onward:
            walk(j.child, count + arm(j), j.child if arm(j) else last)

    walk(base, 0, None)
    if not ends:
        raise RobotError(f"{path}: no actuated joint below the link {base!r} (pick the arm's links with "
                         "--base-link and --ee)")
    best = max(ends.values())
    tips = sorted(link for link, count in ends.items() if count == best)
    hand = _hand_split(tips, joints, arm) if len(tips) > 1 else None
    if hand is not None:
        return hand
    if len(tips) > 1:
        raise RobotError(f"{path}: {len(tips)} arms of {best} joints start at {base!r}, ending at "
                         f"{', '.join(tips)}: pick one with --ee LINK (and --base-link LINK)")
    return _distal_frame(path, tips[0], children, arm)


TIP_WORDS = re.compile(r"flange|tool|tcp|end_?effector|ee(_|$)|tip|grasp")
FINGER_WORDS = re.compile(r"finger|jaw|claw|thumb|knuckle")  # a gripper's body is a tool frame, its fingers not


def _distal_frame(path: Path, link: str, children: Mapping[str, list[UrdfJoint]],
                  arm: Callable[[UrdfJoint], bool]) -> str:
    """The tip: from the arm's last moving link on through fixed joints (not into a gripper's fingers)
    to the most distal frame. Where the fixed joints branch, the frames named like a flange or a tool
    decide (a Panda's flange beside its end-effector frame: the farthest of them); where none is, the
    branches are the tool's own parts and the arm ends where they split. Tool frames equally far but
    elsewhere are an error listing them; at one place (a UR's ee_link and tool0) they are one tip."""
    leaves: list[tuple[str, float, tuple[float, ...]]] = []

    def walk(at: str, distance: float, where: tuple[float, ...]) -> None:
        onward = children.get(at, [])
        fixed = [j for j in onward if j.type == "fixed" and not FINGER_WORDS.search(f"{j.name} {j.child}".lower())]
        if not fixed or any(arm(j) for j in onward):
            leaves.append((at, distance, where))
            return
        for j in fixed:
            walk(j.child, distance + math.dist(j.xyz, (0.0, 0.0, 0.0)), tuple(a + b for a, b in zip(where, j.xyz)))

    if len(children.get(link, [])) == 0:
        return link
    while True:  # a single fixed line first (the old, common case)
        fixed = [j for j in children.get(link, []) if j.type == "fixed"]
        if len(fixed) != 1 or any(arm(j) for j in children.get(link, [])):
            break
        link = fixed[0].child
    walk(link, 0.0, (0.0, 0.0, 0.0))
    if len(leaves) == 1:
        return leaves[0][0]
    tools = [leaf for leaf in leaves if TIP_WORDS.search(leaf[0].lower())]
    if not tools:
        return link
    farthest = max(d for _, d, _ in tools)
    top = [leaf for leaf in tools if abs(leaf[1] - farthest) < 1e-9]
    if len({tuple(round(v, 6) for v in where) for _, _, where in top}) > 1:
        raise RobotError(f"{path}: the arm ends in {len(top)} tool frames equally far apart "
                         f"({', '.join(name for name, _, _ in top)}): pick the tip with --ee LINK")
    return min(name for name, _, _ in top)


HAND_BRANCH = 4  # arm joints below a split, at most, for the branches to be a hand's fingers, not arms


def _hand_split(tips: list[str], joints: Mapping[str, UrdfJoint], arm: Callable[[UrdfJoint], bool]) -> str | None:
    """Where equally long chains split, when what follows the split is a hand's fingers (short branches,
    or three and more alike) rather than arms: the link the arm ends at. None when the tied chains are
    arms (Baxter's two)."""
    by_child = {j.child: j for j in joints.values()}

    def ancestry(link: str) -> list[str]:
        out = [link]
        while link in by_child:
            link = by_child[link].parent
            out.append(link)
        return out

    lines = [ancestry(t) for t in tips]
    common = next(link for link in lines[0] if all(link in line for line in lines[1:]))
    below = [sum(arm(by_child[link]) for link in line[:line.index(common)]) for line in lines]
    return common if max(below) <= HAND_BRANCH or len(tips) >= 3 else None  # no robot has three equal arms


def _limits(j: UrdfJoint) -> tuple[float, float]:
    if j.type == "continuous" or j.lower is None or j.upper is None or j.lower >= j.upper:
        return -math.pi, math.pi
    return j.lower, j.upper


def _velocity(j: UrdfJoint) -> float:
    return j.velocity if j.velocity else 1.0


def _pybullet_indices(path: Path) -> tuple[dict[str, int], dict[str, int]]:
    """(joint name -> index, link name -> index) as pybullet numbers them (base link: -1)."""
    import pybullet as pb
    import pybullet_data

    client = pb.connect(pb.DIRECT)
    try:
        pb.setAdditionalSearchPath(pybullet_data.getDataPath(), physicsClientId=client)
        try:
            body = pb.loadURDF(str(path), useFixedBase=True, physicsClientId=client)
        except pb.error as exc:
            raise RobotError(f"{path}: pybullet cannot load it ({exc})") from None
        joints, links = {}, {pb.getBodyInfo(body, physicsClientId=client)[0].decode(): -1}
        for i in range(pb.getNumJoints(body, physicsClientId=client)):
            info = pb.getJointInfo(body, i, physicsClientId=client)
            joints[info[1].decode()] = i
            links[info[12].decode()] = i
        return joints, links
    finally:
        pb.disconnect(client)
