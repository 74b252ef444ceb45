"""When is a lab ready, and how does anyone else find out: the `up` side and the `wait` side.

`twinmesh up` calls it ready once every Thing of its scene answers its TD on the mesh, its robots'
workspaces are generated (progress is printed meanwhile) and, with the HTTP adapter, once the
adapter lists them all; only then does it print its one `ready` line
and answer on `<prefix>/_lab/status` (a queryable that no Thing key matches: `_lab` is not a
slug). `twinmesh wait` asks that key until it says ready, or, given Thing names, asks those
Things for their TDs. Before anything starts, `free_or_problem` checks that the ports a lab
listens on are free, so a taken port is one clear line, not a traceback after a false banner.
"""
from __future__ import annotations

import socket
import time
from concurrent.futures import ThreadPoolExecutor
from contextlib import contextmanager
from typing import Callable, Iterable, Iterator

import msgspec

from mesh.fabric.directory import Directory
from mesh.fabric.settings import MeshSettings
from mesh.messages import relations
from mesh.messages.lab import LabStatus
from mesh.wot.problem import Problem, Unavailable
from tdgen.robot.cores import compiled, first_compile_notice
from tdgen.service import THING as TDGEN_THING

PROGRESS_EVERY = 10.0  # s between `up`'s lines saying what it still waits for

STATUS_CHUNK = "_lab/status"


class PortTaken(Problem):
    status, slug, title = 409, "port-taken", "Address in use"


class LabDied(Unavailable):
    slug, title = "lab-died", "A process of the lab exited"


def status_key(settings: MeshSettings) -> str:
    return f"{settings.prefix}/{STATUS_CHUNK}"


def tcp_address(endpoint: str) -> tuple[str, int] | None:
    """(host, port) of a `tcp/HOST:PORT` (or tls/quic/udp) endpoint; None for other kinds."""
    proto, _, rest = endpoint.partition("/")
    if proto not in ("tcp", "tls", "udp", "quic") or not rest:
        return None
    host, _, port = rest.split("#", 1)[0].rpartition(":")
    if not port.isdigit():
        return None
    return host.strip("[]"), int(port)


