"""The one `Robot`: a URDF, its main joints, its end effector and how passive joints follow.

Everything in tdgen (kinematics, IK, sampling, workspace, TD) takes a `Robot` instead of
reloading the URDF itself, so joint order, limits and units are decided here once.

Choices a user should know about:
- Units are SI inside (rad, m); `info()` and `to_user_units` give deg for revolute/continuous
  joints and mm for prismatic joints, as the TD does.
- Continuous joints get the limits -pi..pi (one full turn, every orientation once).
- Main joints are the actuated joints on the chain from the root link to the end effector,
  minus URDF <mimic> joints and the joints named passive. Branches off that chain (a Panda's
  finger joints, for instance) are not main joints and stay at 0.
- The automatic end effector follows the chain with the most movable joints and stops where it
  splits into several equally long movable branches (a gripper's fingers); from there it follows
  a single fixed child if there is exactly one (the Panda's `panda_grasptarget`, a UR's
  `ee_link`). Pass `ee=` to choose another link.
- The end-effector position is the origin of the URDF link frame (pybullet's
  `worldLinkFramePosition`), not the link's centre of mass.
"""
from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

ROBOTS_DIR = Path(__file__).parent / "models"  # the shipped URDFs
MOVABLE = ("revolute", "prismatic", "continuous")


