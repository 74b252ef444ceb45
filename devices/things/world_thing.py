"""The `world` Thing of a simulated scene: poses for the recorder, the scene description, speed and reset.

The contract with the recorder is `mesh.messages.scene_description`: an observable property `poses` (a `Poses`)
and a file `scene.json` (a `SceneDescription`), plus each robot's URDF as a file. Here:

- `poses` publishes the latest world snapshot when something moved (a body by more than 0.5 mm or
  about 0.1 deg, so cubes resting in the warehouse, which creep very slowly, do not chatter), at
  most `rate` times per WALL second however fast the simulation runs. The snapshot in which the
  world turns idle (no motion, no belt running: `states.world.idle`) always goes out, so the exact
  final state of every motion is published (the throttle delays, it never drops the last one).
  `joints` has every joint of both robots (main, passive, fingers); `bodies` the cubes and the
  robots' bases (the Dobot's base rides its linear track, so it moves); `states` belts, sensors,
  the Dobot's queue and position, the uArm's location, and the world's own `{idle, speed}`;
- `simTime` (s), `speed` (writable: simulated seconds per wall second; 0 = as fast as the CPU
  allows, i.e. `--speed max`; an idle world then steps in real time);
- `reset` puts every cube back in the warehouse, the robots home, the belts stopped (motions under
  way are cancelled: their callers get a 503); `resetWarehouse {cubes: n}` does the same but leaves
  only the first n cubes of the queue in the warehouse and sets the others aside on the table, out
  of every device's reach, as a lab assistant would (how a test or a class sets up an empty warehouse);
- in a scene that takes obstacles (`ObstacleScene`: the iot-lab), `addObstacle` / `removeObstacle`
  change the scene under the robots and the observable `obstacles` lists them; the TD is then
  re-published with a new `version` (how the recorder knows to reload scene.json). A mesh or scan obstacle's
  file is taken only from the lab's scans folder (`scans`), since the world then serves it to its readers;
- the files the scene's `mesh` and `points` bodies name (CAD meshes, scans) are served beside scene.json
  and linked from the TD (`rel` scene-asset); scene.json names each by the name it is served under,
  relative to scene.json (`devices.things.scene_files`), so a consumer that downloads them rebuilds the scene.

The Thing works for any `SimulatedScene`: it asks the scene for its description, its robots'
URDFs and its reset, and knows nothing of what is on the tables.
"""
from __future__ import annotations

import functools
import logging
import threading
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Callable, Protocol, runtime_checkable

import msgspec

from devices.sim.bodies import pose as _pose
from devices.sim.layouts.obstacles import OBSTACLE_SCHEMA, Obstacle, default_scans_dir
from devices.sim.pybullet_world import MAX_SPEED, MIN_SPEED, Snapshot, World
from devices.things.scene_files import SceneAssets
from mesh.fabric.keys import Keys
from mesh.fabric.server import ExposedThing
from mesh.messages import relations
from mesh.messages.scene_description import POSES_PROPERTY, SCENE_FILE, WORLD_THING, Poses, SceneDescription
from mesh.wot import units
from mesh.wot.problem import BadInput, NotFound
from mesh.wot.thing_description import Link, ThingDescription, decode_td, thing_id
from tdgen.robot_td import URDF_TYPE

log = logging.getLogger(__name__)

POSES_RATE = 20.0  # publications per wall second, at most

_OBJECT = {"type": "object"}


def urdf_file(robot: str) -> str:
    """The world Thing's file name for a robot's URDF (what `RobotModel.urdf` names)."""
    return f"{robot}.urdf"


class SimulatedScene(Protocol):
    """What the world Thing needs of a scene (`IotPlatform`, `IotLab`)."""

    name: str
    world: World

    @property
    def cube_count(self) -> int: ...

    def robot_urdfs(self) -> dict[str, Path]: ...

    def describe(self) -> SceneDescription: ...

    def reset(self, cubes: int | None = None) -> None: ...


@runtime_checkable
class ObstacleScene(Protocol):
    """A scene that takes box obstacles (the iot-lab): its robots see them in their checks and workspaces."""

    def obstacles(self) -> list[Obstacle]: ...

    def add_obstacle(self, obstacle: Obstacle) -> None: ...

    def remove_obstacle(self, name: str) -> Obstacle: ...


