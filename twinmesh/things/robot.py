"""A `RobotTwin` as a Thing on the mesh, and `twinmesh robot URDF`: any common-structure arm as a Zenoh peer.

The Thing serves the robot TD of SPEC §4 and §7 (`getJointposition`, `getCartesianposition`, both
observable; `moveToJointPosition`, `moveToCartesianPosition`, which return when the motion is over
with the collision-free path they took; `planMove`, the same answer without moving; `stop`)
plus the event `twinChanged {robot, version}` and the files `twin.json` (its
`twinmesh.messages.scene.TwinDescription`) and its URDF. The workspace comes from the tdgen service:

1. before joining, the robot subscribes to the service's `generated` event;
2. it joins with a provisional TD (joints with their limits, Cartesian values without bounds,
   links rel=twin and rel=model only); Cartesian moves answer 503 `workspace-generating`;
3. the service sees it join, reads `files/twin.json`, generates (or finds in its cache) and emits
   `generated {robot, hash, version}`;
4. the robot fetches `<robot>.td.json`, `.points.csv`, `.workspace.stl`, `.scene.json` from the
   service, keeps the points for its checks, serves the three artefacts as its own files and
   replaces its TD (`update_td`: observers of `<prefix>/<robot>/td` see it), links rel
   workspace/dataset-points/scene/twin/model with relative hrefs `files/...`.

When the surroundings change (`RobotTwin.set_scene`), twin.json changes, `twinChanged` goes out,
the service regenerates and step 4 repeats. Joint states are published while the robot moves, at
most `rate` times per wall second, and always once more with the final value before a move's reply.
"""
from __future__ import annotations

import functools
import hashlib
import logging
import re
import threading
from concurrent.futures import ThreadPoolExecutor
from contextlib import ExitStack
from pathlib import Path
from typing import TYPE_CHECKING, Any

import msgspec

from twinmesh.fabric.client import MeshClient
from twinmesh.fabric.server import ExposedThing
from twinmesh.fabric.settings import MeshSettings
from twinmesh.fabric.state_publisher import StatePublisher
from twinmesh.messages.scene import MODEL_REL, TWIN_FILE, TWIN_REL, TwinDescription
from twinmesh.wot.problem import BadInput, Problem
from twinmesh.wot.td import ThingDescription, decode_td

if TYPE_CHECKING:  # pybullet loads with twinmesh.sim.robot: `twinmesh --help` need not wait for it
    from twinmesh.sim.robot import RobotTwin

log = logging.getLogger(__name__)

TDGEN = "tdgen"               # the service's Thing name (twinmesh.things.tdgen.THING)
TWIN_CHANGED = "twinChanged"  # twinmesh.things.tdgen.TWIN_CHANGED
URDF_TYPE = "application/xml"
STATE_RATE = 20.0             # joint-state publications per wall second while moving, at most
ARTEFACTS = {  # our file name -> (rel, media type); the service's file is `<robot>.<name>`
    "workspace.stl": ("workspace", "model/stl"),
    "points.csv": ("dataset-points", "text/csv"),
    "scene.json": ("scene", "application/json"),
}
CARTESIAN = ("getCartesianposition", "moveToCartesianPosition")
DEFAULT_SAMPLES = 80_000


