"""The lab's cube workflow (SPEC §3), by affordance name only, over Zenoh or over WoT HTTP.

`cube_workflow(consumer)` drives the devices through a small `Consumer` protocol (read, invoke,
watch an event), so the same eight steps run against the mesh (`MeshConsumer`, a Zenoh session)
and against any WoT HTTP Things (`HttpConsumer`: the TDs' forms, SSE to wait for events) — the
twin's adapter or, unchanged, the real lab. No sleeps: before a belt starts, the workflow
subscribes to the infrared sensor's `detectedObject`, then reads `objectPresence` (the cube may
already be there) and only then starts the belt; it stops the belt on the first `true`. Should a
notification get lost, the presence is read again every `RECHECK` s of waiting.

`twinmesh workflow cube [--via URL] [--runs N]` prints each step with its duration and the colour
read, and exits non-zero when a step fails.
"""
from __future__ import annotations

import colorsys
import json
import queue
import socket
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Callable, ContextManager, Iterator, Protocol

import click

if TYPE_CHECKING:
    import httpx

from twinmesh.fabric.client import NOTHING, MeshClient
from twinmesh.wot.problem import Problem, TimedOut

RECHECK = 5.0  # s: read the sensor again if no notification came for this long
SENSOR_TIMEOUT = 120.0  # s of wall time a belt may run before the cube is declared lost

# SPEC §3's points in the real uArm frame (mm)
ABOVE_RIGHT_BELT, AT_RIGHT_BELT = (192, 192, 87), (192, 192, 52)
COLOR_CHECK = (180, 0, 60)
ABOVE_LEFT_BELT, AT_LEFT_BELT = (200, -200, 90), (200, -200, 70)


class Watch(Protocol):
    def get(self, timeout: float) -> Any:
        """The next notification's value; `queue.Empty` after `timeout` s without one."""


class Consumer(Protocol):
    """What the workflow needs from a WoT client."""

    def read(self, thing: str, prop: str) -> Any: ...

    def invoke(self, thing: str, action: str, input: Any = NOTHING) -> Any: ...

    def watch(self, thing: str, event: str) -> ContextManager[Watch]:
        """Subscribed to `event` when the `with` block starts, unsubscribed when it ends."""


@dataclass
class Step:
    number: int
    title: str
    seconds: float = 0.0
    detail: str = ""


@dataclass
class CubeRun:
    steps: list[Step] = field(default_factory=list)
    color: list[int] | None = None
    seconds: float = 0.0

    @property
    def color_name(self) -> str:
        return color_name(self.color) if self.color is not None else "?"


class StepFailed(Exception):
    def __init__(self, step: Step, cause: BaseException):
        super().__init__(f"step {step.number} ({step.title}) failed: {cause}")
        self.step, self.cause = step, cause


def cube_workflow(c: Consumer, on_step: Callable[[Step], None] = lambda s: None,
                  sensor_timeout: float = SENSOR_TIMEOUT) -> CubeRun:
    """SPEC §3's eight steps; `on_step` hears of each finished step. Raises StepFailed."""
    run = CubeRun()
    started = time.perf_counter()

    def step(title: str, body: Callable[[], str | None]) -> None:
        s = Step(len(run.steps) + 1, title)
        t0 = time.perf_counter()
        try:
            s.detail = body() or ""
        except Exception as e:
            s.seconds = time.perf_counter() - t0
            raise StepFailed(s, e) from e
        s.seconds = time.perf_counter() - t0
        run.steps.append(s)
        on_step(s)

    def go(x: int, y: int, z: int) -> None:
        c.invoke("uarm", "goTo", {"x": x, "y": y, "z": z})

    def pick() -> None:
        c.invoke("uarm", "gripOpen")
        go(*ABOVE_RIGHT_BELT)
        go(*AT_RIGHT_BELT)
        c.invoke("uarm", "gripClose")
        go(*ABOVE_RIGHT_BELT)

    def read_color() -> str:
        run.color = [round(v) for v in c.read("color-sensor", "color")]
        return f"color {run.color} ({color_name(run.color)})"

    def put() -> None:
        go(*ABOVE_LEFT_BELT)
        go(*AT_LEFT_BELT)
        c.invoke("uarm", "gripOpen")
        go(*ABOVE_LEFT_BELT)

    step("dobot getCube: a cube onto conveyor belt 2", lambda: c.invoke("dobot", "getCube"))
    step("conveyor belt 2 forward until infrared sensor 2 sees the cube",
         lambda: belt_until_seen(c, "conveyor-belt-2", "startBeltForward", "infrared-sensor-2", sensor_timeout))
    step("uarm picks the cube up", pick)
    step("uarm carries it over the colour sensor", lambda: go(*COLOR_CHECK))
    step("colour sensor reads the cube", read_color)
    step("uarm puts it on conveyor belt 1", put)
    step("conveyor belt 1 backward until infrared sensor 1 sees the cube",
         lambda: belt_until_seen(c, "conveyor-belt-1", "startBeltBackward", "infrared-sensor-1", sensor_timeout))
    step("dobot returnCube: the cube back into the warehouse", lambda: c.invoke("dobot", "returnCube"))
    run.seconds = time.perf_counter() - started
    return run


