"""The TD generator on the mesh: the `tdgen` Thing generates every robot's TD and workspace artefacts.

It watches Things join (liveliness); a robot is a Thing whose TD links its twin (`rel: "twin"`,
`files/twin.json`, a `mesh.messages.scene_description.TwinDescription`). For each robot it fetches the twin over
Zenoh, runs `tdgen.generate` (the same pipeline as `twinmesh tdgen`) and serves the results as
its own files `<robot>.td.json`, `<robot>.points.csv`, `<robot>.workspace.stl` and
`<robot>.scene.json`, then emits `generated {robot, hash, version}` (or `failed {robot, version,
error}`). The robot, subscribed to `generated` before it joined, fetches them and serves its own TD
from them. A robot's `twinChanged` event (its surroundings changed) makes the service fetch the twin
again and make the new scene's artefacts. When only the scene's bodies changed (a box put on the
table or taken away), that is a live update (`tdgen.live`): the service keeps each robot's samples
(up to LIVE_ROBOTS robots, `tdgen.following`) and re-checks only those the change can touch instead of
generating again; the result is the same, byte for byte. `<robot>.flags` (the
new points.csv's sha256 and collision flags, 10 kB) lets the robot make the new points.csv from the
one it holds instead of fetching it.

Results are cached on disk under `cache_dir/<key>/` (tdgen.cache), the key derived from everything
that shapes the output (the URDF's content and its meshes', base, scene, samples, seed, end effector,
calibration, frame, the robot's name, which titles its TD, and the code that builds them): a robot
that restarts, or whose scene goes back to an earlier state, gets its files at once. A live update's
files are served from memory as soon as they are made and written to the cache after (the robot fetches
them meanwhile). The property `robots` tells, per robot,
`{status: generating|ready|failed, hash, version, seconds, cached, live, error}`.

Generations run one at a time on one thread (each may use `workers` processes for the collision
checks; by default one process up to 20 000 samples, every core above); requests for a robot that
arrive while it waits are merged, the newest twin wins. A stop does not wait for a generation under
way: its temporary directory is left behind, never a half-written cache entry.
"""
from __future__ import annotations

import logging
import queue
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, TypeVar

import msgspec

from mesh.backoff import pauses
from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.server import ExposedThing
from mesh.fabric.settings import MeshSettings
from mesh.messages.lab import RobotStatus
from mesh.messages.scene_description import TWIN_CHANGED, TWIN_REL, TwinDescription
from mesh.wot import units
from mesh.wot.problem import NotFound, Problem, TimedOut, Unavailable
from mesh.wot.thing_description import ThingDescription, decode_td, thing_id
from tdgen.artefacts import artefact_key, live_artefacts, make_artefacts, user_errors, write_entry
from tdgen.cache import ArtefactCache, artefacts_dir
from tdgen.following import Following, SceneFollower
from tdgen.remote_scene_files import fetched_twin
from tdgen.robot.errors import SceneError

if TYPE_CHECKING:
    from tdgen.generate import GenerationResult
    from tdgen.robot.calibration import Calibration
    from tdgen.robot.model import Robot
    from tdgen.robot.points_csv import Flags

    Artefact = bytes | bytearray | Flags  # a cache entry's file, in memory

log = logging.getLogger(__name__)
T = TypeVar("T")

THING = "tdgen"
ARTEFACTS = {  # file suffix -> content type; the generated file is named like the suffix
    "td.json": "application/json",
    "points.csv": "text/csv",
    "workspace.stl": "model/stl",
    "scene.json": "application/json",
}
FLAGS = "flags"  # `<robot>.flags`: the digest of its points.csv (tdgen.robot.points_csv.Flags.digest)
SCENE_FILES = "scene-files"  # cache_dir/scene-files/<sha256><suffix>: scene files fetched from robots on other hosts
WRITE_AFTER_S = 1.0  # a live update's entry is written this long after it is served (the robot fetches meanwhile)


def default_cache_dir() -> Path:
    """`$TWINMESH_CACHE/tdgen`, else in the user's cache directory (`tdgen.cache.artefacts_dir`)."""
    return artefacts_dir()


