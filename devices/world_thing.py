"""The `world` Thing of a simulated scene: poses for the recorder, the scene description, speed and reset.

The contract with the recorder is `mesh.scene_model`: an observable property `poses` (a `Poses`)
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
  of every device's reach, as a lab assistant would (how a test or a class sets up an empty warehouse).
"""
from __future__ import annotations

import logging
import threading
import time
from typing import Any, Callable

import msgspec
import pybullet as pb

from devices.compensation import DOBOT_URDF, UARM_URDF
from devices.platform import IotPlatform
from devices.world import Snapshot, body_pose, place
from mesh.keys import Keys
from mesh.scene_model import (POSES_PROPERTY, SCENE_FILE, WORLD_THING, Body, Pose, Poses, RobotModel,
                              SceneDescription)
from mesh.td import ThingDescription, decode_td, thing_id
from mesh.thing import ExposedThing

log = logging.getLogger(__name__)

SCENE_NAME = "iot-platform"
URDF_TYPE = "application/xml"
ROBOT_URDFS = {"uarm": ("uarm.urdf", UARM_URDF), "dobot": ("dobot.urdf", DOBOT_URDF)}
POSES_RATE = 20.0  # publications per wall second, at most
# where resetWarehouse sets spare cubes aside: on the table left of conveyor belt 1, real uArm frame (mm)
ASIDE_XY = [(x, y) for y in (-440.0, -490.0) for x in (380.0, 420.0, 460.0)]

_OBJECT = {"type": "object"}


def world_td(platform: IotPlatform) -> ThingDescription:
    n = len(platform.cubes)
    return decode_td({
        "title": WORLD_THING,
        "id": thing_id(WORLD_THING),
        "description": (
            f"The simulated world of the {SCENE_NAME} scene (twinmesh). poses: what moves, published when "
            "something changed, at most 20 times per wall second and always once more when a motion ends; "
            "joints per robot (rad or m), bodies: cubes and robot bases ([[x,y,z],[qx,qy,qz,qw]], m, scene frame; "
            "the Dobot's base moves along its track), states per device. Files: scene.json (the scene "
            "description), the robots' URDFs (links rel=model, anchored at each robot's Thing)."),
        "properties": {
            POSES_PROPERTY: {
                "title": "Poses", "type": "object", "readOnly": True, "observable": True,
                "required": ["time"],
                "properties": {"time": {"type": "number", "minimum": 0, "unit": "s"},
                               "joints": _OBJECT, "bodies": _OBJECT, "states": _OBJECT},
            },
            "simTime": {"title": "Simulated time", "description": "Seconds of simulated time since the world "
                        "started.", "type": "number", "minimum": 0, "unit": "s", "readOnly": True},
            "speed": {"title": "Simulation speed", "description": "Simulated seconds per wall second; 0 means "
                      "as fast as the CPU allows (twinmesh up --speed max).", "type": "number", "minimum": 0,
                      "observable": True},
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
                          "properties": {"cubes": {"type": "integer", "minimum": 0, "maximum": n}}},
                "safe": False, "idempotent": True, "synchronous": True,
            },
        },
        "links": [{"rel": "scene", "href": f"files/{SCENE_FILE}", "type": "application/json"}]
        + [{"rel": "model", "href": f"files/{name}", "type": URDF_TYPE, "anchor": thing_id(robot)}
           for robot, (name, _) in ROBOT_URDFS.items()],
    })


def _pose(p: tuple) -> Pose:
    pos, orn = p
    return Pose(tuple(float(v) for v in pos), tuple(float(v) for v in orn))  # type: ignore[arg-type]


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


def scene_description(platform: IotPlatform) -> SceneDescription:
    """Robots, static and moving bodies as they stand now (stepping thread, or before the world starts)."""
    c = platform.world.client
    named = dict(platform.fixtures)
    for name, belt in platform.belts.items():
        named[name] = belt.body
        for i, stop in enumerate(belt.end_stops):
            named[f"{name}-end-stop-{i + 1}"] = stop
    for name, sensor in [*platform.infrared.items(), ("color-sensor", platform.color_sensor)]:
        named[name] = sensor.body
    bodies = [_box(c, name, body) for name, body in named.items()]
    bodies += [_box(c, cube.name, cube.body, moving=True) for cube in platform.cubes]
    robots = [RobotModel(name=robot, urdf=file, base=_pose(body_pose(c, platform.devices[robot].arm.body)))
              for robot, (file, _) in ROBOT_URDFS.items()]
    return SceneDescription(name=SCENE_NAME, robots=robots, bodies=bodies)


