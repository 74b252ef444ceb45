"""The Rerun logger: records everything the mesh publishes to an `.rrd` file (SPEC §6).

Three sides, so that nothing blocks a Zenoh callback and one thread alone owns the file:
- the Zenoh side: a subscriber on `<prefix>/**` and a `Directory` (liveliness). Their callbacks
  only stamp each message with its time (the sample's Zenoh timestamp, else the clock) and queue it;
- the fetcher thread: asks each Thing that joins for its TD and current property values (network
  round trips) and queues the answers like any other message, so every series starts at the join;
  from the `world` Thing of a simulated scene it also fetches `scene.json` and the robots' URDFs
  (again when the world re-publishes its TD); from a robot Thing (its TD links `twin.json`) its
  twin description and URDF, and its workspace points and hull once linked (parsed here, off the
  writer; again when the robot re-publishes its TD);
- the writer thread: owns the `RecordingStream`; it takes messages in arrival order, sets the
  timelines (`time`: wall clock, `seq`: message number), logs what `mesh.recorder.mapping` makes of
  them and flushes every second; on stop it drains the queue, flushes and closes the file, which
  then has its footer (`rerun rrd verify` passes). The world's scene and its `poses` go to
  `mesh.recorder.scene_drawer.SceneDrawer`, which batches the fast poses into a few writes a second; robot
  Things, their `getJointposition` values and their workspaces to `mesh.recorder.robots.RobotDrawer`.
  The writer sends the recording's layout (`lab_blueprint`) whenever the set of drawn robots changes.

Later message kinds are new branches of `_Writer.draw`/`_Writer.entries` and new mapping
functions; the threads stay as they are.
"""
from __future__ import annotations

import logging
import queue
import sys
import threading
import time
from pathlib import Path
from typing import Any, NamedTuple

import msgspec

from mesh.fabric.directory import Directory
from mesh.fabric.keys import Keys
from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.settings import MeshSettings
from mesh.messages.scene_description import POSES_PROPERTY, WORLD_THING, Poses, TwinDescription
from mesh.recorder import mapping
from mesh.recorder.robots import (
    JOINTS_PROPERTY,
    DrawnWorkspace,
    RobotDrawer,
    RobotFiles,
    WorkspaceFiles,
    is_robot,
    read_robot,
)
from mesh.recorder.scene_drawer import BATCH_AGE, SceneDrawer, SceneFiles, lab_blueprint, read_scene
from mesh.wot.problem import BadInput, Problem
from mesh.wot.thing_description import ThingDescription, decode_td
from mesh.wot.validate import validate

log = logging.getLogger(__name__)

DEFAULT_DIR = Path("recordings")
FLUSH_EVERY = 1.0  # seconds; a killed recorder loses at most about this much
QUEUE_LIMIT = 200_000  # messages waiting for the writer; beyond it new ones are dropped and counted
READY_TIMEOUT = 10.0  # how long start() waits for the TDs of the Things already alive
SETTLE_ROUND, SETTLE_TIMEOUT = 0.2, 3.0  # start() asks who is alive until a round adds nobody
CLOSING_GRACE = 0.25  # s of listening after a stop, for publications still in flight


class Message(NamedTuple):
    """A queued message: a Zenoh sample (`key` is its key expression), a property value the fetcher
    read ("read", stamped when it was asked for), a join/leave/notice, the
    scene a world Thing describes (`key` is its name, `payload` a JSON `SceneFiles`), or what a robot
    Thing links (`payload` a `RobotFiles` or a parsed `DrawnWorkspace`)."""

    kind: str  # "sample" | "read" | "join" | "leave" | "notice" | "scene" | "robot" | "workspace"
    key: str  # the sample's key; the Thing's name for join/leave/scene/robot/workspace
    payload: bytes | str | Any
    time: float  # seconds since the epoch


_STOP = Message("stop", "", b"", 0.0)


def default_path(now: float | None = None) -> Path:
    """`recordings/twinmesh-YYYYmmdd-HHMMSS.rrd`: a new file per run, never an old one overwritten."""
    return DEFAULT_DIR / time.strftime("twinmesh-%Y%m%d-%H%M%S.rrd", time.localtime(now))


def prepare_path(path: str | Path | None) -> Path:
    """The file to write: refuses a directory, creates missing parent directories."""
    target = Path(path) if path else default_path()
    if target.is_dir():
        raise ValueError(f"{target} is a directory; give a file path such as {target / 'twinmesh.rrd'}")
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"cannot create the folder {target.parent} for the recording: {e.strerror}") from None
    return target