def belt_until_seen(c: Consumer, belt: str, start: str, sensor: str, timeout: float = SENSOR_TIMEOUT) -> str:
    """Subscribe, check presence, start the belt, wait for the sensor, stop the belt (always)."""
    with c.watch(sensor, "detectedObject") as events:
        if c.read(sensor, "objectPresence") is True:
            c.invoke(belt, "stopBelt")
            return "the cube was already there"
        try:
            c.invoke(belt, start)
            wait_for_presence(c, events, sensor, timeout)
        finally:
            c.invoke(belt, "stopBelt")
    return ""


def wait_for_presence(c: Consumer, events: Watch, sensor: str, timeout: float) -> None:
    deadline = time.monotonic() + timeout
    while (left := deadline - time.monotonic()) > 0:
        try:
            if events.get(min(RECHECK, left)) is True:
                return
        except queue.Empty:
            if c.read(sensor, "objectPresence") is True:  # a lost notification must not hang the run
                return
    raise TimedOut(f"{sensor} saw no object within {timeout:g} s")


def color_name(rgb: list[int] | tuple[int, ...]) -> str:
    """A plain name for an RGB 0..255 reading: black/grey/white, else the nearest of six hues."""
    r, g, b = (min(max(v / 255.0, 0.0), 1.0) for v in rgb)
    h, s, v = colorsys.rgb_to_hsv(r, g, b)
    if v < 0.15:
        return "black"
    if s < 0.25:
        return "white" if v > 0.85 else "grey"
    hues = ["red", "yellow", "green", "cyan", "blue", "magenta"]
    return hues[round(h * 6) % 6]


# --- over Zenoh -----------------------------------------------------------------------------------
class _QueueWatch:
    def __init__(self) -> None:
        self.queue: queue.Queue = queue.Queue()

    def get(self, timeout: float) -> Any:
        return self.queue.get(timeout=timeout)


class MeshConsumer:
    """The workflow's consumer on a Zenoh session."""

    def __init__(self, client: MeshClient):
        self.client = client

    def read(self, thing: str, prop: str) -> Any:
        return self.client.read(thing, prop)

    def invoke(self, thing: str, action: str, input: Any = NOTHING) -> Any:
        return self.client.invoke(thing, action, input)

    @contextmanager
    def watch(self, thing: str, event: str) -> Iterator[Watch]:
        w = _QueueWatch()
        sub = self.client.subscribe(thing, event, w.queue.put)
        try:
            yield w
        finally:
            sub.undeclare()


# --- over WoT HTTP --------------------------------------------------------------------------------
def _problem(r: httpx.Response) -> Problem:
    if r.headers.get("content-type", "").startswith("application/problem+json"):
        return Problem.from_json(r.content)
    return Problem(f"{r.request.method} {r.request.url}: HTTP {r.status_code} {r.text[:200]}", status=r.status_code)


