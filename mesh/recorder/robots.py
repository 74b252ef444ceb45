"""Robot Things in a Rerun recording: each drawn from its URDF, animated, with its workspace (SPEC §6).

A robot Thing (`mesh.messages.scene_description.TwinDescription`) links `twin.json` (`relations.TWIN`: its base pose
in the scene frame, its frame and calibration) and its URDF (`rel: "describedby"`); once its workspace is
generated, also the sampled points (`relations.POINTS`, CSV `x,y,z,collision,<joints>`) and the
hull (`relations.WORKSPACE`, STL), both in mm in the robot's base frame. The recorder's fetcher thread
fetches and parses them (`RobotFiles`, `DrawnWorkspace.from_files`); `RobotDrawer`, owned by the writer
thread, draws them into the RecordingStream.

Entities of robot Thing `r`, simulated in its own world (a process of its own, with its own scene:
never drawn in a room whose simulation it is not part of). `robots/<r>` is that world's root: its
frame `tf#/robots/<r>` is the robot's scene frame, and its links are the frames `robots/<r>/<link>`
(a frame name belongs to one entity: the world's robots are `<r>/<link>`):
- `robots/<r>/model/...`: the URDF's geometry and zero-pose joints, `robots/<r>/model/base` its base
  in its scene frame (static; drawn again when twin.json or the URDF change), and
  `robots/<r>/model/joints` the joints' transforms over time (one row per joint that moved, naming its
  frame: `mesh.recorder.joint_rows`);
- `robots/<r>/scene/<b>`: the bodies of its scene (twin.json's `scene`: boxes, cylinders, URDFs found
  on this machine, and from the files the Thing serves (`scene_files`) a scan as points and a CAD mesh
  as a mesh, `mesh.recorder.scene_assets`), static, placed by the body's pose, those a new twin.json
  drops cleared;
- `robots/<r>/joints`: the joints' values as time series in rad or m, one series per joint (the Thing
  reports deg and mm, as its TD's `unit`s say), batched like the world's poses, a value that did not
  move not logged again; `getJointposition` is not also logged as a plain property;
- `robots/<r>/workspace/points/free` (green) and `.../points/colliding` (red): the sampled
  end-effector positions; `robots/<r>/workspace/hull`: the hull, semi-transparent; all three in the
  robot's base frame (m). Static, one log call each: a regenerated workspace replaces the previous
  one for the whole recording (a TD that no longer links one leaves the last one drawn), and a line
  in `robots/<r>/log` says when each was drawn. One subtree per robot, so it is one eye toggle.
A robot Thing whose name is also a robot of the `world` Thing's scene is drawn once: the world draws
and animates it (its poses are the simulation's state), the Thing adds its joint series and its
workspace, placed in the world robot's base frame. The recorder asks the world first; should a robot
Thing still be drawn before, its own world is cleared when the world takes the robot over, and drawn
again if the world's scene drops it.
"""
from __future__ import annotations

import hashlib
import io
import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import msgspec
import numpy as np
import rerun as rr

from mesh.messages import relations
from mesh.messages.scene_description import MODEL_REL, TWIN_FILE, TWIN_REL, Body, Pose, TwinDescription
from mesh.recorder.joint_rows import JointRows, send_values
from mesh.recorder.mapping import Entry
from mesh.recorder.scene_assets import Asset, asset_archetype, read_asset
from mesh.recorder.scene_drawer import (
    BATCH_AGE,
    BATCH_ROWS,
    ROBOTS,
    DrawnRobot,
    SceneDrawer,
    body_shape,
    thing_robot_path,
)
from mesh.wot import units
from mesh.wot.problem import Problem
from mesh.wot.thing_description import ThingDescription

JOINTS_PROPERTY = "getJointposition"
POINTS_REL = relations.POINTS
WORKSPACE_REL = relations.WORKSPACE
FREE_COLOUR = (40, 180, 70)
COLLIDING_COLOUR = (220, 50, 40)
HULL_COLOUR = (70, 140, 230, 60)  # RGBA: the alpha makes it see-through
PATH_COLOUR = (250, 170, 20)
PATH_RADIUS = 0.004  # m
POINT_RADIUS = rr.Radius.ui_points(1.5)  # on screen, whatever the zoom
_UNITS = {"deg": (math.pi / 180, "rad"), "degree": (math.pi / 180, "rad"), "degrees": (math.pi / 180, "rad"),
          "rad": (1.0, "rad"), "radian": (1.0, "rad"), "radians": (1.0, "rad"),
          "mm": (1e-3, "m"), "millimetre": (1e-3, "m"), "millimeter": (1e-3, "m"), "m": (1.0, "m")}
