"""How a simulated world looks in a Rerun recording: its scene drawn, its poses animated (SPEC §6).

The `world` Thing (`mesh.messages.scene_description`) says what the lab looks like (`scene.json` and the robots'
URDFs) and, in its `poses` property, where everything is at each instant of simulated time.
`SceneDrawer` turns both into Rerun data. It is owned by the recorder's writer thread and writes to
its RecordingStream. Poses may come fast (a world at `--speed max`), and one `log` call per value
costs about 2 ms a sample, so joint values and body poses are kept in per-entity batches and
written with `send_columns` a few times a second (about 0.1 ms a sample). `DrawnRobot` (a URDF drawn
under an entity, placed by its base, its joints animated) is shared with `mesh.recorder.robots`, which
draws the robot Things of the lab; `lab_blueprint` lays out both, so a recording opens on the lab in
3D beside its joint plots and its log.

Entities (frames: `tf#/world` is the scene frame; robot `r`'s links are the frames `r/<link>`):
- `world`: Z-up view coordinates;
- `world/robots/<r>/...`: the URDF's visual geometry, `world/robots/<r>/tf_static` its joints at
  zero (both static, from rerun's URDF support, collision geometry left out);
- `world/robots/<r>/base`: the robot's base pose in the scene (static, from `scene.json`); over time,
  when `poses.bodies` names the robot (a Dobot travelling on its track), in `world/poses`;
- `world/robots/<r>/joints`: the moving joints' transforms over time, computed from the URDF, one row
  per joint that moved naming its frame (`mesh.recorder.joint_rows`: two chunks per robot and flush);
- `world/joints/<r>`: the joints' values as time series (rad or m), one series per joint;
- `world/bodies/<b>`: each body as a box, cylinder or sphere with its colour (static) and its pose
  (static; a moving body such as a cube is in its own frame `world/bodies/<b>` instead, placed over
  time in `world/poses`), a `points` body (a scan) as its points and a
  `mesh` body (a CAD mesh) as its triangles, from the file the world serves (`mesh.recorder.scene_assets`),
  placed by the body's pose (a scan's: its sensor's); a body that shows a device's light (a
  lamp's shade, `Body.shows`) has its colour over time instead, from that device's `{on, color}`
  state in the poses, logged the moment the state changes;
- `world/poses`: the poses over time of the moving bodies and of the robots whose base moves, one row
  per pose naming its frame: one chunk per flush however many move (`mesh.recorder.joint_rows` says why);
- `world/states/<device>/<key>`: each device's small state by the property rules of
  `mesh.recorder.mapping`, logged when it changes;
- `robots/<r>/...`: robot Things (see `mesh.recorder.robots`): those of this world in its frame,
  those simulated apart each in its own world (`tf#/robots/<r>`), never in this room.
A joint value or a body pose equal to the one logged last is not logged again: the world sends every
joint of every robot with each sample, and an idle robot would cost as much as a moving one (Rerun
keeps the last value until the next). Poses are stamped on three timelines: `time` (wall clock),
`seq` (the recorder's message number) and `sim_time` (the world's simulated seconds).
"""
from __future__ import annotations

import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgspec
import numpy as np
import rerun as rr
from rerun.urdf import UrdfJoint, UrdfTree

from mesh.messages.scene_description import SCENE_FILE, Body, Pose, Poses, RobotModel, SceneDescription
from mesh.recorder import mapping
from mesh.recorder.batches import SampleBatch
from mesh.recorder.joint_rows import JointRows, send_transforms, send_values
from mesh.recorder.mapping import Entry, entity_path
from mesh.recorder.scene_assets import Asset, asset_archetype, read_asset
from mesh.urdf_resources import with_absolute_meshes

WORLD = "world"
ROBOTS = "robots"  # robot Things (mesh.recorder.robots)
SCENE_FRAME = "tf#/world"  # the implicit frame of the `world` entity
BATCH_ROWS = 200  # samples held before they are written...
BATCH_AGE = 0.25  # ...or seconds since the oldest one; a killed recorder loses about this much more
PLOT_WINDOW = 60.0  # s of simulated (or wall) time each plot shows before the time cursor
_FILLED = ("Boxes3D", "Cylinders3D", "Ellipsoids3D")  # URDF primitives, drawn solid not wireframe
_MISSING = object()


