"""Scenes: the static surroundings a robot stands in, as a small JSON file format.

A scene names where the robot stands and the static bodies around it; tdgen loads it with the
robot so that sampled configurations that hit the surroundings count as colliding. Units are SI:
metres for positions and sizes, degrees for angles (`yaw`, `rpy`). Example::

    {
      "name": "table-and-wall",
      "description": "A robot on a table, a wall beside it.",
      "robot": {"position": [0, 0, 0.625], "yaw": 0},
      "bodies": [
        {"type": "urdf", "name": "table", "urdf": "pybullet_data:table/table.urdf"},
        {"type": "box", "name": "wall", "size": [2.0, 0.1, 1.6], "position": [0, 0.6, 0.8]},
        {"type": "cylinder", "name": "bin", "radius": 0.1, "length": 0.3,
         "position": [0.5, -0.3, 0.775], "rpy": [0, 0, 0], "rgba": [0.2, 0.4, 0.8, 1]}
      ]
    }

- `robot`: the robot's base position in the world and its orientation: `yaw` about the world z
  axis, and for an arm mounted on a wall or a ceiling `roll` and `pitch` (fixed-axis, degrees, as
  `rpy`; `"roll": 180` hangs it from the ceiling).
- `bodies[].type`: `"urdf"` (a URDF file: a path relative to the scene file, an absolute path, or
  `pybullet_data:<path>` for pybullet's bundled models; optional `scale`), `"box"` (`size`: full
  extents x, y, z), `"cylinder"` (`radius`, `length` along the body's z axis), `"mesh"` (`file`: a
  CAD mesh, STL, OBJ, PLY or glTF, relative to the scene file; optional `scale`; a closed mesh is
  split into convex parts, an open one stays a surface) or `"points"` (`file`: a scan, PCD, PLY or
  XYZ text, in the sensor's frame, `position`/`rpy` being the sensor's pose; `voxel`, m, the
  resolution of the boxes standing for it; `scale`). See `tdgen.robot.scan_bodies`.
- Every body has an optional `name`, `position` (its origin; for boxes and cylinders the centre)
  and `rpy` (fixed-axis roll, pitch, yaw in degrees); boxes and cylinders an optional `rgba`.
- Every body is static (fixed base, mass 0): scenes describe surroundings, not things that move.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Union

import msgspec

from mesh.messages.scene_description import SceneDescription
from tdgen.robot.errors import SceneError as SceneError  # raised here; tdgen.robot.errors holds it

SCENES_DIR = Path(__file__).parent / "scenes"
PYBULLET_DATA = "pybullet_data:"
Vec3 = tuple[float, float, float]


class RobotPlacement(msgspec.Struct, forbid_unknown_fields=True):
    position: Vec3 = (0.0, 0.0, 0.0)
    yaw: float = 0.0    # degrees about the world z axis
    roll: float = 0.0   # degrees, fixed axes x then y then z (a wall mount: roll or pitch 90)
    pitch: float = 0.0

    @property
    def rpy(self) -> Vec3:
        return (self.roll, self.pitch, self.yaw)

    def quaternion(self) -> tuple[float, float, float, float]:
        """(x, y, z, w), as pybullet takes it."""
        from scipy.spatial.transform import Rotation

        x, y, z, w = Rotation.from_euler("xyz", self.rpy, degrees=True).as_quat()
        return float(x), float(y), float(z), float(w)

    @classmethod
    def from_quaternion(cls, position: Vec3, q: tuple[float, float, float, float]) -> "RobotPlacement":
        from scipy.spatial.transform import Rotation

        roll, pitch, yaw = Rotation.from_quat(q).as_euler("xyz", degrees=True)
        return cls(position=tuple(float(v) for v in position), roll=_tidy(roll), pitch=_tidy(pitch),  # type: ignore[arg-type]
                   yaw=_tidy(yaw))


def _tidy(deg: float) -> float:
    """An angle without float dust: -0.0 and 1e-14 are 0."""
    value = round(float(deg), 9)
    return 0.0 if value == 0 else value


class _Body(msgspec.Struct, forbid_unknown_fields=True, omit_defaults=True, tag_field="type", kw_only=True):
    name: str = ""
    position: Vec3 = (0.0, 0.0, 0.0)
    rpy: Vec3 = (0.0, 0.0, 0.0)  # degrees


class UrdfBody(_Body, tag="urdf"):
    urdf: str
    scale: float = 1.0


class BoxBody(_Body, tag="box"):
    size: Vec3  # full extents, m
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)


class CylinderBody(_Body, tag="cylinder"):
    radius: float
    length: float
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)


class MeshBody(_Body, tag="mesh"):
    file: str  # STL, OBJ, PLY, glTF/GLB, OFF, DAE; relative to the scene file
    scale: float = 1.0
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)


class PointsBody(_Body, tag="points"):
    """A scan in the sensor's frame; `position`/`rpy` are the sensor's pose."""

    file: str  # PCD, PLY, XYZ text, LAS/LAZ, E57; relative to the scene file
    voxel: float = 0.02  # m, the resolution of the boxes that stand for the points
    scale: float = 1.0  # 0.001 for a scan in millimetres
    rgba: tuple[float, float, float, float] = (0.5, 0.6, 0.7, 1.0)


Body = Union[UrdfBody, BoxBody, CylinderBody, MeshBody, PointsBody]
FileBody = (MeshBody, PointsBody)


class Surroundings(msgspec.Struct, forbid_unknown_fields=True):
    name: str
    description: str = ""
    robot: RobotPlacement = msgspec.field(default_factory=RobotPlacement)
    bodies: list[Body] = []


def empty_scene() -> Surroundings:
    """The robot alone at the world origin: only self-collision counts."""
    return Surroundings(name="empty", description="The robot alone; only self-collision is checked.")


MOUNT_SIZE, MOUNT_THICKNESS = 4.0, 0.02  # m
MOUNT_MARGIN = 0.25  # m beyond the arm's reach (links are wider than their joint-to-joint lines)


def mount_size(reach: float | None) -> float:
    """The mounting slab's side (m): 4 m, or wider for an arm that reaches farther, so that its edge is
    beyond anything the arm can reach (a point under the floor past the slab's edge was counted free)."""
    return MOUNT_SIZE if reach is None else max(MOUNT_SIZE, 2.0 * (reach + MOUNT_MARGIN))


def default_scene(robot: RobotPlacement | None = None, surface: bool = True, reach: float | None = None
                  ) -> Surroundings:
    """The robot where it is placed, on the surface it is mounted on (a floor for an upright arm, the
    wall or the ceiling for a tilted one: a slab through the base, across the base's z axis, as wide as
    `mount_size(reach)`), unless `surface` is False (the robot alone)."""
    robot = robot or RobotPlacement()
    size = mount_size(reach)
    if not surface:
        return msgspec.structs.replace(empty_scene(), robot=robot)
    from scipy.spatial.transform import Rotation

    down = Rotation.from_euler("xyz", robot.rpy, degrees=True).apply([0.0, 0.0, -MOUNT_THICKNESS / 2 - 0.001])
    centre = tuple(float(p + d) for p, d in zip(robot.position, down))
    slab = BoxBody(name="mounting-surface", size=(size, size, MOUNT_THICKNESS), position=centre,  # type: ignore[arg-type]
                   rpy=robot.rpy, rgba=(0.55, 0.55, 0.55, 1.0))
    return Surroundings(name="mounted", robot=robot, bodies=[slab],
                 description=f"The robot on the surface it is mounted on (a {size:g} m slab through its base, across "
                             "its z axis: the floor for an upright arm, wider than the arm reaches); self-collision and "
                             "that surface are checked.")


def scene_file(name_or_path: str | Path) -> Path:
    """A scene file as given, or a shipped scene by name (`table-and-wall`)."""
    given = Path(name_or_path).expanduser()
    for candidate in (given, SCENES_DIR / given, SCENES_DIR / f"{given}.json"):
        if candidate.is_file():
            return candidate.resolve()
    shipped = ", ".join(sorted(p.stem for p in SCENES_DIR.glob("*.json")))
    raise SceneError(f"{name_or_path}: scene file not found (shipped scenes: {shipped})")


def load_scene(name_or_path: str | Path, robot: str | None = None) -> Surroundings:
    """Read and check a scene file; file URDF paths come back absolute so the scene is self-contained.

    A world Thing's `scene.json` (mesh.messages.scene_description.SceneDescription: `robots` and `bodies`
    with a `shape`) is read too: its static bodies, with robot `robot` standing where that scene puts
    it (`from_world_scene`).
    """
    path = scene_file(name_or_path)
    try:
        raw = msgspec.json.decode(path.read_bytes())
    except msgspec.DecodeError as exc:
        raise SceneError(f"{path}: not a valid scene ({exc})") from None
    if isinstance(raw, dict) and ("robots" in raw or any(isinstance(b, dict) and "shape" in b
                                                         for b in raw.get("bodies", []))):
        try:
            description = msgspec.convert(raw, SceneDescription)
        except msgspec.ValidationError as exc:
            raise SceneError(f"{path}: not a valid world scene ({exc})") from None
        return from_world_scene(description, robot, str(path))
    if robot is not None:
        raise SceneError(f"{path}: a tdgen scene places one robot; --scene-robot is for a world's scene.json")
    try:
        scene = msgspec.convert(raw, Surroundings)
    except msgspec.ValidationError as exc:
        raise SceneError(f"{path}: not a valid scene ({exc})") from None
    bodies = []
    for k, body in enumerate(scene.bodies):
        _check_body(path, k, body)
        if isinstance(body, UrdfBody) and not body.urdf.startswith(PYBULLET_DATA):
            body = msgspec.structs.replace(body, urdf=str((path.parent / body.urdf).resolve()))
        if isinstance(body, FileBody):
            body = msgspec.structs.replace(body, file=str((path.parent / body.file).resolve()))
            prepare(body)  # read now: a bad file stops the scene here, before anything starts
        bodies.append(body)
    return msgspec.structs.replace(scene, bodies=bodies)


def from_world_scene(description: SceneDescription, robot: str | None, source: str = "scene") -> Surroundings:
    """A world Thing's scene as tdgen surroundings: its static bodies (virtual ones such as a safety
    wall included), with robot `robot` (the only one, if None) standing where the world puts it.
    Moving bodies (cubes) and the scene's other robots are left out: they are not surroundings."""
    from scipy.spatial.transform import Rotation

    names = [r.name for r in description.robots]
    if robot is None and len(names) != 1:
        raise SceneError(f"{source}: the scene has {'robots ' + ', '.join(names) if names else 'no robot'}: say "
                         "which one stands in it (--scene-robot NAME)")
    model = next((r for r in description.robots if r.name == (robot or names[0])), None)
    if model is None:
        raise SceneError(f"{source}: no robot {robot!r} in the scene (robots: {', '.join(names) or 'none'})")
    bodies: list[Body] = []
    for b in description.bodies:
        if b.moving:
            continue
        rpy = tuple(float(a) for a in Rotation.from_quat(b.pose.q).as_euler("xyz", degrees=True))
        common = {"name": b.name, "position": tuple(b.pose.p), "rpy": rpy, "rgba": (*b.color, b.opacity)}
        if b.shape in ("mesh", "points"):  # its file, as the world serves it: beside the scene file
            file = str((Path(source).parent / (b.file or "")).resolve())
            extra = {"voxel": b.voxel} if b.shape == "points" and b.voxel else {}
            made = (MeshBody if b.shape == "mesh" else PointsBody)(file=file, scale=b.scale, **extra, **common)  # type: ignore[arg-type]
            prepare(made)  # read now: a bad file stops the scene here
            bodies.append(made)
        elif b.shape == "cylinder":
            bodies.append(CylinderBody(radius=b.size[0], length=b.size[1], **common))  # type: ignore[arg-type]
        else:  # boxes, and a sphere as the box around it
            size = tuple(b.size) if b.shape == "box" else (2 * b.size[0],) * 3
            bodies.append(BoxBody(size=size, **common))  # type: ignore[arg-type]
    placement = RobotPlacement.from_quaternion(tuple(model.base.p), tuple(model.base.q))  # type: ignore[arg-type]
    return Surroundings(name=f"{description.name}:{model.name}", robot=placement, bodies=bodies,
                 description=f"The static bodies of {description.name} ({source}), {model.name} standing where it "
                             "does there.")


def _check_body(path: Path, k: int, body: Body) -> None:
    where = f"{path}: body {k}{f' ({body.name})' if body.name else ''}"
    if isinstance(body, BoxBody) and min(body.size) <= 0:
        raise SceneError(f"{where}: box size must be positive, got {list(body.size)}")
    if isinstance(body, CylinderBody) and (body.radius <= 0 or body.length <= 0):
        raise SceneError(f"{where}: cylinder radius and length must be positive")
    if isinstance(body, UrdfBody):
        if body.scale <= 0:
            raise SceneError(f"{where}: scale must be positive")
        if not urdf_path(body.urdf, path.parent).is_file():
            raise SceneError(f"{where}: URDF {body.urdf!r} not found")
    if isinstance(body, FileBody) and body.scale <= 0:
        raise SceneError(f"{where}: scale must be positive")
    if isinstance(body, PointsBody) and not 0.001 <= body.voxel <= 0.5:
        raise SceneError(f"{where}: voxel must be between 0.001 and 0.5 m, got {body.voxel:g}")


def urdf_path(urdf: str, base_dir: Path) -> Path:
    """Where a body's URDF lives: `pybullet_data:` paths in pybullet's data, others from `base_dir`."""
    if urdf.startswith(PYBULLET_DATA):
        import pybullet_data

        return Path(pybullet_data.getDataPath()) / urdf[len(PYBULLET_DATA):]
    return base_dir / urdf


def encode_scene(scene: Surroundings) -> bytes:
    """The scene as JSON, one body per line (what tdgen writes beside the TD; diff-friendly)."""
    enc = msgspec.json.encode
    head = [b'  "%s": %s' % (k.encode(), enc(getattr(scene, k))) for k in ("name", "description", "robot")]
    bodies = b",\n".join(b"    " + enc(body) for body in scene.bodies)
    return b"{\n" + b",\n".join(head) + b',\n  "bodies": [\n' + bodies + b"\n  ]\n}\n"


def build_into(scene: Surroundings, client: int) -> list[int]:
    """Create the scene's static bodies in pybullet client `client`; returns their body ids."""
    import pybullet as pb

    ids = []
    for body in scene.bodies:
        orn = pb.getQuaternionFromEuler([math.radians(a) for a in body.rpy])
        if isinstance(body, UrdfBody):
            path = urdf_path(body.urdf, Path.cwd())
            try:
                ids.append(pb.loadURDF(str(path), list(body.position), orn, useFixedBase=True,
                                       globalScaling=body.scale, physicsClientId=client))
            except pb.error as exc:
                raise SceneError(f"scene {scene.name}: pybullet cannot load {body.urdf} ({exc})") from None
            continue
        if isinstance(body, FileBody):
            from tdgen.robot.scan_bodies import build

            made = prepare(body)
            at, turn = (((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.0)) if made.kind == "voxels"  # already in the scene frame
                        else (body.position, orn))
            ids.append(build(made, at, turn, client))
            continue
        if isinstance(body, BoxBody):
            half = [s / 2 for s in body.size]
            col = pb.createCollisionShape(pb.GEOM_BOX, halfExtents=half, physicsClientId=client)
            vis = pb.createVisualShape(pb.GEOM_BOX, halfExtents=half, rgbaColor=body.rgba, physicsClientId=client)
        else:
            col = pb.createCollisionShape(pb.GEOM_CYLINDER, radius=body.radius, height=body.length,
                                          physicsClientId=client)
            vis = pb.createVisualShape(pb.GEOM_CYLINDER, radius=body.radius, length=body.length,
                                       rgbaColor=body.rgba, physicsClientId=client)
        ids.append(pb.createMultiBody(0.0, col, vis, list(body.position), orn, physicsClientId=client))
    if any(isinstance(b, FileBody) for b in scene.bodies):
        _quiet_static_pairs(client, ids)
    return ids


def _quiet_static_pairs(client: int, new: list[int]) -> None:
    """No contacts computed between two static bodies (one of them new) whose boxes overlap: a scan's
    triangles against the table it was scanned with cost every collision check milliseconds, and
    nothing asks for those contacts (bodies that move, robots and cubes, are left alone)."""
    import pybullet as pb

    def static(b: int) -> bool:
        return (pb.getDynamicsInfo(b, -1, physicsClientId=client)[0] == 0
                and all(pb.getJointInfo(b, j, physicsClientId=client)[2] == pb.JOINT_FIXED
                        for j in range(pb.getNumJoints(b, physicsClientId=client))))

    bodies = [pb.getBodyUniqueId(k, physicsClientId=client) for k in range(pb.getNumBodies(physicsClientId=client))]
    boxes = {b: [(link, *pb.getAABB(b, link, physicsClientId=client))
                 for link in range(-1, pb.getNumJoints(b, physicsClientId=client))] for b in bodies if static(b)}
    fresh = set(new)
    for a in boxes:
        for b in boxes:
            if a >= b or (a not in fresh and b not in fresh):
                continue
            for la, lo_a, hi_a in boxes[a]:
                for lb, lo_b, hi_b in boxes[b]:
                    if all(lo_a[k] <= hi_b[k] and lo_b[k] <= hi_a[k] for k in range(3)):
                        pb.setCollisionFilterPair(a, b, la, lb, 0, physicsClientId=client)


def content_key(body: Body) -> bytes:
    """What a body is as collision geometry: its description and, for a scan or mesh, its file's content (a
    newer scan written under the same name is another body), for what is kept per body between scene changes."""
    if isinstance(body, FileBody) and Path(body.file).is_file():
        from tdgen.robot.scan_io import content_digest  # the file hashed (or its hash kept), nothing read or built

        return msgspec.json.encode(body) + content_digest(Path(body.file)).encode()
    if isinstance(body, FileBody):
        return msgspec.json.encode(body) + prepare(body).key.encode()  # raises the scene error naming the file
    return msgspec.json.encode(body)


def prepare(body: "MeshBody | PointsBody"):
    """A mesh or scan body read and made into collision pieces (`scan_bodies.Prepared`), cached."""
    from tdgen.robot.scan_bodies import prepare_mesh, prepare_points

    path = Path(body.file)
    if isinstance(body, PointsBody):
        return prepare_points(path, body.voxel, body.scale, body.position, body.rpy)
    return prepare_mesh(path, body.scale)


def cluttered_lab(shelves: int = 2, levels: int = 4, items_per_level: int = 8) -> Surroundings:
    """A robot on a table between shelves full of boxes and tins: many static bodies, for benchmarks.

    The default has 2 + shelves * (2 + levels * (1 + items_per_level)) = 78 bodies, all within a
    UR10's reach, so the broad phase has real work to do.
    """
    bodies: list[Body] = [
        UrdfBody(name="floor", urdf=f"{PYBULLET_DATA}plane.urdf"),
        BoxBody(name="table", size=(1.2, 0.8, 0.05), position=(0.0, 0.0, 0.725), rgba=(0.6, 0.45, 0.3, 1.0)),
    ]
    for s in range(shelves):
        yaw = 90.0 * s
        c, sn = math.cos(math.radians(yaw)), math.sin(math.radians(yaw))

        def at(x: float, y: float, z: float) -> Vec3:  # shelf frame -> world: shelves stand at x = 0.9
            return (round(c * x - sn * y, 4), round(sn * x + c * y, 4), round(z, 4))

        for side in (-1, 1):
            bodies.append(BoxBody(name=f"shelf{s}-side{side:+d}", size=(0.4, 0.03, 1.8),
                                  position=at(0.9, side * 0.6, 0.9), rpy=(0.0, 0.0, yaw)))
        for lvl in range(levels):
            z = 0.5 + 0.35 * lvl
            bodies.append(BoxBody(name=f"shelf{s}-board{lvl}", size=(0.4, 1.2, 0.02),
                                  position=at(0.9, 0.0, z), rpy=(0.0, 0.0, yaw)))
            for i in range(items_per_level):
                y = -0.5 + i * (1.0 / max(items_per_level - 1, 1))
                name = f"shelf{s}-item{lvl}-{i}"
                if i % 2:
                    bodies.append(CylinderBody(name=name, radius=0.04, length=0.12, position=at(0.85, y, z + 0.07),
                                               rgba=(0.8, 0.3, 0.2, 1.0)))
                else:
                    bodies.append(BoxBody(name=name, size=(0.1, 0.08, 0.15), position=at(0.85, y, z + 0.085),
                                          rpy=(0.0, 0.0, yaw), rgba=(0.3, 0.5, 0.8, 1.0)))
    return Surroundings(name="cluttered-lab", robot=RobotPlacement(position=(0.0, 0.0, 0.75)), bodies=bodies,
                 description=f"A robot on a table between {shelves} shelves of boxes and tins "
                             f"({len(bodies)} static bodies); the benchmark scene.")