_UNITS.update({unit.lower(): _UNITS[units.symbol(unit)] for unit in (units.DEGREE, units.MILLIMETRE, units.METRE)})
_REVOLUTE, _PRISMATIC = _UNITS["deg"], _UNITS["mm"]  # SPEC §4's units when a TD does not say


# --- what a robot Thing's TD and files say ---------------------------------------------------------
def urdf_dir(twin: TwinDescription) -> Path | None:
    """The folder of a twin's URDF on this machine, where its meshes are looked for: the one its Thing
    names (`urdf_dir` of twin.json), else its `urdf` as a path or a pybullet_data path; None if not here."""
    import pybullet_data

    if twin.urdf_dir and Path(twin.urdf_dir).is_dir():
        return Path(twin.urdf_dir)
    for path in (Path(twin.urdf), Path(pybullet_data.getDataPath()) / twin.urdf):
        if path.is_file():
            return path.resolve().parent
    return None


def link_file(td: ThingDescription, rel: str) -> str | None:
    """The file name a TD link points at (`files/points.csv`, `zenoh:.../files/points.csv`, a URL)."""
    for link in td.links:
        if link.rel == rel:
            name = link.href.split("#")[0].split("?")[0].rstrip("/").rsplit("/", 1)[-1]
            return name or None
    return None


def is_robot(td: ThingDescription) -> bool:
    return link_file(td, TWIN_REL) is not None


def joint_units(td: ThingDescription) -> dict[str, tuple[float, str]]:
    """Joint -> (factor to rad or m, that unit), from the `unit`s of the TD's `getJointposition`."""
    prop = td.properties.get(JOINTS_PROPERTY)
    fields = (prop.properties or {}) if prop is not None else {}
    return {j: _UNITS[s.unit.lower()] for j, s in fields.items() if s.unit and s.unit.lower() in _UNITS}


@dataclass(frozen=True)
class RobotFiles:
    """What the recorder fetched from a robot Thing to draw it: its twin.json, URDF text and the files of
    its scene's mesh and points bodies (by body label; a line saying why where one cannot be drawn)."""

    thing: str
    twin: TwinDescription
    urdf: str
    assets: dict[str, Asset | str] = field(default_factory=dict)


@dataclass
class DrawnWorkspace:
    """A robot's sampled points and hull, in m in its base frame (twin frame)."""

    thing: str
    points: np.ndarray  # (N, 3) float32
    colliding: np.ndarray  # (N,) bool
    vertices: np.ndarray  # (V, 3) float32
    triangles: np.ndarray  # (F, 3) uint32
    normals: np.ndarray  # (V, 3) float32

    @classmethod
    def from_files(cls, thing: str, csv: bytes, stl: bytes, twin: TwinDescription) -> "DrawnWorkspace":
        xyz, colliding = read_points(csv)
        vertices, triangles, normals = read_hull(stl)
        if twin.frame == "real":  # the TD's files are in the real robot's frame: back to the twin's
            xyz, vertices = to_twin_frame(xyz, twin), to_twin_frame(vertices, twin)
        return cls(thing, (xyz / 1000).astype(np.float32), colliding, (vertices / 1000).astype(np.float32),
                   triangles.astype(np.uint32), normals.astype(np.float32))


def _tip(call: Any) -> np.ndarray | None:
    """`output.path.tip` of an action call as (N, 3) mm, or None when the call carries none."""
    try:
        tip = np.asarray(call["output"]["path"]["tip"], dtype=float)
    except (KeyError, TypeError, ValueError):
        return None
    return tip if tip.ndim == 2 and tip.shape[1] == 3 and len(tip) >= 2 and np.isfinite(tip).all() else None


def read_robot(thing: str, td: ThingDescription, get: Callable[[str], bytes]) -> RobotFiles:
    """A robot Thing's twin.json, URDF and scene files, through `get(file name)` (the recorder's fetcher)."""
    twin = msgspec.json.decode(get(link_file(td, TWIN_REL) or TWIN_FILE), type=TwinDescription)
    urdf = get(link_file(td, MODEL_REL) or twin.urdf_file).decode()
    return RobotFiles(thing, twin, urdf, read_scene_assets(twin, get))