class SceneFiles(msgspec.Struct):
    """What the recorder fetched from the world Thing: its scene, the URDF text of each robot file and the
    files its mesh and points bodies name (by name, as served)."""

    scene: SceneDescription
    urdfs: dict[str, str] = {}
    assets: dict[str, bytes] = {}


def read_scene(get) -> SceneFiles:
    """The world's scene.json, its robots' URDFs and its bodies' files, through `get(file name) -> bytes`;
    a body file that cannot be fetched is left out (the drawer says so)."""
    from mesh.wot.problem import Problem

    scene = msgspec.json.decode(get(SCENE_FILE), type=SceneDescription)
    urdfs: dict[str, str] = {}
    for robot in scene.robots:
        if robot.urdf not in urdfs:
            urdfs[robot.urdf] = get(robot.urdf).decode()
    assets: dict[str, bytes] = {}
    for body in scene.bodies:
        if body.file and body.shape in ("mesh", "points") and body.file not in assets:
            try:
                assets[body.file] = get(body.file)
            except Problem:
                continue
    return SceneFiles(scene, urdfs, assets)


# --- entity paths --------------------------------------------------------------------------------
def robot_path(robot: str) -> str:
    return entity_path(WORLD, "robots", robot)


def joint_values_path(robot: str) -> str:
    return entity_path(WORLD, "joints", robot)


def body_path(body: str) -> str:
    return entity_path(WORLD, "bodies", body)


def body_frame(body: str) -> str:
    """The frame of a moving body, placed over time in `POSES` (a frame belongs to one entity)."""
    return f"{WORLD}/bodies/{body}"


POSES = entity_path(WORLD, "poses")


def state_path(device: str, key: str) -> str:
    return entity_path(WORLD, "states", device, key)


def thing_robot_path(robot: str, *parts: str) -> str:
    """`robots/<r>/...`: a robot Thing's model, joint series and workspace (mesh.recorder.robots)."""
    return entity_path(ROBOTS, robot, *parts)


# --- robots --------------------------------------------------------------------------------------
@dataclass
class DrawnRobot:
    """A robot as drawn: its URDF tree under the entity `root` (frames prefixed `<name>/`), its moving joints."""

    name: str
    root: str  # entity path (escaped), e.g. `world/robots/uarm`
    tree: UrdfTree
    joints: dict[str, UrdfJoint]
    base_frame: str
    missing: list[str]  # mesh files that could not be found: those links are drawn as frames only

    @classmethod
    def load(cls, name: str, urdf: str, root: str, urdf_dir: Path | None,
             frame_prefix: str | None = None) -> "DrawnRobot":
        """`urdf_dir`: where the URDF lives on this machine (as its Thing says), so that its meshes
        (`package://`, relative) are found; the text itself came over the mesh. Its frames are
        `<frame_prefix><link>` (default `<name>/`): a frame name belongs to one entity of the recording."""
        urdf, missing = with_absolute_meshes(urdf, urdf_dir)
        prefix = f"{name}/" if frame_prefix is None else frame_prefix
        with tempfile.TemporaryDirectory(prefix="twinmesh-urdf-") as tmp:
            path = Path(tmp) / f"{name}.urdf"
            path.write_text(urdf)
            tree = UrdfTree.from_file_path(path, None, frame_prefix=prefix,
                                           static_transform_entity_path=f"{root}/tf_static")
        joints = {j.name: j for j in tree.joints() if j.joint_type != "fixed"}
        return cls(name, root, tree, joints, f"{prefix}{tree.root_link().name}", missing)

    def draw(self, rec, base: Pose, parent_frame: str = SCENE_FRAME, scale: float = 1.0) -> None:
        """Its geometry and zero-pose joints (static), primitives solid, the base placed in `parent_frame`
        (the lab's scene frame, or the frame of a robot's own world) and scaled as a whole by `scale`
        (a scene's URDF body: pybullet's `globalScaling`, link origins and geometry alike)."""
        chunks, filled = self.static_chunks()
        rec.send_chunks(chunks)
        for path, archetype in filled:
            rec.log(path, getattr(rr, archetype).from_fields(fill_mode="solid"), static=True)
        rec.log(f"{self.root}/base", _placement(base, self.base_frame, parent_frame, scale), static=True)

    def static_chunks(self) -> tuple[list, list[tuple[str, str]]]:
        """The URDF's visual geometry and zero-pose joint transforms moved under `root`, and the
        (path, archetype) of the primitives among them (to be drawn solid)."""
        root, target = "/" + rr.escape_entity_path_part(self.tree.name), "/" + self.root
        chunks, filled = [], []
        for chunk in self.tree.stream():
            path = chunk.entity_path
            if path == root or path.startswith(root + "/"):
                if path.startswith(root + "/collision_geometries"):
                    continue
                path = target + path[len(root):]
                chunk = chunk.with_entity_path(path)
            archetypes = {f.name.split(":")[0] for f in chunk.to_record_batch().schema}
            filled += [(path, a) for a in _FILLED if a in archetypes]
            chunks.append(chunk)
        return chunks, filled

    @property
    def joints_path(self) -> str:
        return f"{self.root}/joints"

    def send_joints(self, rec, moved: SampleBatch) -> None:
        """The transforms of the joints that moved (values in rad or m; those the URDF has), one chunk."""
        send_transforms(rec, self.joints_path, self.tree, set(self.joints), moved)

    def unit(self, joint: str) -> str:
        j = self.joints.get(joint)
        return "m" if j is not None and j.joint_type == "prismatic" else "rad"