def slug(name: str) -> str:
    """A Thing name from a robot name: `lbr_iiwa_14_r820` -> `lbr-iiwa-14-r820`."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "robot"


def urdf_reference(path: Path) -> str:
    """How the tdgen service finds the URDF: a pybullet_data or tdgen/robots path if it is one, else absolute."""
    import pybullet_data

    from twinmesh.robot.model import ROBOTS_DIR

    for root in (Path(pybullet_data.getDataPath()).resolve(), ROBOTS_DIR.resolve()):
        if path.is_relative_to(root):
            return str(path.relative_to(root))
    return str(path)


# --- TDs -----------------------------------------------------------------------------------------
def _links(twin: RobotTwin, generated: bool) -> list[dict[str, str]]:
    links = [{"href": f"files/{name}", "rel": rel, "type": media} for name, (rel, media) in ARTEFACTS.items()
             if generated]
    links += [{"href": f"files/{TWIN_FILE}", "rel": TWIN_REL, "type": "application/json"},
              {"href": f"files/{twin.robot.urdf_path.name}", "rel": MODEL_REL, "type": URDF_TYPE}]
    return links


def _finish(td: dict[str, Any], twin: RobotTwin, generated: bool) -> ThingDescription:
    td.pop("base", None)
    td["links"] = _links(twin, generated)
    td["events"] = {TWIN_CHANGED: {
        "title": "Twin changed", "description": "The robot's surroundings changed: its workspace, TD and files "
        "are being regenerated (the TD on the mesh is replaced when they are ready).",
        "data": {"type": "object", "required": ["robot", "version"], "properties": {
            "robot": {"type": "string"}, "version": {"type": "integer", "minimum": 0}}},
        "forms": [{"href": f"events/{TWIN_CHANGED}", "op": ["subscribeevent", "unsubscribeevent"],
                   "contentType": "application/json"}]}}
    return decode_td(td)


def provisional_td(twin: RobotTwin) -> ThingDescription:
    """The TD before the workspace is known: joint limits, Cartesian values without bounds."""
    import numpy as np

    from twinmesh.tdgen.td import build_td, robot_id

    td = build_td(twin.robot, np.zeros(3), np.zeros(3), frame=twin.frame.name, title=twin.name,
                  thing_id=robot_id(twin.name),
                  description=f"{twin.robot.name} (twinmesh twin, from {twin.robot.urdf_path.name}). Its workspace "
                  "is being generated by the tdgen service: Cartesian bounds and the links to the workspace hull, "
                  "sampled points and scene follow when it is ready (this TD is then replaced); until then "
                  "Cartesian moves answer 503.")
    cartesian = [td["properties"]["getCartesianposition"], td["actions"]["moveToCartesianPosition"]["input"],
                 td["actions"]["planMove"]["input"]]
    for schema in cartesian:
        for axis in "xyz":
            schema["properties"][axis].pop("minimum", None)
            schema["properties"][axis].pop("maximum", None)
    return _finish(td, twin, generated=False)


def generated_td(td_json: bytes, twin: RobotTwin, hash: str, version: int) -> ThingDescription:
    """The TD the tdgen service generated for twin `version`, with this robot's links and events."""
    td = msgspec.json.decode(td_json)
    td["version"] = {"instance": str(version)}
    gate = ("" if twin.max_collision_probability is None else
            f", where the collision probability of the sampled neighbours exceeds {twin.max_collision_probability:g}")
    td["description"] = (f"{td.get('description', '')} Generated by the tdgen service (twin version {version}, "
                         f"hash {hash}). Every move follows a collision-free joint path (straight where that is "
                         "free, else planned with OMPL in the live scene); Cartesian moves are refused outside the "
                         f"workspace hull{gate}, where no joint configuration reaches, where every configuration "
                         "found collides, or where no path is found.").strip()
    return _finish(td, twin, generated=True)