def world_td(scene: SimulatedScene, version: int = 0, assets: Sequence[Link] = ()) -> ThingDescription:
    """`assets`: the links to the files of the scene's mesh and points bodies."""
    n = scene.cube_count
    takes_obstacles = isinstance(scene, ObstacleScene)
    td: dict[str, Any] = {
        "title": WORLD_THING,
        "id": thing_id(WORLD_THING),
        "version": {"instance": str(version)},
        "description": (
            f"The simulated world of the {scene.name} scene (twinmesh). poses: what moves, published when "
            "something changed, at most 20 times per wall second and always once more when a motion ends; "
            "joints per robot (rad or m), bodies: cubes and robot bases ([[x,y,z],[qx,qy,qz,qw]], m, scene frame; "
            "the Dobot's base moves along its track), states per device. Files: scene.json (the scene "
            "description), the robots' URDFs (links rel=describedby, anchored at each robot's Thing)."
            + (" Obstacles (boxes, CAD meshes, scans) can be added and removed (addObstacle, removeObstacle); the "
               "files of mesh and scan obstacles are served beside scene.json (links rel scene-asset); the robots "
               "then check their moves against them at once and their workspaces and TDs are regenerated; this TD is "
               "re-published with a new version so that observers reload scene.json." if takes_obstacles else "")),
        "properties": {
            POSES_PROPERTY: {
                "title": "Poses", "type": "object", "readOnly": True, "observable": True,
                "required": ["time"],
                "properties": {"time": {"type": "number", "minimum": 0, "unit": units.SECOND},
                               "joints": _OBJECT, "bodies": _OBJECT, "states": _OBJECT},
            },
            "simTime": {"title": "Simulated time", "description": "Seconds of simulated time since the world "
                        "started.", "type": "number", "minimum": 0, "unit": units.SECOND, "readOnly": True},
            "speed": {"title": "Simulation speed", "description": "Simulated seconds per wall second; 0 means "
                      f"as fast as the CPU allows (twinmesh up --speed max); otherwise {MIN_SPEED:g} to "
                      f"{MAX_SPEED:g}.", "type": "number", "minimum": 0, "maximum": MAX_SPEED, "unit": units.UNITLESS,
                      "observable": True},
            "stepping": {"title": "Simulation running", "description": "Whether the simulation steps. If it ever "
                         "stops, the world's process ends and every device of it leaves the mesh.",
                         "type": "boolean", "readOnly": True},
        },
        "actions": {
            "reset": {"title": "Reset the scene", "description": "Every cube back in the warehouse (original "
                      "order), robots home, belts stopped and at speed 100. Motions under way are cancelled.",
                      "safe": False, "idempotent": True, "synchronous": True},
            "resetWarehouse": {
                "title": "Reset with fewer cubes", "description": "Like reset, but only the first `cubes` cubes "
                "stay in the warehouse queue; the others are set aside on the table, out of every device's "
                "reach (0: an empty warehouse).",
                "input": {"type": "object", "required": ["cubes"],
                          "properties": {"cubes": {"type": "integer", "minimum": 0, "maximum": n,
                                                    "unit": units.NUMBER}}},
                "safe": False, "idempotent": True, "synchronous": True,
            },
        },
        "links": [{"rel": relations.SCENE, "href": f"files/{SCENE_FILE}", "type": "application/json"}]
        + [{"rel": relations.MODEL, "href": f"files/{urdf_file(robot)}", "type": URDF_TYPE, "anchor": thing_id(robot)}
           for robot in scene.robot_urdfs()]
        + [msgspec.to_builtins(link) for link in assets],
    }
    if takes_obstacles:
        td["properties"]["obstacles"] = {
            "title": "Obstacles", "description": "The obstacles added to the scene, in the order added.",
            "type": "array", "items": OBSTACLE_SCHEMA, "readOnly": True, "observable": True}
        td["actions"]["addObstacle"] = {
            "title": "Add an obstacle", "description": "A static box in the scene frame (m, yaw in deg), or a CAD mesh "
            "or a scan from a file in the lab's scans folder on its host (`type` mesh or points, `position`/`rpy` its "
            "pose, a scan's its sensor's). Refused (422) if the name is taken (a scan replaces the scan of its name), "
            "the file is outside the scans folder (file-outside-scans) or cannot be used, or the obstacle would touch "
            "a robot where it stands now.",
            "input": OBSTACLE_SCHEMA, "safe": False, "idempotent": False, "synchronous": True}
        td["actions"]["removeObstacle"] = {
            "title": "Remove an obstacle", "description": "Removes the obstacle of that name (422 if there is none).",
            "input": {"type": "object", "required": ["name"], "properties": {"name": OBSTACLE_SCHEMA["properties"]["name"]}},
            "output": OBSTACLE_SCHEMA, "safe": False, "idempotent": False, "synchronous": True}
    return decode_td(td)


def to_poses(snap: Snapshot) -> Poses:
    return Poses(time=snap.time, joints=snap.joints, bodies={k: _pose(v) for k, v in snap.bodies.items()},
                 states=snap.states)