def body_label(i: int, body: Any) -> str:
    """A scene body's entity name: its name, else its place in the scene."""
    return str(body.get("name") or f"body-{i}") if isinstance(body, dict) else f"body-{i}"


def read_scene_assets(twin: TwinDescription, get: Callable[[str], bytes]) -> dict[str, Asset | str]:
    """The files of the twin's mesh and points bodies, fetched by the names its Thing serves them under and
    read for drawing; for a body that cannot be drawn, why."""
    assets: dict[str, Asset | str] = {}
    for i, body in enumerate(twin.scene.get("bodies") or []):
        if not isinstance(body, dict) or body.get("type") not in ("mesh", "points"):
            continue
        label, name = body_label(i, body), twin.scene_files.get(str(body.get("file")))
        if name is None:
            assets[label] = f"its Thing serves no file for {body.get('file')}"
            continue
        try:
            assets[label] = read_asset(body["type"], name, get(name), float(body.get("scale", 1.0)))
        except Problem as e:
            assets[label] = f"cannot fetch {name}: {e}"
        except ValueError as e:
            assets[label] = str(e)
    return assets


class WorkspaceFiles:
    """Reads robots' workspaces through `get(file name)`; the same files twice are read once."""

    def __init__(self):
        self._digests: dict[str, str] = {}  # robot -> digest of what was read last

    def read(self, thing: str, td: ThingDescription, twin: TwinDescription,
             get: Callable[[str], bytes]) -> DrawnWorkspace | None:
        """The workspace the TD links; None when it links none or the files have not changed."""
        points, hull = link_file(td, POINTS_REL), link_file(td, WORKSPACE_REL)
        if points is None or hull is None:
            return None
        csv, stl = get(points), get(hull)
        h = hashlib.sha256()
        for part in (csv, stl, msgspec.json.encode([twin.frame, twin.calibration])):
            h.update(len(part).to_bytes(8, "little") + part)
        if self._digests.get(thing) == h.hexdigest():
            return None
        workspace = DrawnWorkspace.from_files(thing, csv, stl, twin)
        self._digests[thing] = h.hexdigest()
        return workspace


def read_points(csv: bytes) -> tuple[np.ndarray, np.ndarray]:
    """x, y, z (mm) and collision of each row of a points CSV (header `x,y,z,collision,<joints>`)."""
    header, _, body = csv.decode().partition("\n")
    names = [h.strip().lower() for h in header.split(",")]
    missing = [c for c in ("x", "y", "z", "collision") if c not in names]
    if missing:
        raise ValueError(f"the points CSV has no {', '.join(missing)} column (header {header.strip()!r})")
    if not body.strip():
        return np.zeros((0, 3)), np.zeros(0, dtype=bool)
    columns = [names.index(c) for c in ("x", "y", "z", "collision")]
    data = np.loadtxt(io.StringIO(body), delimiter=",", usecols=columns, ndmin=2)
    return data[:, :3], data[:, 3] != 0


def read_hull(stl: bytes) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (mm), triangles and vertex normals of an STL (binary or ASCII), shared vertices merged."""
    import trimesh  # only when a workspace is drawn

    mesh = trimesh.load_mesh(io.BytesIO(stl), file_type="stl")
    if len(mesh.faces) == 0:
        raise ValueError("the workspace STL has no triangles")
    return np.asarray(mesh.vertices), np.asarray(mesh.faces), np.asarray(mesh.vertex_normals)


def to_twin_frame(points: np.ndarray, twin: TwinDescription) -> np.ndarray:
    """Real-frame points (mm) back in the twin's base frame, by a least-squares fit of the twin's
    calibration pairs (affine with 4 pairs off one plane, else per axis); unchanged without pairs."""
    pairs = np.asarray(twin.calibration or [], dtype=float)
    if len(pairs) < 2 or len(points) == 0:
        return points
    real, tw = pairs[:, 3:6], pairs[:, :3]
    design = np.column_stack([real, np.ones(len(real))])
    if len(pairs) >= 4 and np.linalg.matrix_rank(design) == 4:
        m, *_ = np.linalg.lstsq(design, tw, rcond=None)  # (4, 3): twin = [real 1] @ m
        return points @ m[:3] + m[3]
    out = np.array(points, dtype=float)
    for i in range(3):
        if np.ptp(real[:, i]) > 0:
            k, b = np.polyfit(real[:, i], tw[:, i], 1)
            out[:, i] = k * out[:, i] + b
    return out


def own_frame(robot: str) -> str:
    """The scene frame of a robot Thing's own world: the implicit frame of its root entity."""
    return "tf#/" + thing_robot_path(robot)