class Recorder:
    """Records the mesh of `session` into `rec` (a RecordingStream the writer thread then owns)."""

    def __init__(self, session, settings: MeshSettings, rec, batch_age: float = BATCH_AGE):
        """`batch_age`: how long joint values and poses wait to be written together (one chunk per entity
        each time): the live view waits longer than a file, so that a browser has fewer chunks to take in."""
        self.keys: Keys = settings.keys
        self.client = MeshClient(session, settings)
        self.session = session
        self.inbox: queue.Queue[Message] = queue.Queue(QUEUE_LIMIT)
        self.dropped = 0
        self.writer = _Writer(rec, self.keys, self.inbox, batch_age)
        self.fetcher = _Fetcher(self.client, self._queue)
        self._sub = None
        self._directory: Directory | None = None
        self._world_td = self.keys.td(WORLD_THING)

    def start(self, ready_timeout: float = READY_TIMEOUT) -> list[str]:
        """Subscribe, then wait until the Things alive now have been asked for their TDs and values.

        Returns their names. Each of them has by then answered a query routed after the
        subscription was declared, so it knows of the subscriber: what it publishes next is recorded.
        A fresh peer may ask before the router's declarations reach it (all of them or some) and see
        fewer Things than are alive: it asks again until a round adds nobody, for up to SETTLE_TIMEOUT.
        """
        self.writer.start()
        self.fetcher.start()
        self._sub = self.session.declare_subscriber(self.keys.everything(), self._sample)
        self._directory = Directory(self.session, self.keys, on_join=self._joined, on_leave=self._left)
        deadline = time.monotonic() + SETTLE_TIMEOUT
        alive: set[str] = set()
        while True:
            seen = alive | set(self.client.things(timeout=1.0)) | set(self._directory.alive())
            if (alive and seen == alive) or time.monotonic() > deadline:
                break
            alive = seen
            time.sleep(SETTLE_ROUND)
        names = sorted(seen)
        if not self.fetcher.wait_fetched(names, ready_timeout):
            log.warning("not all of %s answered with their TDs within %.0f s", names, ready_timeout)
        return names

    def close(self) -> None:
        """Stop listening, write what is queued, close the file. Publications still on their way
        when the stop came (a value put just before a Ctrl-C of the whole lab) get a moment to arrive."""
        time.sleep(CLOSING_GRACE)
        if self._directory is not None:
            self._directory.close()
        if self._sub is not None:
            self._sub.undeclare()
        if self.fetcher.is_alive():
            self.fetcher.stop()
        if self.dropped:
            text = f"the recorder dropped {self.dropped} messages (its queue was full)"
            self._queue(Message("notice", "", text, time.time()))
        while self.writer.is_alive():  # the queue may be full: the writer is still draining it
            try:
                self.inbox.put(_STOP, timeout=0.5)
                break
            except queue.Full:
                continue
        if self.writer.ident is not None:
            self.writer.join()

    def __enter__(self) -> "Recorder":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # --- Zenoh callbacks: stamp and queue, nothing else ------------------------------------------
    def _sample(self, sample) -> None:
        key = str(sample.key_expr)
        payload = sample.payload.to_bytes()
        self._queue(Message("sample", key, payload, _sample_time(sample)))
        if key == self._world_td:  # a world that changes its scene re-publishes its TD
            self.fetcher.todo.put_nowait((WORLD_THING, None))
        elif key.endswith("/td"):  # a robot's regenerated workspace comes with a re-published TD
            parsed = self.keys.parse(key)
            if parsed is not None and parsed.kind == "td":
                self.fetcher.todo.put_nowait((parsed.thing, payload))

    def _joined(self, thing: str) -> None:
        self._queue(Message("join", thing, b"", time.time()))
        self.fetcher.todo.put_nowait((thing, None))

    def _left(self, thing: str) -> None:
        self._queue(Message("leave", thing, b"", time.time()))
        self.fetcher.forget(thing)

    def _queue(self, message: Message) -> None:
        try:
            self.inbox.put_nowait(message)
        except queue.Full:
            self.dropped += 1


def _sample_time(sample) -> float:
    ts = sample.timestamp
    if ts is not None:
        try:
            return ts.get_time().timestamp()  # an aware UTC datetime
        except (AttributeError, ValueError, OverflowError):
            pass
    return time.time()