POSITION_TOLERANCE = 5e-4   # m: resting cubes creep (~0.01 mm/s); a real move crosses this within a step or two
ORIENTATION_TOLERANCE = 1e-3  # quaternion component (~0.1 deg)
JOINT_TOLERANCE = 1e-5     # rad or m: joints are set, they never creep


def moved(a: Snapshot, b: Snapshot) -> bool:
    """Whether `b` differs from `a` by more than the tolerances (or in any state, joint or body set)."""
    if a.states != b.states or a.joints.keys() != b.joints.keys() or a.bodies.keys() != b.bodies.keys():
        return True
    for robot, joints in b.joints.items():
        before = a.joints[robot]
        if joints.keys() != before.keys() or any(abs(v - before[j]) > JOINT_TOLERANCE for j, v in joints.items()):
            return True
    for name, (pos, orn) in b.bodies.items():
        pos0, orn0 = a.bodies[name]
        if any(abs(p - p0) > POSITION_TOLERANCE for p, p0 in zip(pos, pos0)):
            return True
        same = max(abs(q - q0) for q, q0 in zip(orn, orn0))
        flipped = max(abs(q + q0) for q, q0 in zip(orn, orn0))  # q and -q are one rotation
        if min(same, flipped) > ORIENTATION_TOLERANCE:
            return True
    return False


class Throttle:
    """Publishes the latest offered value at most `rate` times per wall second, never dropping the last.

    `flush(value)` publishes at once, in the caller's thread (an action publishes the state it
    leaves before it replies, which the HTTP adapter's cache relies on); a value offered earlier
    is never published after a newer one.
    """

    def __init__(self, publish: Callable[[Any], None], rate: float = POSES_RATE):
        self._publish, self._period = publish, 1.0 / rate
        self._latest: tuple[int, Any] | None = None
        self._seq = self._sent = 0
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()       # _latest and _seq
        self._sending = threading.Lock()    # one publication at a time, in order
        self._thread = threading.Thread(target=self._loop, name="poses-throttle", daemon=True)
        self._thread.start()

    def offer(self, value: Any) -> None:
        with self._lock:
            self._seq += 1
            self._latest = (self._seq, value)
        self._dirty.set()

    def flush(self, value: Any) -> None:
        with self._lock:
            self._seq += 1
            item, self._latest = (self._seq, value), None
        self._send(item)

    def close(self) -> None:
        self._stop.set()
        self._dirty.set()
        self._thread.join(timeout=2)

    def _send(self, item: tuple[int, Any]) -> None:
        with self._sending:
            if item[0] > self._sent:
                self._sent = item[0]
                self._publish(item[1])

    def _loop(self) -> None:
        while True:
            self._dirty.wait()
            if self._stop.is_set():
                return
            self._dirty.clear()
            with self._lock:
                item, self._latest = self._latest, None
            if item is None:
                continue
            started = time.monotonic()
            try:
                self._send(item)
            except Exception:  # keep publishing later values (a closing session ends the loop below)
                if self._stop.is_set():
                    return
                log.exception("publishing failed")
            if self._stop.wait(max(0.0, self._period - (time.monotonic() - started))):
                return