def own_prefix(robot: str) -> str:
    """Its links' frames are `robots/<r>/<link>`: never the world's `<r>/<link>`, even for one name."""
    return f"{ROBOTS}/{robot}/"


def scene_urdf(ref: str) -> Path:
    """The file of a scene's URDF body: `pybullet_data:<path>` or a path that exists on this machine."""
    import pybullet_data

    if ref.startswith("pybullet_data:"):
        path = Path(pybullet_data.getDataPath()) / ref.removeprefix("pybullet_data:")
    else:
        path = Path(ref)
    if not path.is_file():
        raise ValueError(f"its URDF {ref} is not on this machine")
    return path


def _quaternion(rpy_deg) -> tuple[float, float, float, float]:
    """(x, y, z, w) of fixed-axis roll, pitch, yaw in degrees (the tdgen scene convention)."""
    r, p, y = (math.radians(float(a)) / 2 for a in rpy_deg)
    cr, sr, cp, sp, cy, sy = math.cos(r), math.sin(r), math.cos(p), math.sin(p), math.cos(y), math.sin(y)
    return (sr * cp * cy - cr * sp * sy, cr * sp * cy + sr * cp * sy, cr * cp * sy - sr * sp * cy,
            cr * cp * cy + sr * sp * sy)


# --- drawing -------------------------------------------------------------------------------------
@dataclass
class _RobotThing:
    files: RobotFiles | None = None
    units: dict[str, tuple[float, str]] = field(default_factory=dict)
    robot: DrawnRobot | None = None  # its own drawing; None when the world draws it (or not drawn yet)
    host: str | None = None  # the world's robot of the same name, which draws it
    workspace: DrawnWorkspace | None = None
    frame: str | None = None  # the base frame the workspace was logged in
    scene: set[str] = field(default_factory=set)  # the bodies of its own world drawn now


