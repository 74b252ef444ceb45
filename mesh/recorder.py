"""The Rerun logger: records everything the mesh publishes to an `.rrd` file (SPEC §6).

Three sides, so that nothing blocks a Zenoh callback and one thread alone owns the file:
- the Zenoh side: a subscriber on `<prefix>/**` and a `Directory` (liveliness). Their callbacks
  only stamp each message with its time (the sample's Zenoh timestamp, else the clock) and queue it;
- the fetcher thread: asks each Thing that joins for its TD and current property values (network
  round trips) and queues the answers like any other message, so every series starts at the join;
  from the `world` Thing of a simulated scene it also fetches `scene.json` and the robots' URDFs
  (again when the world re-publishes its TD);
- the writer thread: owns the `RecordingStream`; it takes messages in arrival order, sets the
  timelines (`time`: wall clock, `seq`: message number), logs what `mesh.rerun_mapping` makes of
  them and flushes every second; on stop it drains the queue, flushes and closes the file, which
  then has its footer (`rerun rrd verify` passes). The world's scene and its `poses` go to
  `mesh.rerun_scene.SceneDrawer`, which batches the fast poses into a few writes a second.

Later message kinds (workspace points) are new branches of `_Writer.entries` and new mapping
functions; the threads stay as they are.
"""
from __future__ import annotations

import logging
import queue
import sys
import threading
import time
from pathlib import Path
from typing import NamedTuple

import msgspec

from mesh import rerun_mapping as mapping
from mesh.consumer import MeshClient
from mesh.directory import Directory
from mesh.keys import Keys
from mesh.problem import Problem
from mesh.rerun_scene import SceneDrawer, SceneFiles
from mesh.scene_model import POSES_PROPERTY, SCENE_FILE, WORLD_THING, Poses, SceneDescription
from mesh.settings import MeshSettings
from mesh.td import ThingDescription, decode_td

log = logging.getLogger(__name__)

DEFAULT_DIR = Path("recordings")
FLUSH_EVERY = 1.0  # seconds; a killed recorder loses at most about this much
QUEUE_LIMIT = 200_000  # messages waiting for the writer; beyond it new ones are dropped and counted
READY_TIMEOUT = 10.0  # how long start() waits for the TDs of the Things already alive