def _box(client: int, name: str, body: int, moving: bool = False) -> Body:
    shape = pb.getVisualShapeData(body, physicsClientId=client)[0]
    if shape[2] != pb.GEOM_BOX:  # pragma: no cover - the platform is built of boxes
        raise ValueError(f"{name}: only boxes are described")
    return Body(name=name, shape="box", size=tuple(float(v) for v in shape[3]), pose=_pose(body_pose(client, body)),
                color=tuple(float(v) for v in shape[7][:3]), moving=moving)  # type: ignore[arg-type]


class Throttle:
    """Publishes the latest offered value at most `rate` times per wall second, never dropping the last."""

    def __init__(self, publish: Callable[[Any], None], rate: float = POSES_RATE):
        self._publish, self._period = publish, 1.0 / rate
        self._latest: Any = None
        self._dirty = threading.Event()
        self._stop = threading.Event()
        self._lock = threading.Lock()
        self._thread = threading.Thread(target=self._loop, name="poses-throttle", daemon=True)
        self._thread.start()

    def offer(self, value: Any) -> None:
        with self._lock:
            self._latest = value
        self._dirty.set()

    def close(self) -> None:
        self._stop.set()
        self._dirty.set()
        self._thread.join(timeout=2)

    def _loop(self) -> None:
        while True:
            self._dirty.wait()
            if self._stop.is_set():
                return
            self._dirty.clear()
            with self._lock:
                value = self._latest
            started = time.monotonic()
            try:
                self._publish(value)
            except Exception:  # keep publishing later values (a closing session ends the loop below)
                if self._stop.is_set():
                    return
                log.exception("publishing failed")
            if self._stop.wait(max(0.0, self._period - (time.monotonic() - started))):
                return


class WorldThing:
    """The `world` Thing of an `IotPlatform`; use as a context manager (exposes, then tears down)."""

    def __init__(self, session, platform: IotPlatform, keys: Keys | None = None, rate: float = POSES_RATE):
        self.platform, self.world = platform, platform.world
        self.thing = ExposedThing(session, world_td(platform), WORLD_THING, keys)
        scene = msgspec.json.encode(self.world.run(lambda: scene_description(platform)))
        t = self.thing
        t.on_read(POSES_PROPERTY, lambda: to_poses(self.world.snapshot()))
        t.on_read("simTime", lambda: self.world.time)
        t.on_read("speed", lambda: self.world.speed or 0.0).on_write("speed", self._set_speed)
        t.on_action("reset", lambda _: self.reset())
        t.on_action("resetWarehouse", lambda v: self.reset(v["cubes"]))
        t.on_file(SCENE_FILE, lambda: scene, "application/json")
        for name, path in ROBOT_URDFS.values():
            t.on_file(name, lambda data=path.read_bytes(): data, URDF_TYPE)
        self._published: Snapshot | None = None
        self._lock = threading.Lock()
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

    def _fill(self, snap: Snapshot) -> None:  # stepping thread: a snapshot source
        snap.states[WORLD_THING] = {"idle": self.world.idle(), "speed": self.world.speed or 0.0}

    def _snapshot(self, snap: Snapshot, force: bool = False) -> None:  # mostly the world's notifier thread
        """Publish what moved. The snapshot in which the world turns idle differs in its state, so the
        exact final state of a motion always goes out."""
        with self._lock:
            if self._published is not None and not force and not moved(self._published, snap):
                return
            self._published = snap
            self._throttle.offer(to_poses(snap))

    def _set_speed(self, value: float) -> None:
        self.world.speed = None if value == 0 else float(value)
        self.thing.emit_property_change("speed", self.world.speed or 0.0)

    def reset(self, cubes: int | None = None) -> None:
        """The scene as it started; with `cubes`, only that many left in the warehouse queue."""
        self.platform.reset()
        if cubes is not None:
            self.world.run(lambda: self._set_aside(cubes))
        self._snapshot(self.world.snapshot(), force=True)

    def _set_aside(self, keep: int) -> None:  # stepping thread
        p = self.platform
        queue = p.warehouse.queue
        p.warehouse.queue, aside = queue[:keep], queue[keep:]
        for cube, (x, y) in zip(aside, ASIDE_XY):
            place(self.world.client, cube.body, p.w(x, y, cube.size * 500.0))
        for sensor in p.infrared.values():
            sensor.refresh()