class _SseWatch:
    """One SSE stream read by a thread; open (the adapter registered it) once the headers arrived."""

    def __init__(self, http: httpx.Client, url: str, timeout: float = 10.0):
        self.queue: queue.Queue = queue.Queue()
        self._opened = threading.Event()
        self._closing = False
        self._response = None
        self._error: BaseException | None = None
        self._thread = threading.Thread(target=self._read, args=(http, url), name="sse", daemon=True)
        self._thread.start()
        if not self._opened.wait(timeout):
            raise TimedOut(f"{url}: the event stream did not open within {timeout:g} s")
        if self._error is not None:
            raise self._error

    def get(self, timeout: float) -> Any:
        item = self.queue.get(timeout=timeout)
        if isinstance(item, BaseException):
            raise item
        return item

    def _read(self, http, url: str) -> None:
        import httpx

        try:
            with http.stream("GET", url, headers={"Accept": "text/event-stream"},
                             timeout=httpx.Timeout(10.0, read=None)) as r:
                if r.status_code != 200:
                    r.read()
                    self._error = _problem(r)
                    return
                self._response = r
                self._opened.set()
                data: list[str] = []
                for line in r.iter_lines():
                    if line.startswith("data:"):
                        data.append(line[5:].removeprefix(" "))
                    elif not line and data:
                        self.queue.put(json.loads("\n".join(data)))
                        data = []
        except Exception as e:
            if not self._closing:
                self._error = e
                self.queue.put(Problem(f"the event stream {url} broke: {e}", status=502))
        finally:
            self._opened.set()

    def close(self) -> None:
        """End the stream: shut the socket down so the reading thread wakes up."""
        self._closing = True
        stream = self._response.extensions.get("network_stream") if self._response is not None else None
        sock = stream.get_extra_info("socket") if stream is not None else None
        if sock is not None:
            try:
                sock.shutdown(socket.SHUT_RDWR)
            except OSError:
                pass
        self._thread.join(timeout=5)


class HttpConsumer:
    """The workflow's consumer on WoT HTTP Things whose TDs are at `{base}/{thing}` (the twinmesh adapter's
    layout), using their forms: readproperty GET, invokeaction POST, subscribeevent over SSE."""

    def __init__(self, base: str, auth: str | None = None, action_timeout: float = 300.0):
        import httpx

        self.base = base.rstrip("/")
        self.headers, self.auth = _http_auth(auth)
        self.http = httpx.Client(headers=self.headers, auth=self.auth, timeout=httpx.Timeout(10.0))
        self.action_timeout = action_timeout
        self._tds: dict[str, dict] = {}

    def close(self) -> None:
        self.http.close()

    def td(self, thing: str) -> dict:
        if thing not in self._tds:
            r = self.http.get(f"{self.base}/{thing}")
            if r.status_code != 200:
                raise _problem(r)
            self._tds[thing] = r.json()
        return self._tds[thing]

    def href(self, thing: str, kind: str, name: str, op: str, subprotocol: str | None = None) -> str:
        affordance = self.td(thing).get(kind, {}).get(name)
        if affordance is None:
            raise Problem(f"{thing} has no {kind[:-1] if kind != 'properties' else 'property'} {name!r}", status=404)
        for form in affordance.get("forms", []):
            ops = form.get("op", [])
            if op in ([ops] if isinstance(ops, str) else ops) and (subprotocol is None
                                                                  or form.get("subprotocol") == subprotocol):
                return form["href"]
        raise Problem(f"{thing}.{name}: no {op} form{f' over {subprotocol}' if subprotocol else ''}", status=404)

    def read(self, thing: str, prop: str) -> Any:
        r = self.http.get(self.href(thing, "properties", prop, "readproperty"), headers={"Accept": "application/json"})
        if r.status_code != 200:
            raise _problem(r)
        return r.json()

    def invoke(self, thing: str, action: str, input: Any = NOTHING) -> Any:
        url = self.href(thing, "actions", action, "invokeaction")
        kwargs: dict[str, Any] = {"timeout": self.action_timeout}
        if input is not NOTHING:
            kwargs["json"] = input
        r = self.http.post(url, **kwargs)
        if r.status_code >= 300:
            raise _problem(r)
        return r.json() if r.content else None

    @contextmanager
    def watch(self, thing: str, event: str) -> Iterator[Watch]:
        w = _SseWatch(self.http, self.href(thing, "events", event, "subscribeevent", "sse"))
        try:
            yield w
        finally:
            w.close()


def _http_auth(auth: str | None) -> tuple[dict[str, str], Any]:
    """`bearer:TOKEN` or `basic:USER:PASS` (as `twinmesh up --auth` takes it) -> headers, httpx auth."""
    if not auth:
        return {}, None
    scheme, _, rest = auth.partition(":")
    if scheme == "bearer" and rest:
        return {"Authorization": f"Bearer {rest}"}, None
    user, _, password = rest.partition(":")
    if scheme == "basic" and user and password:
        import httpx

        return {}, httpx.BasicAuth(user, password)
    raise click.BadParameter("want bearer:TOKEN or basic:USER:PASS", param_hint="--auth")