class Message(NamedTuple):
    """A queued message: a Zenoh sample (`key` is its key expression), a join/leave/notice, or the
    scene a world Thing describes (`key` is its name, `payload` a JSON `SceneFiles`)."""

    kind: str  # "sample" | "join" | "leave" | "notice" | "scene"
    key: str  # the sample's key; the Thing's name for join/leave
    payload: bytes | str
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

    def __init__(self, session, settings: MeshSettings, rec):
        self.keys: Keys = settings.keys
        self.client = MeshClient(session, settings)
        self.session = session
        self.inbox: queue.Queue[Message] = queue.Queue(QUEUE_LIMIT)
        self.dropped = 0
        self.writer = _Writer(rec, self.keys, self.inbox)
        self.fetcher = _Fetcher(self.client, self._queue)
        self._sub = None
        self._directory: Directory | None = None
        self._world_td = self.keys.td(WORLD_THING)

    def start(self, ready_timeout: float = READY_TIMEOUT) -> list[str]:
        """Subscribe, then wait until the Things alive now have been asked for their TDs and values.

        Returns their names. Each of them has by then answered a query routed after the
        subscription was declared, so it knows of the subscriber: what it publishes next is recorded.
        """
        self.writer.start()
        self.fetcher.start()
        self._sub = self.session.declare_subscriber(self.keys.everything(), self._sample)
        self._directory = Directory(self.session, self.keys, on_join=self._joined, on_leave=self._left)
        alive = self.client.things()
        if not self.fetcher.wait_fetched(alive, ready_timeout):
            log.warning("not all of %s answered with their TDs within %.0f s", alive, ready_timeout)
        return alive

    def close(self) -> None:
        """Stop listening, write what is queued, close the file."""
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
        self._queue(Message("sample", key, sample.payload.to_bytes(), _sample_time(sample)))
        if key == self._world_td:  # a world that changes its scene re-publishes its TD
            self.fetcher.todo.put_nowait(WORLD_THING)

    def _joined(self, thing: str) -> None:
        self._queue(Message("join", thing, b"", time.time()))
        self.fetcher.todo.put_nowait(thing)

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
    """Asks joining Things for their TD and readable property values, off the Zenoh threads."""

    def __init__(self, client: MeshClient, put):
        super().__init__(name="recorder-fetcher", daemon=True)
        self.client = client
        self.keys = client.keys
        self.put = put
        self.todo: queue.Queue[str] = queue.Queue()
        self._fetched: set[str] = set()
        self._cond = threading.Condition()
        self._halt = threading.Event()

    def run(self) -> None:
        while not self._halt.is_set():
            try:
                thing = self.todo.get(timeout=0.2)
            except queue.Empty:
                continue
            try:
                self.fetch(thing)
            except Exception as e:  # never let one Thing stop the recording
                log.exception("fetching %s failed", thing)
                self.put(Message("notice", "", f"could not fetch {thing}: {e}", time.time()))
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
        for name, prop in td.properties.items():
            if prop.writeOnly or self._halt.is_set():
                continue
            key = self.keys.property(thing, name)
            try:
                reply = self.client.request(key, thing=thing)
            except Problem as e:
                self.put(Message("notice", "", f"could not read {thing}/{name}: {e}", time.time()))
                continue
            self.put(Message("sample", key, reply.payload, time.time()))

    def fetch_scene(self, thing: str) -> None:
        """The world's `scene.json` and the URDF of each of its robots, queued as one "scene" message."""
        try:
            scene = msgspec.json.decode(self.client.file(thing, SCENE_FILE).payload, type=SceneDescription)
            urdfs = {}
            for robot in scene.robots:
                if robot.urdf not in urdfs:
                    urdfs[robot.urdf] = self.client.file(thing, robot.urdf).payload.decode()
        except (Problem, msgspec.DecodeError, msgspec.ValidationError, UnicodeDecodeError) as e:
            self.put(Message("notice", "", f"no scene from {thing}: {e}", time.time()))
            return
        self.put(Message("scene", thing, msgspec.json.encode(SceneFiles(scene, urdfs)), time.time()))

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

    def __init__(self, rec, keys: Keys, inbox: queue.Queue):
        super().__init__(name="recorder-writer", daemon=True)
        self.rec = rec
        self.keys = keys
        self.inbox = inbox
        self.tds: dict[str, ThingDescription] = {}
        self.seq = 0
        self.scene = SceneDrawer(rec)
        self._poses_key = keys.property(WORLD_THING, POSES_PROPERTY)
        self._styled: set[str] = set()  # entity paths whose static style is logged

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
                if self.scene.flush_due():
                    self.flush_scene()
                if time.monotonic() - last_flush >= FLUSH_EVERY:
                    self.rec.flush()
                    last_flush = time.monotonic()
        finally:
            self.flush_scene()
            self.rec.flush()
            self.rec.disconnect()  # closes the file with its footer

    def flush_scene(self) -> None:
        try:
            self.scene.flush()
        except Exception as e:  # a bad batch must not end the recording
            log.exception("writing the world's poses failed")
            self.log_entries(mapping.notice_entries(f"could not record the world's poses: {e}"))

    def write(self, message: Message) -> None:
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
        """A world's scene and poses go to the scene drawer; True when `message` was one of them."""
        if message.kind == "scene":
            files = msgspec.json.decode(message.payload, type=SceneFiles)
            problems = self.scene.draw_scene(files, message.time, self.stamp(message))
            self.log_entries([e for p in problems for e in mapping.notice_entries(p)])
            return True
        if message.kind == "sample" and message.key == self._poses_key:
            poses = msgspec.json.decode(message.payload, type=Poses)
            self.log_entries(self.scene.add_poses(poses, message.time, self.stamp(message, poses.time)))
            return True
        return False

    def log_entries(self, entries: list[mapping.Entry]) -> None:
        for e in entries:
            if e.static:
                if e.path in self._styled:
                    continue
                self._styled.add(e.path)
            self.rec.log(e.path, e.archetype, static=e.static)

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
            return mapping.td_entries(parsed.thing, td)
        value = msgspec.json.decode(message.payload) if message.payload else None
        td = self.tds.get(parsed.thing)
        if parsed.kind == "properties":
            schema = td.properties.get(parsed.name) if td else None
            return mapping.property_entries(parsed.thing, parsed.name, value, schema)
        if parsed.kind == "events":
            return mapping.event_entries(parsed.thing, parsed.name, value)
        if parsed.kind == "actions":
            return mapping.action_entries(parsed.thing, parsed.name, value)
        return []


def run(settings: MeshSettings, stop: threading.Event, path: str | None = None) -> None:
    """Process entry (`twinmesh record`, `twinmesh up --record`): record until `stop` is set."""
    import rerun as rr

    from mesh.session import is_connected, open_session

    try:
        target = prepare_path(path)
    except ValueError as e:
        raise SystemExit(f"twinmesh record: {e}") from None
    rec = rr.RecordingStream("twinmesh")
    rec.save(str(target))
    rec.send_recording_name(f"twinmesh {settings.prefix} {time.strftime('%Y-%m-%d %H:%M:%S')}")
    with open_session(settings) as session, Recorder(session, settings, rec) as recorder:
        alive = recorder.start()
        reach = "" if is_connected(session) else f"; no lab reachable yet at {', '.join(settings.connect)}"
        print(f"recording to {target} ({len(alive)} things alive{reach})", file=sys.stderr, flush=True)
        stop.wait()
    print(f"recording saved: {target}", file=sys.stderr, flush=True)