def service_td() -> ThingDescription:
    status = {"type": "object", "properties": {
        "status": {"type": "string", "enum": ["generating", "ready", "failed"]},
        "version": {"type": "integer", "minimum": 0}, "hash": {"type": "string"},
        "seconds": {"type": "number", "minimum": 0, "unit": units.SECOND}, "cached": {"type": "boolean"},
        "progress": {"type": "number", "minimum": 0, "maximum": 1, "unit": units.UNITLESS,
                     "description": "Share of the workspace samples checked so far, while generating"},
        "live": {"type": "boolean", "description": "Made by a live update: the previous scene's samples, only "
                                                   "those the change can touch checked again"},
        "error": {"type": "string"}}}
    return decode_td({
        "title": THING,
        "id": thing_id(THING),
        "description": (
            "The twinmesh TD generator. It generates the TD, sampled points (CSV), workspace hull (STL) and scene "
            "of every robot on the mesh (a Thing linking its twin, rel=twin) and serves them as files "
            "<robot>.td.json, <robot>.points.csv, <robot>.workspace.stl and <robot>.scene.json; results are "
            "cached by a hash of their inputs."),
        "properties": {
            "robots": {"title": "Robots", "description": "Per robot: generation status, input hash, twin version, "
                       "seconds taken, whether it came from the cache or a live update, the error if it failed.",
                       "type": "object", "additionalProperties": status, "readOnly": True, "observable": True},
        },
        "events": {
            "generated": {"title": "Generated", "description": "A robot's artefacts are ready to fetch.",
                          "data": {"type": "object", "required": ["robot", "hash", "version"], "properties": {
                              "robot": {"type": "string"}, "hash": {"type": "string"},
                              "version": {"type": "integer", "minimum": 0}}}},
            "failed": {"title": "Generation failed", "description": "A robot's generation failed; `error` says why.",
                       "data": {"type": "object", "required": ["robot", "version", "error"], "properties": {
                           "robot": {"type": "string"}, "version": {"type": "integer", "minimum": 0},
                           "error": {"type": "string"}}}},
        },
    })