class _Fetcher(threading.Thread):
    """Asks joining Things for their TD and readable property values, off the Zenoh threads.

    `todo` holds (thing, None) for a Thing that joined (or a world to fetch again) and (thing, TD
    bytes) for a TD a Thing re-published: only what the TD links is fetched again then."""

    def __init__(self, client: MeshClient, put):
        super().__init__(name="recorder-fetcher", daemon=True)
        self.client = client
        self.keys = client.keys
        self.put = put
        self.todo: queue.Queue[tuple[str, bytes | None]] = queue.Queue()
        self._fetched: set[str] = set()
        self._workspaces = WorkspaceFiles()
        self._cond = threading.Condition()
        self._halt = threading.Event()

    def run(self) -> None:
        pending: list[tuple[str, bytes | None]] = []
        while not self._halt.is_set():
            try:
                if not pending:
                    pending.append(self.todo.get(timeout=0.2))
                while True:
                    pending.append(self.todo.get_nowait())
            except queue.Empty:
                if not pending:
                    continue
            # the world first: a robot it simulates is then drawn in it, never first in a world of its own
            first = next((i for i, (name, _) in enumerate(pending) if name == WORLD_THING), 0)
            thing, td = pending.pop(first)
            try:
                if td is None:
                    self.fetch(thing)
                else:
                    self.fetch_links(thing, td)
            except Exception as e:  # never let one Thing stop the recording
                log.exception("fetching %s failed", thing)
                self.put(Message("notice", "", f"could not fetch {thing}: {e}", time.time()))
            if td is not None:
                continue
            with self._cond:
                self._fetched.add(thing)
                self._cond.notify_all()

    def fetch(self, thing: str) -> None:
        try:
            raw = self.client.td_bytes(thing)
            td = decode_td(raw)
        except (Problem, msgspec.DecodeError, msgspec.ValidationError) as e:
            self.put(Message("notice", "", f"no TD from {thing}: {e}", time.time()))
            return
        self.put(Message("sample", self.keys.td(thing), raw, time.time()))
        if thing == WORLD_THING:
            self.fetch_scene(thing)  # before the first poses are read, so they find the robots drawn
        twin = self.fetch_robot(thing, td) if is_robot(td) else None  # before its joints, likewise
        for name, prop in td.properties.items():
            if prop.writeOnly or self._halt.is_set():
                continue
            key = self.keys.property(thing, name)
            asked = time.time()
            try:
                reply = self.client.request(key, thing=thing)
            except Problem as e:
                self.put(Message("notice", "", f"could not read {thing}/{name}: {e}", time.time()))
                continue
            self.put(Message("read", key, reply.payload, asked))
        if twin is not None:
            self.fetch_workspace(thing, td, twin)

    def fetch_links(self, thing: str, raw: bytes) -> None:
        """A re-published TD: a robot's twin, URDF and workspace again (the writer skips what is unchanged)."""
        try:
            td = decode_td(raw)
        except (msgspec.DecodeError, msgspec.ValidationError):
            return  # recorded as it is by the writer, which says what is wrong with it
        if is_robot(td):
            twin = self.fetch_robot(thing, td)
            if twin is not None and not self._halt.is_set():
                self.fetch_workspace(thing, td, twin)

    def fetch_robot(self, thing: str, td: ThingDescription) -> TwinDescription | None:
        """A robot Thing's twin.json and URDF, queued as one "robot" message; returns the twin."""
        try:
            files = read_robot(thing, td, lambda name: self.client.file(thing, name).payload)
        except (Problem, msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError) as e:
            self.put(Message("notice", "", f"no robot model from {thing}: {e}", time.time()))
            return None
        self.put(Message("robot", thing, files, time.time()))
        return files.twin

    def fetch_workspace(self, thing: str, td: ThingDescription, twin: TwinDescription) -> None:
        """A robot's points and hull, parsed here, when its TD links them and they changed."""
        try:
            workspace = self._workspaces.read(thing, td, twin, lambda name: self.client.file(thing, name).payload)
        except Exception as e:  # unreachable, malformed CSV or STL: said in the log, the recording goes on
            self.put(Message("notice", "", f"no workspace from {thing}: {e}", time.time()))
            return
        if workspace is not None:
            self.put(Message("workspace", thing, workspace, time.time()))

    def fetch_scene(self, thing: str) -> None:
        """The world's `scene.json`, the URDF of each of its robots and its bodies' files, queued as one "scene"
        message."""
        try:
            files = read_scene(lambda name: self.client.file(thing, name).payload)
        except (Problem, msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError) as e:
            self.put(Message("notice", "", f"no scene from {thing}: {e}", time.time()))
            return
        self.put(Message("scene", thing, msgspec.json.encode(files), time.time()))

    def forget(self, thing: str) -> None:
        with self._cond:
            self._fetched.discard(thing)

    def wait_fetched(self, things: list[str], timeout: float) -> bool:
        with self._cond:
            return self._cond.wait_for(lambda: set(things) <= self._fetched, timeout)

    def stop(self, timeout: float = 1.0) -> None:
        """Stop between two requests; a Thing slow to answer must not delay closing the file."""
        self._halt.set()
        self.join(timeout)