class SceneDrawer:
    """Draws the world's scene and animates it from its poses, into `rec` (one thread only)."""

    def __init__(self, rec, batch_rows: int = BATCH_ROWS, batch_age: float = BATCH_AGE):
        self.rec = rec
        self.batch_rows, self.batch_age = batch_rows, batch_age
        self.robots: dict[str, DrawnRobot] = {}
        self.bodies: dict[str, Body] = {}
        self.sim_time: float | None = None  # the latest simulated time seen
        self._scene: SceneFiles | None = None
        self._assets: dict[tuple, Asset] = {}  # read files, by what they were read from: a redraw reads none again
        self._static_bodies: set[str] = set()  # drawn static (the first scene): cleared static too
        self._joints: dict[str, JointRows] = {}  # robot -> its joints (their latest values kept)
        self._poses: dict[str, SampleBatch] = {}  # body name or robot name (its base) -> poses
        self._states: dict[tuple[str, str], Any] = {}
        self._shown: dict[str, tuple[int, ...]] = {}  # body showing a light -> the colour it was drawn in
        self._body_poses: dict[str, Pose] = {}  # the last pose logged per moving body
        self._styled: dict[str, list[str]] = {}  # joint values entity -> the series names logged
        self._rows = 0
        self._oldest: float | None = None  # monotonic time of the oldest unwritten row

    # --- the scene (static) ----------------------------------------------------------------
    def draw_scene(self, files: SceneFiles, wall: float, seq: int) -> list[str]:
        """Draw robots and bodies; a scene equal to the last one drawn is skipped. Returns problems."""
        if files == self._scene:
            return []
        first = self._scene is None  # the room as it starts: static, there for the whole recording
        old_robots, old_bodies = set(self.robots), set(self.bodies)
        self._scene, self.robots, self.bodies, problems = files, {}, {}, []
        self.rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        for model in files.scene.robots:
            try:
                self._draw_robot(model, files.urdfs[model.urdf])
            except Exception as e:  # one bad URDF must not hide the rest of the scene
                problems.append(f"cannot draw robot {model.name} from {model.urdf}: {e}")
        for body in files.scene.bodies:
            try:
                self._draw_body(body, wall, seq, static=first or body.name in self._static_bodies)
            except ValueError as e:  # a file that cannot be drawn: said, the rest of the scene drawn
                problems.append(f"cannot draw body {body.name}: {e}")
        for gone in old_robots - set(self.robots):
            self.rec.log(robot_path(gone), rr.Clear(recursive=True), static=True)
        for gone in old_bodies - set(self.bodies):  # an obstacle removed: gone from then on, not before
            self.rec.log(body_path(gone), rr.Clear(recursive=True), static=gone in self._static_bodies)
            self._static_bodies.discard(gone)
        return problems

    def _asset_shape(self, body: Body) -> rr.Points3D | rr.Mesh3D:
        """A mesh or points body from its file, in its colour."""
        assert self._scene is not None
        data = self._scene.assets.get(body.file or "")
        if data is None:
            raise ValueError(f"the world did not serve its file {body.file}")
        key = (body.shape, body.file, body.scale, len(data), hash(data))
        asset = self._assets.get(key)
        if asset is None:
            asset = self._assets[key] = read_asset(body.shape, body.file or "", data, body.scale)
        return asset_archetype(asset, (*body.color, body.opacity))

    @property
    def scene(self) -> SceneDescription | None:
        """The scene drawn last, if any."""
        return self._scene.scene if self._scene is not None else None

    def _draw_robot(self, model: RobotModel, urdf: str) -> None:
        robot = DrawnRobot.load(model.name, urdf, robot_path(model.name),
                           Path(model.urdf_dir) if model.urdf_dir else None)
        robot.draw(self.rec, model.base)
        self.robots[model.name] = robot
        if model.name in self._joints:  # drawn at its zero pose: the next sample places every joint again
            self._joints[model.name].redrawn()

    def _draw_body(self, body: Body, wall: float, seq: int, static: bool) -> None:
        """A body of the first scene is static; one added later (an obstacle) exists from the time it was
        drawn on, so that scrolling back shows the lab without it."""
        path = body_path(body.name)
        shape = self._asset_shape(body) if body.shape in ("mesh", "points") else \
            body_shape(body, with_colour=body.shows is None)
        self.rec.log(path, shape, static=static)
        if body.shows is not None:  # its colour over time, from the device's state (a static one would shadow it)
            self._shown.pop(body.name, None)
            entry = self._shown_colour(body)
            if entry is not None:
                if self.sim_time is None:  # no poses yet: from the start of the simulated time on
                    self.rec.set_time("sim_time", duration=0.0)
                self.rec.log(entry.path, entry.archetype)
        if body.moving:  # a static pose would shadow the poses to come: log it as the first of them
            self.rec.log(path, rr.CoordinateFrame(body_frame(body.name)), static=static)
            self._batch_pose(body.name, body.pose, wall, seq)
        else:
            placement = rr.Transform3D(translation=body.pose.p, quaternion=rr.Quaternion(xyzw=body.pose.q))
            self.rec.log(path, placement, static=static)
        self.bodies[body.name] = body
        if static:
            self._static_bodies.add(body.name)

    # --- poses (over time) -----------------------------------------------------------------
    def add_poses(self, poses: Poses, wall: float, seq: int) -> list[Entry]:
        """Queue one sample's joints and body poses; returns the logs for the states that changed."""
        self.sim_time = sim = poses.time
        for robot, joints in poses.joints.items():  # every joint of every robot comes each time: only
            rows = self._joints.get(robot)          # a move is logged (the rest hold)
            if rows is None:
                rows = self._joints[robot] = JointRows()
            rows.add(wall, seq, sim, {joint: float(value) for joint, value in joints.items()})
        for name, pose in poses.bodies.items():
            if self._body_poses.get(name) != pose:
                self._batch_pose(name, pose, wall, seq)
        out: list[Entry] = []
        for device, state in poses.states.items():
            changed = False
            for key, value in state.items():
                if self._states.get((device, key), _MISSING) != value:
                    self._states[(device, key)] = value
                    out += mapping.value_entries(state_path(device, key), key, value, None)
                    changed = True
            if changed:
                out += [e for b in self.bodies.values() if b.shows == device
                        for e in [self._shown_colour(b)] if e is not None]
        self._rows += 1
        if self._oldest is None:
            self._oldest = time.monotonic()
        return out

    def _shown_colour(self, body: Body) -> Entry | None:
        """The colour of a body that shows a light: the device's colour while it is on, the body's own
        while off (or before any state); None when it is already drawn in it."""
        state = {k: v for (device, k), v in self._states.items() if device == body.shows}
        lit = mapping.light_colour(state.get("color")) if state.get("on") is True else None
        rgb = lit if lit is not None else body.color
        colour = tuple(round(min(max(c, 0.0), 1.0) * 255) for c in (*rgb, body.opacity))
        if self._shown.get(body.name) == colour:
            return None
        self._shown[body.name] = colour
        archetype = _ARCHETYPES.get(body.shape)
        return Entry(body_path(body.name), archetype.from_fields(colors=[colour])) if archetype is not None else None

    def _batch_pose(self, name: str, pose: Pose, wall: float, seq: int) -> None:
        self._body_poses[name] = pose
        batch = self._poses.get(name)
        if batch is None:
            batch = self._poses[name] = SampleBatch()
        batch.add(wall, seq, self.sim_time or 0.0, pose)
        if self._oldest is None:
            self._oldest = time.monotonic()

    def flush_due(self) -> bool:
        return self._oldest is not None and (
            self._rows >= self.batch_rows or time.monotonic() - self._oldest >= self.batch_age)

    def flush(self) -> None:
        """Write every queued row: one `send_columns` per entity, a robot's joints two (rows that fail to
        write are dropped)."""
        poses = self._poses
        self._poses, self._rows, self._oldest = {}, 0, None
        made: dict[tuple[int, ...], list[rr.TimeColumn]] = {}
        for robot_name, joints in self._joints.items():
            rows, moved = joints.take()
            if not rows.values:
                continue
            robot = self.robots.get(robot_name)  # named again once its URDF tells a prismatic joint
            units = [robot.unit(j) if robot is not None else "rad" for j in joints.names]
            send_values(self.rec, joint_values_path(robot_name), joints.names, units, rows, made, self._styled)
            if robot is not None:
                robot.send_joints(self.rec, moved)
        framed, frames = SampleBatch(), []  # the poses of moving bodies and robot bases: one chunk
        for name, batch in poses.items():
            frame = self._pose_frame(name)
            if frame is None:
                self._send_poses(body_path(name), batch, batch.indexes(made))
                continue
            for row in zip(batch.wall, batch.seq, batch.sim, batch.values):
                framed.add(*row)
            frames += [frame] * len(batch.values)
        if frames:
            self._send_poses(POSES, framed, framed.indexes(), frames)

    def _pose_frame(self, name: str) -> str | None:
        """The frame a pose over time places: a robot's root link (its base moves), a moving body's frame;
        None for a body drawn in its entity's own frame."""
        robot, body = self.robots.get(name), self.bodies.get(name)
        if robot is not None:
            return robot.base_frame
        return body_frame(name) if body is None or body.moving else None

    def _send_poses(self, path: str, batch: SampleBatch, indexes: list[rr.TimeColumn],
                    frames: list[str] | None = None) -> None:
        """Poses to `path`: each row placing its frame in `frames` in the scene frame, or without frames
        the entity's own."""
        translations = np.array([p.p for p in batch.values])
        quaternions = np.array([p.q for p in batch.values])
        columns = rr.Transform3D.columns(translation=translations, quaternion=quaternions,
                                         parent_frame=None if frames is None else [SCENE_FRAME] * len(frames),
                                         child_frame=frames)
        self.rec.send_columns(path, indexes, columns)