# --- the Thing -----------------------------------------------------------------------------------
class RobotThing:
    """A RobotTwin on one Zenoh session; use as a context manager (subscribe, expose, then tear down)."""

    def __init__(self, session, settings: MeshSettings, twin: RobotTwin, *, urdf: str | None = None,
                 samples: int = DEFAULT_SAMPLES, seed: int = 0, rate: float = STATE_RATE):
        self.session, self.settings, self.keys = session, settings, settings.keys
        self.twin, self.name, self.samples, self.seed = twin, twin.name, samples, seed
        path = twin.robot.urdf_path
        self._urdf_bytes = path.read_bytes()
        self._urdf = urdf or urdf_reference(path)
        self._urdf_sha = hashlib.sha256(self._urdf_bytes).hexdigest()
        self._artefacts: dict[str, bytes] = {}
        self.client = MeshClient(session, settings)
        self.thing = t = ExposedThing(session, provisional_td(twin), self.name, self.keys)
        t.on_read("getJointposition", twin.joint_position)
        t.on_read("getCartesianposition", twin.cartesian_position)
        t.on_action("moveToJointPosition", self._move_to_joints)
        t.on_action("moveToCartesianPosition", self._move_to_cartesian)
        t.on_action("planMove", self._plan_move)
        t.on_action("stop", lambda _: {"stopped": twin.stop()})
        t.on_file(TWIN_FILE, lambda: msgspec.json.encode(self.description()), "application/json")
        t.on_file(path.name, lambda: self._urdf_bytes, URDF_TYPE)
        for name, (_, media) in ARTEFACTS.items():
            t.on_file(name, functools.partial(self._artefact, name), media)
        self.publisher = StatePublisher(t, lambda: {"getJointposition": twin.joint_position(),
                                                    "getCartesianposition": twin.cartesian_position()}, rate)
        twin.on_state(self.publisher.changed)
        self._worker = ThreadPoolExecutor(1, thread_name_prefix=f"{self.name}-td")
        self._declared: list[Any] = []
        twin.on_scene_changed(self._scene_changed)

    def description(self) -> "TwinDescription":
        """This robot's twin.json, as it stands now."""
        return self.twin.description(self._urdf, self._urdf_sha, self.twin.robot.urdf_path.name, self.samples,
                                     self.seed)

    def __enter__(self) -> "RobotThing":
        ev = self.keys.event
        self._declared.append(self.session.declare_subscriber(ev(TDGEN, "generated"), self._generated))
        self._declared.append(self.session.declare_subscriber(ev(TDGEN, "failed"), self._failed))
        self.thing.expose()
        self.publisher.start()
        self.publisher.flush()
        return self

    def __exit__(self, *exc) -> None:
        for d in reversed(self._declared):
            try:
                d.undeclare()
            except Exception:
                pass
        self.publisher.close()
        self._worker.shutdown(wait=False, cancel_futures=True)
        self.thing.destroy()

    # --- handlers ----------------------------------------------------------------------------------
    def _move_to_joints(self, joints: dict[str, float]) -> dict[str, Any]:
        try:
            return self.twin.move_to_joints(joints).answer(self.twin)
        finally:
            self.publisher.flush()  # the final state goes out before the reply (a stopped move's too)

    def _move_to_cartesian(self, target: dict[str, float]) -> dict[str, Any]:
        try:
            return self.twin.move_to_cartesian((target["x"], target["y"], target["z"])).answer(self.twin)
        finally:
            self.publisher.flush()

    def _plan_move(self, request: dict[str, Any]) -> dict[str, Any]:
        """The dry run: `{x, y, z}` or `{joints: {...}}`, never both."""
        cartesian = [axis for axis in "xyz" if axis in request]
        if cartesian and len(cartesian) < 3:
            raise BadInput(f"planMove: a Cartesian target needs x, y and z (got {', '.join(cartesian)})")
        target = (request["x"], request["y"], request["z"]) if cartesian else None
        return self.twin.plan_move(joints=request.get("joints"), target_mm=target).answer(self.twin)

    def _artefact(self, name: str) -> bytes:
        data = self._artefacts.get(name)
        if data is None:
            from twinmesh.sim.robot import WorkspacePending

            raise WorkspacePending(f"{self.name}: {name} is being generated by the tdgen service",
                                   reason="workspace-generating")
        return data

    # --- the tdgen service (Zenoh callbacks hand off to the worker) ----------------------------------
    def _generated(self, sample) -> None:
        try:
            data = msgspec.json.decode(sample.payload.to_bytes())
        except msgspec.DecodeError:
            return
        if isinstance(data, dict) and data.get("robot") == self.name:
            self._worker.submit(self._adopt, str(data.get("hash")), int(data.get("version", 0)))

    def _failed(self, sample) -> None:
        try:
            data = msgspec.json.decode(sample.payload.to_bytes())
        except msgspec.DecodeError:
            return
        if isinstance(data, dict) and data.get("robot") == self.name and data.get("version") == self.twin.version:
            log.warning("%s: the tdgen service could not generate the workspace: %s", self.name, data.get("error"))
            self.twin.set_workspace_failed(str(data.get("error")))

    def _adopt(self, hash: str, version: int) -> None:
        """Fetch the generated artefacts, check with them, serve them, replace the TD."""
        if version < self.twin.version:
            return  # generated for surroundings that have changed since; the next one is on its way
        if hash == self.twin.workspace_hash and self.thing.td.version == {"instance": str(version)}:
            return  # already serving it (the service restarted and announced it again)
        try:
            files = {name: self.client.file(TDGEN, f"{self.name}.{name}").payload
                     for name in ("td.json", *ARTEFACTS)}
            from twinmesh.sim.robot import workspace_from_csv

            workspace = workspace_from_csv(files["points.csv"])
            td = generated_td(files["td.json"], self.twin, hash, version)
        except (Problem, ValueError, msgspec.DecodeError, msgspec.ValidationError) as e:
            log.warning("%s: cannot use the generated artefacts (%s): %s", self.name, hash, e)
            return
        self._artefacts = {name: files[name] for name in ARTEFACTS}
        self.twin.set_workspace(workspace, hash)
        self.thing.update_td(td)
        log.info("%s: TD generated (hash %s, version %d, %d points)", self.name, hash, version,
                 len(workspace.positions))

    def _scene_changed(self, version: int) -> None:
        self.thing.emit_event(TWIN_CHANGED, {"robot": self.name, "version": version})