class RobotDrawer:
    """Draws the robot Things of the lab and their workspaces into `rec` (the writer thread only).

    `scene` is the world's drawer: a robot of its scene is not drawn a second time."""

    def __init__(self, rec, scene: SceneDrawer, batch_rows: int = BATCH_ROWS, batch_age: float = BATCH_AGE):
        self.rec = rec
        self.scene = scene
        self.batch_rows, self.batch_age = batch_rows, batch_age
        self.things: dict[str, _RobotThing] = {}
        self._joints: dict[str, JointRows] = {}  # robot -> its joints (their latest values kept)
        self._styled: dict[str, list[str]] = {}  # joint values entity -> the series names logged
        self._path_frames: dict[str, str] = {}  # robot -> the frame its path entity was placed in
        self._rows = 0
        self._oldest: float | None = None

    def knows(self, thing: str) -> bool:
        return thing in self.things

    def bases(self) -> dict[str, Pose]:
        """The base poses of the robot Things of the lab's world (the blueprint's camera looks at them)."""
        return {name: t.files.twin.base for name, t in self.things.items() if t.files is not None and t.host}

    def own_worlds(self) -> dict[str, Pose]:
        """The robot Things drawn in their own world, with their base poses in it (one tab each)."""
        return {name: t.files.twin.base for name, t in self.things.items() if t.robot is not None and t.files}

    def set_td(self, thing: str, td: ThingDescription) -> None:
        """A robot Thing's TD (again): its joint units."""
        self.things.setdefault(thing, _RobotThing()).units = joint_units(td)

    # --- the model (static) --------------------------------------------------------------------
    def draw_robot(self, files: RobotFiles) -> list[str]:
        """Draw a robot Thing from its URDF at its base (unless the world draws it). Returns problems."""
        t = self.things.setdefault(files.thing, _RobotThing())
        if t.files == files:
            return []
        t.files = files
        return self._place(files.thing, t, redraw=True)

    def world_changed(self) -> list[str]:
        """The world's scene was drawn: hand robots over to it, or take back those it dropped."""
        return [p for name, t in self.things.items() for p in self._place(name, t)]

    def _place(self, name: str, t: _RobotThing, redraw: bool = False) -> list[str]:
        host = name if name in self.scene.robots else None
        problems: list[str] = []
        if host is not None and t.robot is not None:  # the world took it over: its own world goes
            for part in ("model", "scene"):
                self.rec.log(thing_robot_path(name, part), rr.Clear(recursive=True), static=True)
            t.robot, t.scene = None, set()
        elif host is None and t.files is not None and (t.robot is None or redraw):
            try:
                robot = DrawnRobot.load(name, t.files.urdf, thing_robot_path(name, "model"), urdf_dir(t.files.twin),
                                        frame_prefix=own_prefix(name))
            except Exception as e:  # a bad URDF: the joint series and the log still record
                problems.append(f"cannot draw robot {name} from {t.files.twin.urdf_file}: {e}")
            else:
                problems += [f"robot {name}: {m}" for m in robot.missing]
                self.rec.log(thing_robot_path(name), rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
                robot.draw(self.rec, t.files.twin.base, own_frame(name))
                t.robot = robot
                if name in self._joints:  # drawn at its zero pose: the next sample places every joint again
                    self._joints[name].redrawn()
                problems += self._draw_own_scene(name, t)
        t.host = host
        if t.workspace is not None and self._frame(t) != t.frame:  # its base frame is another robot's now
            self._log_frames(name, t)
        return problems

    def _draw_own_scene(self, name: str, t: _RobotThing) -> list[str]:
        """The bodies of a robot's own scene around it (static), those no longer in it cleared."""
        assert t.files is not None
        problems: list[str] = []
        drawn: set[str] = set()
        for i, body in enumerate(t.files.twin.scene.get("bodies") or []):
            label = body_label(i, body)
            try:
                self._draw_scene_body(name, label, body, t.files.assets.get(label))
            except Exception as e:  # one body it cannot draw: said, the rest drawn
                problems.append(f"robot {name}: scene body {label} not drawn ({e})")
            else:
                drawn.add(label)
        for gone in t.scene - drawn:
            self.rec.log(thing_robot_path(name, "scene", gone), rr.Clear(recursive=True), static=True)
        t.scene = drawn
        return problems

    def _draw_scene_body(self, robot: str, label: str, body: dict, asset: Asset | str | None = None) -> None:
        """A tdgen scene body (box, cylinder, URDF, or a mesh or points body from its file, `asset`; position m,
        rpy deg) in the robot's own world."""
        path = thing_robot_path(robot, "scene", label)
        pose = Pose(tuple(body.get("position", (0.0, 0.0, 0.0))), _quaternion(body.get("rpy", (0.0, 0.0, 0.0))))
        kind = body.get("type")
        if kind in ("mesh", "points"):
            if not isinstance(asset, Asset):
                raise ValueError(asset or "its file was not fetched")
            default = (0.5, 0.6, 0.7, 1.0) if kind == "points" else (0.7, 0.7, 0.7, 1.0)  # tdgen's
            self.rec.log(path, asset_archetype(asset, tuple(body.get("rgba", default))), static=True)
            self.rec.log(path, rr.Transform3D(translation=pose.p, quaternion=rr.Quaternion(xyzw=pose.q)), static=True)
            return
        if kind == "urdf":
            file = scene_urdf(str(body["urdf"]))
            drawn = DrawnRobot.load(label, file.read_text(), path, file.parent,
                                    frame_prefix=f"{own_prefix(robot)}scene/{label}/")
            drawn.draw(self.rec, pose, own_frame(robot), float(body.get("scale", 1.0)))
            return
        rgba = tuple(body.get("rgba", (0.7, 0.7, 0.7, 1.0)))
        if kind == "box":
            shape = Body(label, "box", tuple(body["size"]), pose, rgba[:3], rgba[3])
        elif kind == "cylinder":
            shape = Body(label, "cylinder", (body["radius"], body["length"]), pose, rgba[:3], rgba[3])
        else:
            raise ValueError(f"a {kind!r} body is not drawn")
        self.rec.log(path, body_shape(shape), static=True)
        self.rec.log(path, rr.Transform3D(translation=pose.p, quaternion=rr.Quaternion(xyzw=pose.q)), static=True)

    def _urdf(self, t: _RobotThing) -> DrawnRobot | None:
        return self.scene.robots.get(t.host) if t.host is not None else t.robot

    def _frame(self, t: _RobotThing) -> str | None:
        robot = self._urdf(t)
        return robot.base_frame if robot is not None else None

    # --- the workspace (static) ----------------------------------------------------------------
    def draw_workspace(self, ws: DrawnWorkspace) -> list[Entry]:
        """Points (free and colliding apart) and hull in the robot's base frame; returns a log line."""
        name = ws.thing
        t = self.things.setdefault(name, _RobotThing())
        t.workspace = ws
        free, colliding = ws.points[~ws.colliding], ws.points[ws.colliding]
        for part, points, colour in (("free", free, FREE_COLOUR), ("colliding", colliding, COLLIDING_COLOUR)):
            self.rec.log(thing_robot_path(name, "workspace", "points", part),
                         rr.Points3D(points, colors=[colour], radii=[POINT_RADIUS]),  # type: ignore[arg-type]
                         static=True)
        self.rec.log(thing_robot_path(name, "workspace", "hull"),
                     rr.Mesh3D(vertex_positions=ws.vertices, triangle_indices=ws.triangles,
                               vertex_normals=ws.normals, albedo_factor=HULL_COLOUR), static=True)
        self._log_frames(name, t)
        text = (f"workspace: {len(ws.points)} points, {len(colliding)} colliding; "
                f"hull of {len(ws.vertices)} vertices")
        level = "INFO" if t.frame is not None else "WARN"
        if t.frame is None:
            text += " (not placed: the robot is not drawn)"
        return [Entry(thing_robot_path(name, "log"), rr.TextLog(text, level=level))]

    def _log_frames(self, name: str, t: _RobotThing) -> None:
        t.frame = self._frame(t)
        if t.frame is None:
            return
        for parts in (("points", "free"), ("points", "colliding"), ("hull",)):
            self.rec.log(thing_robot_path(name, "workspace", *parts), rr.CoordinateFrame(t.frame), static=True)

    # --- a move's path (over time) -------------------------------------------------------------
    def draw_path(self, thing: str, call: Any) -> list[Entry]:
        """The end effector's sweep of a robot move (its answer's `path.tip`, mm in the TD's frame) as a
        line in the robot's base frame, shown from that move on; nothing for other calls."""
        tip = _tip(call)
        t = self.things.get(thing)
        if tip is None or t is None:
            return []
        if t.files is not None and t.files.twin.frame == "real":
            tip = to_twin_frame(tip, t.files.twin)
        path = thing_robot_path(thing, "path")
        frame = self._frame(t)
        if frame is not None and self._path_frames.get(thing) != frame:
            self.rec.log(path, rr.CoordinateFrame(frame), static=True)
            self._path_frames[thing] = frame
        return [Entry(path, rr.LineStrips3D([(tip / 1000).astype(np.float32)], colors=[PATH_COLOUR],
                                            radii=[PATH_RADIUS]))]

    # --- joints (over time) --------------------------------------------------------------------
    def add_joints(self, thing: str, values: Any, wall: float, seq: int, sim: float | None) -> None:
        """Queue one `getJointposition` value (joint -> deg or mm), converted to rad or m."""
        if not isinstance(values, dict):
            return
        t = self.things.setdefault(thing, _RobotThing())
        rows = self._joints.get(thing)
        if rows is None:
            rows = self._joints[thing] = JointRows()
        rows.add(wall, seq, sim, {joint: float(v) * self._unit(t, joint)[0] for joint, v in values.items()
                                  if isinstance(v, (int, float)) and not isinstance(v, bool)})
        self._rows += 1
        if self._oldest is None:
            self._oldest = time.monotonic()

    def _unit(self, t: _RobotThing, joint: str) -> tuple[float, str]:
        if joint in t.units:
            return t.units[joint]
        robot = self._urdf(t)
        return _PRISMATIC if robot is not None and robot.unit(joint) == "m" else _REVOLUTE

    def flush_due(self) -> bool:
        return self._oldest is not None and (
            self._rows >= self.batch_rows or time.monotonic() - self._oldest >= self.batch_age)

    def flush(self) -> None:
        """Per robot, one `send_columns` for its joints' values and one for their transforms (rows that
        fail are dropped)."""
        self._rows, self._oldest = 0, None
        made: dict[tuple[int, ...], list[rr.TimeColumn]] = {}
        for thing, joints in self._joints.items():
            rows, moved = joints.take()
            if not rows.values:
                continue
            t = self.things[thing]
            units = [self._unit(t, j)[1] for j in joints.names]
            send_values(self.rec, thing_robot_path(thing, "joints"), joints.names, units, rows, made, self._styled)
            if t.robot is not None:
                t.robot.send_joints(self.rec, moved)