def port_in_use(host: str, port: int, udp: bool = False) -> str | None:
    """Why `host:port` cannot be listened on (in use, no such address), or None when it can."""
    if port == 0:
        return None
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    with socket.socket(family, socket.SOCK_DGRAM if udp else socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # a TIME_WAIT leftover is no obstacle
        try:
            s.bind((host, port))
        except OSError as e:
            return e.strerror or str(e)
    return None


def free_or_problem(zenoh_endpoints: Iterable[str], http: tuple[str, int] | None) -> None:
    """Raise PortTaken naming the first address a lab could not listen on, and the option that changes it."""
    for endpoint in zenoh_endpoints:
        addr = tcp_address(endpoint)
        if addr is None:
            continue
        why = port_in_use(*addr, udp=endpoint.startswith(("udp/", "quic/")))
        if why:
            raise PortTaken(f"the Zenoh endpoint {endpoint} cannot be listened on ({why}); "
                            "choose another with --zenoh ENDPOINT (e.g. tcp/127.0.0.1:7448)")
    if http is not None:
        why = port_in_use(*http)
        if why:
            raise PortTaken(f"the HTTP address {http[0]}:{http[1]} cannot be listened on ({why}); "
                            "choose another with --http HOST:PORT, or --no-http")


def view_free_or_problem(view: tuple[str, int]) -> None:
    """PortTaken when the live 3D view cannot listen at `view`, naming the options that change it."""
    why = port_in_use(*view)
    if why:
        raise PortTaken(f"the 3D view's address {view[0]}:{view[1]} cannot be listened on ({why}); "
                        "choose another with --view HOST:PORT, or --no-view")


def free_port_near(host: str, start: int, tries: int = 100) -> int:
    """The first port from `start` on that `host` can listen on (the 3D view's stream)."""
    for port in range(start, min(start + tries, 65536)):
        if not port_in_use(host, port):
            return port
    raise PortTaken(f"no free port on {host} from {start} to {start + tries - 1} for the 3D view's stream; "
                    "choose another --view HOST:PORT, or --no-view")


def serve_status(session, settings: MeshSettings, status: LabStatus):
    """Answer `<prefix>/_lab/status` with `status` (the caller keeps the queryable and undeclares it)."""
    payload = msgspec.json.encode(status)

    def answer(query) -> None:  # Zenoh thread: no blocking work, the reply is ready
        query.reply(status_key(settings), payload, encoding="application/json")

    return session.declare_queryable(status_key(settings), answer)


TD_QUERIES_AT_ONCE = 16
# A round asks at most this many TDs, and a live Thing that did not answer is left alone for a few
# seconds: ten hosts of 1,000 devices each joining a lab, each asking every silent TD again every
# 0.2 s, kept the lab's router too busy to take the sessions still coming (Zenoh 1.10 matches every
# query against every key it holds).
TDS_PER_ROUND = 256
QUIET_AFTER_SILENCE = 3.0  # s


def missing_tds(client, things: Iterable[str], timeout: float = 1.0, alive: set[str] | None = None,
                robots: set[str] | None = None) -> list[str]:
    """The Things among `things` that do not answer their TD now. A Thing not alive (`alive`, else one
    liveliness query) is missing without waiting `timeout` for its TD (a fleet of thousands starts).
    The robots among those that answered go into `robots`."""
    things = list(things)
    if alive is None:
        try:
            alive = set(client.things())
        except Problem:
            return things
    missing = [t for t in things if t not in alive]

    def answers(thing: str) -> bool:
        try:
            reply = client.request(client.keys.td(thing), timeout=timeout, thing=thing)
        except Problem:
            return False
        _note_robot(thing, reply.payload, robots)
        return True

    asked = [t for t in things if t in alive]
    if asked:
        with ThreadPoolExecutor(min(TD_QUERIES_AT_ONCE, len(asked))) as pool:  # a fleet: thousands of TDs
            missing += [t for t, ok in zip(asked, pool.map(answers, asked)) if not ok]
    return missing


def answered_in_order(client, things: list[str], timeout: float = 5.0, at_once: int = TD_QUERIES_AT_ONCE,
                      most: int = TDS_PER_ROUND, robots: set[str] | None = None) -> list[str]:
    """The Things at the head of `things` that answer their TD now, asked `at_once` at a time in order
    and no further than the first batch with a silent one: devices start in order, so the Things after
    it most likely are not up either, and every query costs the lab's router a match against all the
    keys it holds (a joining host asking 1,000 absent TDs a second slowed the sessions still coming).
    An absent Thing is silent at once (nothing serves its key); `timeout` is for a busy one. The
    robots among those that answered go into `robots`."""
    out: list[str] = []

    def answers(thing: str) -> bool:
        for r in client.session.get(client.keys.td(thing), timeout=timeout):
            if r.ok is not None:
                _note_robot(thing, r.ok.payload.to_bytes(), robots)
                return True
        return False

    with ThreadPoolExecutor(at_once) as pool:
        for start in range(0, min(len(things), most), at_once):
            batch = things[start:start + at_once]
            oks = list(pool.map(answers, batch))
            out += [t for t, ok in zip(batch, oks) if ok]
            if not all(oks):
                break
    return out


def _note_robot(thing: str, td: bytes, robots: set[str] | None) -> None:
    """Add `thing` to `robots` if its TD links its twin (tdgen generates its workspace)."""
    if robots is None:
        return
    try:
        links = msgspec.json.decode(td, type=_Links).links
    except (msgspec.DecodeError, msgspec.ValidationError):
        return
    if any(link.rel == relations.TWIN for link in links):
        robots.add(thing)


class _Link(msgspec.Struct):
    rel: str | None = None


class _Links(msgspec.Struct):
    links: list[_Link] = []


def unready_workspaces(client, robots: Iterable[str]) -> list[str]:
    """The `robots` whose workspace the tdgen service has not generated yet, with how far its sampling
    is: a robot is not ready for Cartesian moves before. A failed generation does not hold the lab
    up (the robot says why on each such move). The robots come from the TDs readiness asked anyway:
    asking every Thing's TD again on every round took a fleet of 10,000 three minutes."""
    robots = list(robots)
    if not robots:
        return []
    try:
        status = client.read(TDGEN_THING, "robots")
    except Problem:
        return [f"{r}'s workspace" for r in robots]
    out = []
    for robot in robots:
        s = status.get(robot) if isinstance(status, dict) else None
        if isinstance(s, dict) and s.get("status") in ("ready", "failed"):
            continue
        share = s.get("progress") if isinstance(s, dict) else None
        out.append(f"{robot}'s workspace" + (f" ({share * 100:.0f} % sampled)" if isinstance(share, (int, float)) else ""))
    return out


def missing_over_http(base_url: str, things: Iterable[str]) -> list[str]:
    """The Things that the adapter at `base_url` does not list yet (all of them if it does not answer)."""
    import httpx

    things = list(things)
    try:
        listed = httpx.get(base_url.rstrip("/") + "/", timeout=2.0).json()
    except (httpx.HTTPError, ValueError):
        return things
    names = {str(url).rstrip("/").rsplit("/", 1)[-1] for url in listed} if isinstance(listed, list) else set()
    return [t for t in things if t not in names]


def wait_ready(settings: MeshSettings, open_client: Callable, things: list[str] | None, timeout: float,
               alive: Callable[[], str | None] = lambda: None, progress: Callable[[str], None] = lambda _: None,
               http: str | None = None, follow: bool = True) -> LabStatus | None:
    """Poll until the lab is ready; returns its status, or raises Unavailable naming what is missing.

    `open_client()` is a context manager giving a MeshClient (it raises Unavailable while no router
    answers). With `things`, ready means they all answer their TD, the robots among them have their
    workspaces (when the tdgen service is one of them), and `http`, if given, lists them;
    without, it means the lab's status key says so. `alive()` names a lab process that died (stop
    waiting at once). `follow`: learn who is alive from a liveliness subscription to the whole mesh
    (the lab's own `up`); without, the Things are asked their TDs in order (`answered_in_order`): a
    host joining a lab, whose Zenoh client would otherwise follow every token of a mesh of N and
    spend O(N) on each one that joins (ten joining hosts did, on the lab router's cores).
    """
    deadline = time.monotonic() + timeout
    missing: list[str] = list(things or ["the lab's status"])
    if things is not None and TDGEN_THING in things and not compiled():
        progress(first_compile_notice())
    rounds = None if things is None else _ThingRounds(settings, things, http)
    said = time.monotonic()
    while True:
        dead = alive()
        if dead:
            raise LabDied(dead)
        try:
            with open_client() as client, _presence(client, rounds is not None and follow) as present:
                while True:
                    dead = alive()
                    if dead:
                        raise LabDied(dead)
                    if rounds is None:
                        status = _status(client, settings)
                        if status is not None and status.ready:
                            return status
                        missing = ["the lab's status"] if status is None else status.things
                    else:
                        missing = rounds.missing(client, present)
                        if not missing:
                            return None
                    if time.monotonic() >= deadline:
                        break
                    if time.monotonic() - said >= PROGRESS_EVERY:
                        progress(f"still waiting for {_some(missing)}")
                        said = time.monotonic()
                    time.sleep(0.2 if rounds is None else rounds.pause)
        except LabDied:
            raise
        except Unavailable:  # no router yet
            if time.monotonic() >= deadline:
                raise
            time.sleep(0.3)
            continue
        raise Unavailable(f"not ready within {timeout:g} s; waiting for {_some(missing)}")


class _ThingRounds:
    """What `wait_ready` still waits for among named Things, one round at a time. A Thing that answered
    its TD once is not asked again; a live Thing whose TD did not come is left alone a while."""

    def __init__(self, settings: MeshSettings, things: list[str], http: str | None):
        self.settings, self.things, self.http = settings, things, http
        self.answered: set[str] = set()
        self.quiet: dict[str, float] = {}  # Thing -> when to ask it again
        self.robots: set[str] = set()  # Things whose TD links a twin: ready once tdgen generated their workspace
        self.pause = 0.2  # s until the next round

    def missing(self, client, present: Directory | None) -> list[str]:
        now, before = time.monotonic(), len(self.answered)
        if present is not None:
            alive_now = set(present.alive())
            asked = [t for t in self.things if t not in self.answered and t in alive_now
                     and self.quiet.get(t, 0.0) <= now][:TDS_PER_ROUND]
            silent = set(missing_tds(client, asked, alive=alive_now, robots=self.robots))
            self.answered.update(t for t in asked if t not in silent)
            self.quiet.update((t, now + QUIET_AFTER_SILENCE) for t in silent)
        else:
            self.answered.update(answered_in_order(client, [t for t in self.things if t not in self.answered],
                                                   self.settings.query_timeout, robots=self.robots))
        # asking in order and nothing new: ask less often (up to every 2 s)
        self.pause = 0.2 if present is not None or len(self.answered) > before else min(self.pause * 2, 2.0)
        missing = [t for t in self.things if t not in self.answered]
        if not missing and TDGEN_THING in self.things:
            missing = unready_workspaces(client, sorted(self.robots))
        if not missing and self.http is not None:
            missing = [f"{t} (over HTTP)" for t in missing_over_http(self.http, self.things)]
        return missing


@contextmanager
def _presence(client, wanted: bool) -> Iterator[Directory | None]:
    """Who is alive, followed by a liveliness subscription: its current tokens come once, then the
    changes. Asking `wot/*` on each round instead made the router list every token of the mesh each
    time (most of its time while 10 hosts joined a lab of 10,000 devices)."""
    if not wanted:
        yield None
        return
    directory = Directory(client.session, client.keys)
    try:
        yield directory
    finally:
        directory.close()


def _some(names: list[str], show: int = 12) -> str:
    """`a, b, c` or, for a fleet, `a, b, ... and 988 more`."""
    return ", ".join(names) if len(names) <= show else f"{', '.join(names[:show])} and {len(names) - show} more"


def _status(client, settings: MeshSettings) -> LabStatus | None:
    for reply in client.session.get(status_key(settings), timeout=1.0):
        if reply.ok is None:
            continue
        try:
            return msgspec.json.decode(reply.ok.payload.to_bytes(), type=LabStatus)
        except (msgspec.DecodeError, msgspec.ValidationError):
            continue
    return None