# --- the process ---------------------------------------------------------------------------------
def run(settings: MeshSettings, stop: threading.Event, urdf: str, name: str | None = None, scene: str | None = None,
        base: tuple[float, float, float, float] | None = None, samples: int = DEFAULT_SAMPLES, seed: int = 0,
        ee: str | None = None, calibration: str | None = None, max_collision_probability: float | None = None,
        speed: float | None = 1.0, planning_budget: float = 1.0) -> None:
    """Process entry: one robot in its own World (its scene's static bodies loaded) until `stop` is set.

    `base` is (x, y, z [m], yaw [deg]) in the scene frame (default: the scene's robot placement);
    `speed` None runs the simulation as fast as possible.
    """
    from twinmesh.fabric.session import open_session
    from twinmesh.robot.calibration import load_calibration
    from twinmesh.robot.model import Robot
    from twinmesh.robot.surroundings import build_into, empty_scene, load_scene
    from twinmesh.sim.robot import WORKSPACE_WAIT, Base, RobotTwin
    from twinmesh.sim.world import World

    robot = Robot.load(urdf, ee=ee)
    the_scene = load_scene(scene) if scene else empty_scene()
    if base:
        where = Base((base[0], base[1], base[2]), float(base[3]))
    else:
        where = Base(the_scene.robot.position, the_scene.robot.yaw)
    cal = load_calibration(calibration) if calibration else None
    world = World(speed=speed)
    with ExitStack() as stack:
        stack.callback(world.close)
        build_into(the_scene, world.client)
        world.start()
        twin = RobotTwin(world, robot, name or slug(robot.name), where, the_scene, calibration=cal,
                         max_collision_probability=max_collision_probability, workspace_wait=WORKSPACE_WAIT,
                         planning_budget=planning_budget)
        stack.callback(twin.close)
        session = stack.enter_context(open_session(settings))
        stack.enter_context(RobotThing(session, settings, twin, samples=samples, seed=seed))
        stack.callback(world.close)  # first on the way out: pending motions fail, their handlers answer
        log.info("%s: %s on the mesh (speed %s)", twin.name, robot.name, "max" if speed is None else f"{speed:g}")
        world.on_death(stop.set)
        stop.wait()
        if not world.stepping:
            raise SystemExit(f"{twin.name}: the simulation stopped stepping; see the log above")