class WorldThing:
    """The `world` Thing of a simulated scene; use as a context manager (exposes, then tears down)."""

    def __init__(self, session, scene: SimulatedScene, keys: Keys | None = None, rate: float = POSES_RATE,
                 scans: Path | None = None):
        """`scans`: the only folder mesh and scan obstacles are taken from (default: `default_scans_dir()`)."""
        self.scene, self.world = scene, scene.world
        self.scans = scans if scans is not None else default_scans_dir()
        self.version = 0
        self._urdfs = {urdf_file(robot): path for robot, path in scene.robot_urdfs().items()}
        self.assets = SceneAssets(taken=[SCENE_FILE, *self._urdfs])
        self._scene_json, links = self._describe()
        self.thing = ExposedThing(session, world_td(scene, 0, links), WORLD_THING, keys)
        t = self.thing
        t.on_read(POSES_PROPERTY, lambda: to_poses(self.world.snapshot()))
        t.on_read("simTime", lambda: self.world.time)
        t.on_read("speed", lambda: self.world.speed or 0.0).on_write("speed", self._set_speed)
        t.on_read("stepping", lambda: self.world.stepping)
        t.on_action("reset", lambda _: self.reset())
        t.on_action("resetWarehouse", lambda v: self.reset(v["cubes"]))
        urdfs = {name: path.read_bytes() for name, path in self._urdfs.items()}
        t.on_any_file(functools.partial(self._file, urdfs))  # a scene change may bring files
        self._obstacles: ObstacleScene | None = scene if isinstance(scene, ObstacleScene) else None
        if isinstance(scene, ObstacleScene):
            t.on_read("obstacles", scene.obstacles)
            t.on_action("addObstacle", self._add_obstacle)
            t.on_action("removeObstacle", self._remove_obstacle)
        self._published: Snapshot | None = None
        self._lock = threading.Lock()
        self._changing = threading.Lock()  # one scene change at a time
        self._throttle = Throttle(lambda poses: t.emit_property_change(POSES_PROPERTY, poses), rate)
        self._unsubscribe: Callable[[], None] | None = None

    def __enter__(self) -> "WorldThing":
        self.world.run(lambda: self.world.add_snapshot_source(self._fill))
        self.thing.expose()
        self._unsubscribe = self.world.on_snapshot(self._snapshot)
        self._snapshot(self.world.snapshot())  # the state at start-up
        return self

    def __exit__(self, *exc) -> None:
        if self._unsubscribe:
            self._unsubscribe()
        self._throttle.close()
        self.thing.destroy()

    def _describe(self) -> tuple[bytes, list[Link]]:
        """scene.json, its mesh and points bodies naming their files as served, and the TD's links to those."""
        description = self.world.run(self.scene.describe)
        files = [{"type": b.shape, "file": b.file} for b in description.bodies if b.file]
        self.assets.add(files)
        names = self.assets.names()
        bodies = [msgspec.structs.replace(b, file=names[b.file]) if b.file in names else b
                  for b in description.bodies]
        served = msgspec.structs.replace(description, bodies=bodies)
        return msgspec.json.encode(served), self.assets.links(files)

    def _file(self, urdfs: dict[str, bytes], name: str) -> tuple[bytes, str]:
        """files/<name>: scene.json, a robot's URDF or a file of the scene (read when asked, never kept)."""
        if name == SCENE_FILE:
            return self._scene_json, "application/json"
        if name in urdfs:
            return urdfs[name], URDF_TYPE
        asset = self.assets.named(name)
        if asset is None:
            raise NotFound(f"{WORLD_THING} has no file {name!r}")
        return asset.read(), asset.media_type

    def _fill(self, snap: Snapshot) -> None:  # stepping thread: a snapshot source
        snap.states[WORLD_THING] = {"idle": self.world.idle(), "speed": self.world.speed or 0.0}

    def _snapshot(self, snap: Snapshot, now: bool = False) -> None:  # mostly the world's notifier thread
        """Publish what moved (throttled; `now`: at once, whatever moved). The snapshot in which the world
        turns idle differs in its state, so the exact final state of a motion always goes out."""
        with self._lock:
            if self._published is not None and not now and not moved(self._published, snap):
                return
            self._published = snap
            (self._throttle.flush if now else self._throttle.offer)(to_poses(snap))  # in order

    def _set_speed(self, value: float) -> None:
        if value != 0 and not MIN_SPEED <= value <= MAX_SPEED:
            raise BadInput(f"speed: must be 0 (as fast as possible) or within {MIN_SPEED:g}..{MAX_SPEED:g}, "
                           f"not {value:g}")
        self.world.speed = None if value == 0 else float(value)
        self.thing.emit_property_change("speed", self.world.speed or 0.0)

    def reset(self, cubes: int | None = None) -> None:
        """The scene as it started; with `cubes`, only that many left in the warehouse queue."""
        self.scene.reset(cubes)
        self._snapshot(self.world.snapshot(), now=True)  # published before the reply

    # --- obstacles (an ObstacleScene) -----------------------------------------------------------
    def _add_obstacle(self, value: dict) -> None:
        from devices.sim.layouts.obstacles import from_input

        with self._changing:
            self._obstacle_scene().add_obstacle(from_input(value, self.scans))
            self._scene_changed()

    def _remove_obstacle(self, value: dict) -> Obstacle:
        with self._changing:
            gone = self._obstacle_scene().remove_obstacle(value["name"])
            self._scene_changed()
            return gone

    def _obstacle_scene(self) -> ObstacleScene:
        assert self._obstacles is not None  # the obstacle actions exist only for an ObstacleScene
        return self._obstacles

    def _scene_changed(self) -> None:
        """New scene.json, the TD re-published with a new version (the recorder redraws), obstacles out."""
        self._scene_json, links = self._describe()
        self.version += 1
        self.thing.update_td(world_td(self.scene, self.version, links))
        self.thing.emit_property_change("obstacles", self._obstacle_scene().obstacles())
        self._snapshot(self.world.snapshot(), now=True)