_ARCHETYPES: dict[str, Any] = {"box": rr.Boxes3D, "cylinder": rr.Cylinders3D, "sphere": rr.Ellipsoids3D}


def body_shape(body: Body, with_colour: bool = True) -> rr.Boxes3D | rr.Cylinders3D | rr.Ellipsoids3D:
    """A body's primitive, solid, in its colour unless `with_colour` is False (its colour is logged apart)."""
    colors = [[round(min(max(c, 0.0), 1.0) * 255) for c in (*body.color, body.opacity)]] if with_colour else None
    if body.shape == "box":
        return rr.Boxes3D(half_sizes=[[s / 2 for s in body.size]], colors=colors, fill_mode="solid")
    if body.shape == "cylinder":
        return rr.Cylinders3D(radii=[body.size[0]], lengths=[body.size[1]], colors=colors, fill_mode="solid")
    r = body.size[0]
    return rr.Ellipsoids3D(half_sizes=[[r, r, r]], colors=colors, fill_mode="solid")


def lab_blueprint(scene: SceneDescription | None, world_robots: list[str], thing_robots: dict[str, Pose],
                  own_worlds: dict[str, Pose] | None = None, plots: bool = True, log: bool = True):
    """How a recording of a lab opens: the lab in 3D, each robot simulated apart in its own 3D tab, joint
    plots per robot, states, the log, the time cursor following the latest data. The live view sends the
    same blueprint, so a replay looks the same. Each plot shows the last `PLOT_WINDOW` seconds before the
    time cursor (zoom out to see more): a plot of everything costs the viewer more each frame the longer
    the lab runs, until a browser drawing slowly falls behind the live stream.

    `thing_robots` are the robot Things of the lab's world (name -> base pose): their workspaces are
    hidden in the lab view (one eye toggle per robot in the blueprint panel: `robots/<r>/workspace`)
    and shown in a second 3D tab, `workspaces`. `own_worlds` are the robot Things simulated in their
    own world (name -> base pose in it): one tab each, its origin the robot's own root `robots/<r>`,
    with its scene and workspace. The time panel opens on `sim_time` when a world runs, else `time`.
    `plots` and `log` (False: that part left out) are there for the viewer benchmarks.
    """
    import rerun.blueprint as rrb

    own = own_worlds or {}
    spatial: list[rrb.Spatial3DView | rrb.Tabs] = []
    if scene is not None or thing_robots:
        bases = [r.base.p for r in scene.robots] if scene is not None else []
        bases += [p.p for p in thing_robots.values()]
        contents = [f"+ /{WORLD}/robots/**", f"+ /{WORLD}/bodies/**"]
        contents += [f"+ /{thing_robot_path(r)}/**" for r in thing_robots]
        hidden = {"/" + thing_robot_path(r, "workspace"): rrb.EntityBehavior(visible=False) for r in thing_robots}
        eye = _eye(bases, 2.5 if thing_robots else 1.0)  # a UR10's workspace is 2.6 m across
        spatial.append(rrb.Spatial3DView(
            origin=f"/{WORLD}", name=scene.name if scene is not None else "lab", contents=contents,
            overrides=hidden, eye_controls=eye))  # type: ignore[arg-type]  # rerun's Mapping is invariant in its key
        if thing_robots:
            spatial.append(rrb.Spatial3DView(origin=f"/{WORLD}", name="workspaces", contents=contents,
                                             eye_controls=eye))
    for r, base in own.items():
        spatial.append(rrb.Spatial3DView(origin="/" + thing_robot_path(r), name=f"{r} (own world)",
                                         contents=[f"+ /{thing_robot_path(r)}/**"], eye_controls=_eye([base.p], 2.5)))
    main = spatial[0] if len(spatial) == 1 else rrb.Tabs(*spatial)
    recent = [rrb.VisibleTimeRange(timeline, start=rrb.TimeRangeBoundary.cursor_relative(seconds=-PLOT_WINDOW),
                                   end=rrb.TimeRangeBoundary.cursor_relative()) for timeline in ("sim_time", "time")]
    joints = [rrb.TimeSeriesView(origin="/" + entity_path(WORLD, "joints", r), name=f"{r} joints", time_ranges=recent)
              for r in world_robots]
    joints += [rrb.TimeSeriesView(origin="/" + thing_robot_path(r, "joints"), time_ranges=recent,
                                  name=f"{r} joints" + (" (Thing)" if r in world_robots else ""))
               for r in [*thing_robots, *own]]
    values = rrb.Tabs(rrb.TimeSeriesView(origin=f"/{WORLD}/states", name="device states", time_ranges=recent),
                      rrb.TimeSeriesView(origin="/things", name="properties", time_ranges=recent))
    side_views: list[rrb.Tabs | rrb.TextLogView] = []
    side_views += ([rrb.Tabs(*joints)] if joints else []) + [values] if plots else []
    side_views += [rrb.TextLogView(origin="/", name="log")] if log else []
    layout = rrb.Horizontal(main, rrb.Vertical(*side_views), column_shares=[3, 2]) if side_views else main
    return rrb.Blueprint(layout,
                         rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
                         rrb.TimePanel(timeline="sim_time" if scene is not None else "time", state="collapsed",
                                       play_state="following"))


def _eye(bases: list, least: float = 1.0):
    """A camera in front of and above the robots, far enough to see them all (`least` from one)."""
    import rerun.blueprint as rrb

    at = np.array(bases or [(0.0, 0.0, 0.0)])
    target = at.mean(axis=0)
    reach = max(least, 1.6 * float(np.ptp(at, axis=0).max()))
    return rrb.EyeControls3D(position=target + reach * np.array([-0.35, -1.0, 0.6]), look_target=target,
                             eye_up=(0.0, 0.0, 1.0))


def _placement(pose: Pose, child_frame: str, parent_frame: str = SCENE_FRAME, scale: float = 1.0) -> rr.Transform3D:
    return rr.Transform3D(translation=pose.p, quaternion=rr.Quaternion(xyzw=pose.q), parent_frame=parent_frame,
                          child_frame=child_frame, scale=None if scale == 1.0 else scale)