class _Writer(threading.Thread):
    """The one thread that touches the RecordingStream."""

    def __init__(self, rec, keys: Keys, inbox: queue.Queue, batch_age: float = BATCH_AGE):
        super().__init__(name="recorder-writer", daemon=True)
        self.rec = rec
        self.keys = keys
        self.inbox = inbox
        self.tds: dict[str, ThingDescription] = {}
        self.dropped: dict[str, int] = {}  # publications not recorded (not allowed by their TD), per affordance
        self.seq = 0
        self.scene = SceneDrawer(rec, batch_age=batch_age)
        self.robots = RobotDrawer(rec, self.scene, batch_age=batch_age)
        self._poses_key = keys.property(WORLD_THING, POSES_PROPERTY)
        self._joints_suffix = f"/properties/{JOINTS_PROPERTY}"
        self._styled: set[str] = set()  # entity paths whose static style is logged
        self._layout = b""  # what the blueprint last sent was made from
        self._published: dict[str, float] = {}  # key -> time of its latest publication written

    def run(self) -> None:
        last_flush = time.monotonic()
        try:
            while True:
                try:
                    message = self.inbox.get(timeout=0.2)
                except queue.Empty:
                    message = None
                if message is _STOP:
                    break
                if message is not None:
                    self.write(message)
                if self.scene.flush_due() or self.robots.flush_due():
                    self.flush_scene()
                if time.monotonic() - last_flush >= FLUSH_EVERY:
                    self.rec.flush()
                    last_flush = time.monotonic()
        finally:
            self.flush_scene()
            self.rec.flush()
            self.rec.disconnect()  # closes the file with its footer

    def flush_scene(self) -> None:
        for drawer, what in ((self.scene, "the world's poses"), (self.robots, "the robots' joints")):
            try:
                drawer.flush()
            except Exception as e:  # a bad batch must not end the recording
                log.exception("writing %s failed", what)
                self.log_entries(mapping.notice_entries(f"could not record {what}: {e}"))

    def write(self, message: Message) -> None:
        if message.kind == "read":  # a value read while a change was published may arrive after it
            if self._published.get(message.key, float("-inf")) >= message.time:
                return  # a publication since the read was asked is the newer value
            message = message._replace(kind="sample")
        elif message.kind == "sample":
            self._published[message.key] = max(message.time, self._published.get(message.key, message.time))
        try:
            if self.draw(message):
                return
            entries = self.entries(message)
        except Exception as e:  # a malformed payload is logged as such, the recording goes on
            entries = mapping.notice_entries(f"could not record {message.key}: {e}")
        if entries:
            self.stamp(message)
            self.log_entries(entries)

    def stamp(self, message: Message, sim_time: float | None = None) -> int:
        """Set the timelines for what is logged next; returns the message's number (`seq`)."""
        seq = self.seq
        self.seq += 1
        self.rec.set_time("time", timestamp=message.time)
        self.rec.set_time("seq", sequence=seq)
        sim_time = self.scene.sim_time if sim_time is None else sim_time
        if sim_time is not None:  # anything after a world's poses also has the latest simulated time
            self.rec.set_time("sim_time", duration=sim_time)
        return seq

    def draw(self, message: Message) -> bool:
        """A world's scene and poses go to the scene drawer, robot Things' files and joints to the
        robot drawer; True when `message` was one of them."""
        if message.kind == "scene":
            files = msgspec.json.decode(message.payload, type=SceneFiles)
            problems = self.scene.draw_scene(files, message.time, self.stamp(message))
            problems += self.robots.world_changed()
            self.log_entries([e for p in problems for e in mapping.notice_entries(p)])
            self.send_layout()
            return True
        if message.kind == "robot":
            assert isinstance(message.payload, RobotFiles)
            problems = self.robots.draw_robot(message.payload)
            self.stamp(message)
            self.log_entries([e for p in problems for e in mapping.notice_entries(p)])
            self.send_layout()
            return True
        if message.kind == "workspace":
            assert isinstance(message.payload, DrawnWorkspace)
            entries = self.robots.draw_workspace(message.payload)
            self.stamp(message)
            self.log_entries(entries)
            return True
        if message.kind == "sample" and message.key == self._poses_key:
            poses = msgspec.json.decode(message.payload, type=Poses)
            self.log_entries(self.scene.add_poses(poses, message.time, self.stamp(message, poses.time)))
            return True
        if message.kind == "sample" and message.key.endswith(self._joints_suffix):
            parsed = self.keys.parse(message.key)
            if parsed is not None and self.robots.knows(parsed.thing):
                values = msgspec.json.decode(message.payload) if message.payload else None
                self.robots.add_joints(parsed.thing, values, message.time, self.stamp(message), self.scene.sim_time)
                return True
        return False

    def send_layout(self) -> None:
        """The lab's blueprint, when what it shows changed (a scene drawn, a robot Thing drawn)."""
        scene, things, own = self.scene.scene, self.robots.bases(), self.robots.own_worlds()
        layout = msgspec.json.encode([scene, list(self.scene.robots), things, own])
        if (scene is None and not things and not own) or layout == self._layout:
            return
        self._layout = layout
        self.rec.send_blueprint(lab_blueprint(scene, list(self.scene.robots), things, own))

    def log_entries(self, entries: list[mapping.Entry]) -> None:
        for e in entries:
            if e.static:
                if e.path in self._styled:
                    continue
                self._styled.add(e.path)
            self.rec.log(e.path, e.archetype, static=e.static)

    def _allowed(self, td: ThingDescription | None, thing: str, kind: str, name: str, value: Any) -> bool:
        """Only values the Thing's TD allows are recorded (anyone on the mesh can publish): a value of an
        unknown Thing or affordance, or one that breaks its schema, is dropped, counted, logged once."""
        affordance = td.affordance(kind, name) if td is not None else None  # type: ignore[arg-type]
        why = "no TD for it" if affordance is None else None
        if affordance is not None:
            schema = affordance if kind == "properties" else affordance.data
            try:
                if value is not None or kind == "properties":
                    validate(value, schema, name)
            except BadInput as e:
                why = e.detail
        if why is None:
            return True
        key = f"{thing}/{kind}/{name}"
        self.dropped[key] = self.dropped.get(key, 0) + 1
        if self.dropped[key] == 1:
            log.warning("not recording a publication on %s (%s); further ones are dropped silently", key, why)
        return False

    def entries(self, message: Message) -> list[mapping.Entry]:
        if message.kind in ("join", "leave"):
            if message.kind == "leave":
                self.tds.pop(message.key, None)
            return mapping.presence_entries(message.key, message.kind == "join")
        if message.kind == "notice":
            return mapping.notice_entries(str(message.payload))
        parsed = self.keys.parse(message.key)
        if parsed is None:
            return []  # not a Thing's key (e.g. a world's, later)
        if parsed.kind == "td":
            td = self.tds[parsed.thing] = decode_td(message.payload)
            if is_robot(td):
                self.robots.set_td(parsed.thing, td)
            return mapping.td_entries(parsed.thing, td)
        value = msgspec.json.decode(message.payload) if message.payload else None
        known = self.tds.get(parsed.thing)
        if parsed.kind in ("properties", "events") and not self._allowed(known, parsed.thing, parsed.kind,
                                                                         parsed.name, value):
            return []
        if parsed.kind == "properties":
            schema = known.properties.get(parsed.name) if known else None
            return mapping.property_entries(parsed.thing, parsed.name, value, schema)
        if parsed.kind == "events":
            return mapping.event_entries(parsed.thing, parsed.name, value)
        if parsed.kind == "actions":
            drawn = self.robots.draw_path(parsed.thing, value) if self.robots.knows(parsed.thing) else []
            return mapping.action_entries(parsed.thing, parsed.name, value) + drawn
        return []


def run(settings: MeshSettings, stop: threading.Event, path: str | None = None) -> None:
    """Process entry (`twinmesh record`, `twinmesh up --record`): record until `stop` is set."""
    import rerun as rr

    from mesh.fabric.session import is_connected, open_session

    try:
        target = prepare_path(path)
    except ValueError as e:
        raise SystemExit(f"twinmesh record: {e}") from None
    rec = rr.RecordingStream("twinmesh")
    rec.save(str(target))
    rec.send_recording_name(f"twinmesh {settings.prefix} {time.strftime('%Y-%m-%d %H:%M:%S')}")
    with open_session(settings, service=True) as session, Recorder(session, settings, rec) as recorder:
        alive = recorder.start()
        reach = "" if is_connected(session) else f"; no lab reachable yet at {', '.join(settings.connect)}"
        print(f"recording to {target} ({len(alive)} things alive{reach})", file=sys.stderr, flush=True)
        stop.wait()
    print(f"recording saved: {target}", file=sys.stderr, flush=True)