class RobotError(Exception):
    """A URDF that cannot be used; the message names the file and the problem."""


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

    @classmethod
    def load(cls, urdf: str | Path, ee: str | None = None, passive_joints: Sequence[str] = (),
             passive: PassiveMap | None = None) -> "Robot":
        """Read the URDF (xml for structure, a private pybullet client for joint indices)."""
        path = resolve_urdf(urdf)
        name, root, ujoints = _parse_urdf(path)
        by_child = {j.child: j for j in ujoints.values()}
        links = {root} | set(by_child)
        if ee is None:
            ee = _auto_ee(root, ujoints)
        elif ee not in links:
            raise RobotError(f"{path}: no link named {ee!r} (links: {', '.join(sorted(links))})")
        chain = _path_to(ee, by_child)
        passive_names = list(passive_joints)
        unknown = [n for n in passive_names if n not in ujoints or ujoints[n].type not in MOVABLE]
        if unknown:
            raise RobotError(f"{path}: passive joints {unknown} are not movable joints of the URDF")
        if passive_names and passive is None:
            raise RobotError(f"{path}: passive joints {passive_names} need a passive map")
        main = [j for j in chain if j.type in MOVABLE and j.mimic is None and j.name not in passive_names]
        if not main:
            raise RobotError(f"{path}: no actuated joint between the root link {root!r} and {ee!r}")
        indices, link_indices = _pybullet_indices(path)
        joints = [Joint(j.name, j.type, indices[j.name], *_limits(j), _velocity(j)) for j in main]
        return cls(path, name, joints, passive_names, ee, link_indices[ee], passive, ujoints, indices)

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
        }

    # --- joint values -----------------------------------------------------------------------
    def chain(self) -> list[UrdfJoint]:
        """The URDF joints (fixed ones included) from the root link to the end effector."""
        return _path_to(self.ee_link, {j.child: j for j in self._urdf_joints.values()})

    def drives(self) -> dict[str, Drive]:
        """How every main, passive and mimic joint of the URDF gets its value."""
        main = {j.name: k for k, j in enumerate(self.joints)}
        passive = {n: k for k, n in enumerate(self.passive_names)}

        def drive(name: str, depth: int = 0) -> Drive:
            if name in main:
                return Drive("main", main[name])
            if name in passive:
                return Drive("passive", passive[name])
            uj = self._urdf_joints.get(name)
            if uj is None or uj.mimic is None or depth > len(self._urdf_joints):
                return Drive("const", -1, 0.0, 0.0)
            src = drive(uj.mimic[0], depth + 1)
            m, off = uj.mimic[1], uj.mimic[2]
            return Drive(src.kind, src.index, m * src.multiplier, m * src.offset + off)

        mimics = [n for n, j in self._urdf_joints.items() if j.mimic and n not in main and n not in passive]
        return {n: drive(n) for n in [*main, *passive, *mimics]}

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
    def load_into(self, client: int, base_position=(0, 0, 0), base_yaw: float = 0.0, flags: int = 0) -> int:
        """Load the robot with a fixed base into pybullet client `client`; returns the body id."""
        import pybullet as pb

        orn = pb.getQuaternionFromEuler([0.0, 0.0, base_yaw])
        try:
            body = pb.loadURDF(str(self.urdf_path), list(base_position), orn, useFixedBase=True,
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


def _floats(text: str | None, default: tuple[float, float, float]) -> tuple[float, float, float]:
    """Three numbers of a URDF attribute (xyz, rpy, axis)."""
    if not text:
        return default
    x, y, z = (float(v) for v in text.split())
    return x, y, z


def _child(el: ET.Element, tag: str) -> ET.Element:
    found = el.find(tag)
    if found is None:
        raise KeyError(f"no <{tag}>")
    return found


def _parse_urdf(path: Path) -> tuple[str, str, dict[str, UrdfJoint]]:
    """(robot name, root link, joints by name) straight from the XML."""
    try:
        root_el = ET.parse(path).getroot()
    except ET.ParseError as exc:
        raise RobotError(f"{path}: broken XML ({exc})") from None
    if root_el.tag != "robot":
        raise RobotError(f"{path}: not a URDF (root element <{root_el.tag}>, expected <robot>)")
    joints: dict[str, UrdfJoint] = {}
    try:
        for el in root_el.findall("joint"):
            origin, axis, limit, mimic = (el.find(t) for t in ("origin", "axis", "limit", "mimic"))
            lim = limit.attrib if limit is not None else {}
            joints[el.attrib["name"]] = UrdfJoint(
                name=el.attrib["name"], type=el.attrib["type"],
                parent=_child(el, "parent").attrib["link"], child=_child(el, "child").attrib["link"],
                xyz=_floats(origin.get("xyz") if origin is not None else None, (0.0, 0.0, 0.0)),
                rpy=_floats(origin.get("rpy") if origin is not None else None, (0.0, 0.0, 0.0)),
                axis=_floats(axis.get("xyz") if axis is not None else None, (1.0, 0.0, 0.0)),
                lower=float(lim["lower"]) if "lower" in lim else None,
                upper=float(lim["upper"]) if "upper" in lim else None,
                velocity=float(lim["velocity"]) if "velocity" in lim else None,
                mimic=(mimic.attrib["joint"], float(mimic.get("multiplier", 1)), float(mimic.get("offset", 0)))
                if mimic is not None else None)
    except (KeyError, AttributeError, ValueError) as exc:
        raise RobotError(f"{path}: malformed <joint> ({type(exc).__name__}: {exc})") from None
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


def _auto_ee(root: str, joints: dict[str, UrdfJoint]) -> str:
    """Last link of the longest movable chain; a split into equal branches (fingers) ends it."""
    children: dict[str, list[UrdfJoint]] = {}
    for j in joints.values():
        children.setdefault(j.parent, []).append(j)

    def depth(link: str) -> int:  # most movable joints (mimic ones count) on any path below `link`
        return max((int(j.type in MOVABLE) + depth(j.child) for j in children.get(link, [])), default=0)

    link = root
    while True:
        scored = [(int(j.type in MOVABLE) + depth(j.child), j) for j in children.get(link, [])]
        best = max((s for s, _ in scored), default=0)
        leaders = [j for s, j in scored if s == best]
        if best == 0 or len(leaders) > 1:
            break
        link = leaders[0].child
    while True:
        fixed = [j for j in children.get(link, []) if j.type == "fixed" and depth(j.child) == 0]
        if len(fixed) != 1:
            return link
        link = fixed[0].child


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