class TdgenService:
    """The `tdgen` Thing on one session; use as a context manager."""

    def __init__(self, session, settings: MeshSettings, cache_dir: str | Path | None = None,
                 workers: int | None = None, live: bool = True):
        """`live`: follow a robot's scene changes by re-checking only the samples a change can touch
        (`tdgen.live`); False generates every scene from scratch."""
        self.session, self.settings, self.keys = session, settings, settings.keys
        self.live = live
        self.cache_dir = Path(cache_dir).expanduser() if cache_dir else default_cache_dir()
        self.follower = SceneFollower(self.cache_dir, live)  # generator thread only
        self.cache = ArtefactCache(self.cache_dir)
        self.workers = workers
        self.client = MeshClient(session, settings)
        self.thing = ExposedThing(session, service_td(), THING, self.keys)
        self.thing.on_read("robots", self.robots)
        self.thing.on_any_file(self._file)
        self._robots: dict[str, RobotStatus] = {}
        self._ready: dict[str, str] = {}  # robot -> hash of its latest artefacts (served while others generate)
        self._digests: dict[str, tuple[str, bytes]] = {}  # robot -> (hash, digest of its points.csv)
        self._unwritten: dict[str, tuple[str, dict[str, Artefact]]] = {}  # robot -> a live update's (hash, files)
        self._twin_files: dict[str, str] = {}  # robot -> the name of its twin file (from its TD's link)
        self._pending: dict[str, TwinDescription] = {}
        self._lock = threading.Lock()
        self._fetching = ThreadPoolExecutor(4, thread_name_prefix="tdgen-fetch")
        self._writing = ThreadPoolExecutor(1, thread_name_prefix="tdgen-write")  # live updates' cache entries
        self._stopping = threading.Event()
        # a daemon thread, not an executor: a stop must not wait for a generation to finish
        self._queue: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._generator = threading.Thread(target=self._generate_loop, name="tdgen-generate", daemon=True)
        self._declared: list[Any] = []

    def __enter__(self) -> "TdgenService":
        from mesh.fabric.directory import Directory

        self.cache_dir.mkdir(parents=True, exist_ok=True)
        self._generator.start()
        self.thing.expose()
        self._declared.append(self.session.declare_subscriber(self.keys.event("*", TWIN_CHANGED), self._twin_changed))
        directory = Directory(self.session, self.keys, on_join=self._joined, tokens="twin")  # robots alone
        self._declared.append(directory)
        self.client.presence = directory
        log.info("tdgen service on the mesh (cache %s)", self.cache_dir)
        return self

    def __exit__(self, *exc) -> None:
        for d in reversed(self._declared):
            try:
                (d.close if hasattr(d, "close") else d.undeclare)()
            except Exception:  # the session may be closing
                pass
        self._fetching.shutdown(wait=False, cancel_futures=True)
        self._stopping.set()
        self._writing.shutdown(wait=True)  # the entries served from memory are written now (some ms each)
        self._queue.put(None)
        self.thing.destroy()

    # --- the Thing -------------------------------------------------------------------------------
    def robots(self) -> dict[str, Any]:
        with self._lock:
            return {name: msgspec.to_builtins(s) for name, s in sorted(self._robots.items())}

    def _set_status(self, robot: str, status: RobotStatus) -> None:
        with self._lock:
            self._robots[robot] = status
        self.thing.emit_property_change("robots", self.robots())

    def _file(self, name: str) -> tuple[bytes, str]:
        if name.endswith(f".{FLAGS}"):
            return self._digest(name.removesuffix(f".{FLAGS}")), "application/octet-stream"
        for suffix in ARTEFACTS:
            robot = name.removesuffix(f".{suffix}")
            if robot != name:
                break
        else:
            raise NotFound(f"tdgen has no file {name!r} (files are <robot>.{{{','.join(ARTEFACTS)}}})")
        with self._lock:
            status, ready = self._robots.get(robot), self._ready.get(robot)
            unwritten = self._unwritten.get(robot)
        if ready is None:
            if status is not None and status.status == "generating":
                raise Unavailable(f"{robot}'s artefacts are being generated", reason="workspace-generating")
            raise NotFound(f"tdgen has generated nothing for {robot!r}")
        if unwritten is not None and unwritten[0] == ready:  # a live update's, not yet on disk
            content = unwritten[1][suffix]
            return bytes(content if isinstance(content, (bytes, bytearray)) else content.data), ARTEFACTS[suffix]
        return (self.cache_dir / ready / suffix).read_bytes(), ARTEFACTS[suffix]

    def _digest(self, robot: str) -> bytes:
        """`<robot>.flags`: the digest of its points.csv (`points_csv.Flags.digest`), with which a robot that
        holds the previous file makes the new one after a scene change instead of fetching the whole file."""
        from tdgen.robot import points_csv

        with self._lock:
            ready, held = self._ready.get(robot), self._digests.get(robot)
        if ready is None:
            raise NotFound(f"tdgen has generated nothing for {robot!r}")
        if held is None or held[0] != ready:
            held = (ready, points_csv.Flags((self.cache_dir / ready / "points.csv").read_bytes()).digest())
            with self._lock:
                self._digests[robot] = held
        return held[1]

    # --- discovery (Zenoh threads: hand off, never block) -----------------------------------------
    def _joined(self, thing: str) -> None:
        if thing != THING:
            self._fetching.submit(self._consider, thing)

    def _twin_changed(self, sample) -> None:
        parsed = self.keys.parse(str(sample.key_expr))
        if parsed is not None:
            self._fetching.submit(self._consider, parsed.thing)

    def _consider(self, thing: str) -> None:
        """Fetch a Thing's TD; if it links a twin, fetch that and ask for a generation. For a robot whose
        twin was read before (its `twinChanged`), the twin file at once: one round trip less."""
        try:
            name = self._twin_files.get(thing)
            twin = None
            if name is not None:
                try:
                    twin = msgspec.json.decode(self.client.file(thing, name).payload, type=TwinDescription)
                except Problem:  # restarted under another name for its twin: ask its TD
                    twin = None
            if twin is None:
                td = self._patiently(lambda: self.client.td(thing))
                link = next((link for link in td.links if link.rel == TWIN_REL), None)
                if link is None:
                    return
                name = link.href.rsplit("/", 1)[-1]
                payload = self._patiently(lambda: self.client.file(thing, name).payload)
                twin = msgspec.json.decode(payload, type=TwinDescription)
                self._twin_files[thing] = name
        except (Problem, msgspec.DecodeError, msgspec.ValidationError) as e:
            log.warning("%s: cannot read its twin: %s", thing, e)
            return
        if twin.robot != thing:
            log.warning("%s: its twin describes %r; ignored", thing, twin.robot)
            return
        self.request(twin)

    def _patiently(self, ask: Callable[[], T], attempts: int = 8) -> T:
        """`ask()`, again with backoff while the Thing is unreachable or silent. A peer that just joined may
        not be reachable by queries yet; a router taking thousands of sessions may answer late (a TD timed
        out while 10,000 devices joined); a robot that just started may not answer for seconds while it
        compiles its loops on a fresh machine (its twin file timed out, and it never got its TD)."""
        for attempt, pause in zip(range(attempts), pauses(0.05, 1.0)):
            try:
                return ask()
            except (Unavailable, TimedOut):
                if attempt == attempts - 1:
                    raise
                time.sleep(pause)
        raise AssertionError("unreachable")

    # --- generation ------------------------------------------------------------------------------
    def request(self, twin: TwinDescription) -> None:
        """Generate (or fetch from the cache) for this twin; merged with a request still waiting."""
        with self._lock:
            waiting = twin.robot in self._pending
            self._pending[twin.robot] = twin
        if not waiting:
            self._queue.put(twin.robot)

    def _generate_loop(self) -> None:
        while (robot := self._queue.get()) is not None:
            with self._lock:
                twin = self._pending.pop(robot, None)
            if twin is None:
                continue
            try:
                self.generate(twin)
            except Exception:  # publishing on a closing session; the next request tries again
                log.exception("%s: generation could not be reported", robot)
        self.follower.close()  # stopped: their pybullet worlds go

    def generate(self, twin: TwinDescription) -> RobotStatus:
        """Make the artefacts of `twin` available (cache, live update or generation), publish the status and
        the event."""
        started = time.perf_counter()
        try:
            twin, paths = fetched_twin(twin, self.cache_dir / SCENE_FILES, lambda name: self._patiently(
                lambda: self.client.file(twin.robot, name).payload))
        except SceneError as e:  # a file neither here nor served by the robot: said, other robots go on
            return self._failed(twin, artefact_key(twin), started, e)
        key = artefact_key(twin, paths)
        cached = self.cache.has(key)
        following = None
        generated: list[tuple[Robot, Calibration | None, GenerationResult]] = []  # kept for the next scene change
        unwritten: dict[str, Artefact] | None = None  # a live update's files: served now, written after
        if not cached:
            self._set_status(twin.robot, RobotStatus("generating", twin.version, key, progress=0.0))
            try:
                following = self.follower.live_update(twin)
                if following is not None:
                    unwritten = live_artefacts(twin, following.samples, following.robot, following.calibration,
                                               paths)
                    self._progress_reporter(twin, key)(1.0)
                else:
                    make_artefacts(twin, self.cache, key, self.workers, self._progress_reporter(twin, key),
                                   keep=lambda *made: generated.append(made), paths=paths)
            except Exception as e:  # noqa: BLE001 - every failure is reported on the mesh
                return self._failed(twin, key, started, e)
        seconds = round(time.perf_counter() - started, 3)
        status = RobotStatus("ready", twin.version, key, seconds, cached, live=True if following else None)
        with self._lock:
            self._ready[twin.robot] = key
            if following is not None:
                self._digests[twin.robot] = (key, following.samples.flags.digest())
            if unwritten is not None:
                self._unwritten[twin.robot] = (key, unwritten)
        self._set_status(twin.robot, status)
        log.info("%s: artefacts ready (%s, %.3f s, version %d, hash %s)", twin.robot,
                 "cached" if cached else "followed live" if following else "generated", seconds, twin.version, key)
        self.thing.emit_event("generated", {"robot": twin.robot, "hash": key, "version": twin.version})
        if unwritten is not None:  # on disk once the robot has them (not in its way)
            self._writing.submit(self._write_entry, twin.robot, key, unwritten)
        kept = self.follower.follow(twin, key, following or (self.follower.held(twin, *generated[0]) if generated else None))
        if kept is not None:
            self._know_digest(twin.robot, key, kept)
        return status

    def _failed(self, twin: TwinDescription, key: str, started: float, e: Exception) -> RobotStatus:
        expected = isinstance(e, user_errors())
        error = str(e) if expected else f"{type(e).__name__}: {e}"
        log.warning("%s: generation failed: %s", twin.robot, error, exc_info=not expected)
        status = RobotStatus("failed", twin.version, key, round(time.perf_counter() - started, 3), False, error)
        self._set_status(twin.robot, status)
        self.thing.emit_event("failed", {"robot": twin.robot, "version": twin.version, "error": error})
        return status

    def _know_digest(self, robot: str, key: str, kept: Following) -> None:
        """The robot asks for its points.csv's digest next (`_digest`): from the samples in memory, not the file."""
        with self._lock:
            known = self._digests.get(robot, ("", b""))[0] == key
        if not known:
            digest = kept.samples.flags.digest()
            with self._lock:
                if self._ready.get(robot) == key:
                    self._digests[robot] = (key, digest)

    def _write_entry(self, robot: str, key: str, files: dict[str, Artefact]) -> None:
        self._stopping.wait(WRITE_AFTER_S)
        try:
            write_entry(self.cache, key, files)
        except OSError:  # a full disk: the entry is served from memory until the robot's next change
            log.exception("%s: cannot write its artefacts to the cache", robot)
            return
        with self._lock:
            if self._unwritten.get(robot, ("", {}))[0] == key:
                del self._unwritten[robot]

    def _progress_reporter(self, twin: TwinDescription, key: str) -> Callable[[float], None]:
        """Publishes the generation's progress at most twice a second (and its end)."""
        last = [0.0]

        def report(fraction: float) -> None:
            now = time.monotonic()
            if now - last[0] >= 0.5 or fraction >= 1.0:
                last[0] = now
                self._set_status(twin.robot, RobotStatus("generating", twin.version, key,
                                                         progress=round(min(fraction, 1.0), 3)))
        return report


def run(settings: MeshSettings, stop: threading.Event, cache_dir: str | None = None,
        workers: int | None = None, live: bool = True) -> None:
    """Process entry (`twinmesh up` starts it after the router): serve until `stop` is set."""
    from mesh.fabric.session import open_session

    with open_session(settings, service=True) as session, TdgenService(session, settings, cache_dir, workers, live):
        stop.wait()
