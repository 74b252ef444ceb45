"""The lights over HTTP: read, write, invoke, bad inputs (4xx problem+json, device state unchanged),
long-poll and SSE observation of properties and events. Real processes: `twinmesh up lights`.
"""
from __future__ import annotations

import json
import threading

import httpx
import pytest
from waiting import always, eventually

pytestmark = pytest.mark.lab

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def mesh(lab):
    """A Zenoh consumer on the lab: the device's own view, bypassing the adapter and its cache."""
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    settings = MeshSettings(connect=(lab.endpoint,), mode="client")
    with open_session(settings) as session:
        yield MeshClient(session, settings)


@pytest.fixture()
def left(lab, mesh):
    """light-left's base URL, the light off and white."""
    mesh.write("light-left", "lightState", False)
    mesh.invoke("light-left", "setColor", {"r": 1, "g": 1, "b": 1})
    return f"{lab.http}/light-left"


def state(mesh) -> dict:
    return {p: mesh.read("light-left", p) for p in ("lightState", "lightColor")}


def test_read_write_invoke(left, mesh):
    assert httpx.get(f"{left}/properties/lightState").json() is False
    r = httpx.put(f"{left}/properties/lightState", json=True)
    assert r.status_code == 204 and r.content == b""
    assert mesh.read("light-left", "lightState") is True
    assert httpx.get(f"{left}/properties/lightState").json() is True, "read-your-write through the cache"
    r = httpx.post(f"{left}/actions/setColor", json={"r": 1, "g": 0.5, "b": 0})
    assert r.status_code == 200 and r.json() == [1, 0.5, 0]
    assert httpx.get(f"{left}/properties").json() == {"lightState": True, "lightColor": [1, 0.5, 0]}


def test_invoke_without_input_as_node_wot_sends_it(left, mesh):
    r = httpx.post(f"{left}/actions/switchOn", headers={"content-length": "0"})
    assert r.status_code == 204, r.text
    assert mesh.read("light-left", "lightState") is True
    assert httpx.get(f"{left}/properties/lightState").json() is True


def test_chunked_body_is_accepted(left, mesh):
    def chunks():
        yield b'{"r": 0, '
        yield b'"g": 1, "b": 0}'
    r = httpx.post(f"{left}/actions/setColor", content=chunks(), headers={"content-type": "application/json"})
    assert r.request.headers["transfer-encoding"] == "chunked"
    assert r.status_code == 200 and r.json() == [0, 1, 0]
    assert mesh.read("light-left", "lightColor") == [0, 1, 0]


# one per kind of answer through the real adapter and device; every route-level case (schema rules,
# JSON, missing inputs, unknown affordances, methods) is in tests/unit/test_http_routes.py
BAD = [
    ("PUT", "properties/lightColor", b"[1, 0, 2]", 400, "above the maximum 1"),
    ("POST", "actions/setColor", b'{"r": 1, "g"', 400, "not valid JSON"),
    ("GET", "properties/noSuchProperty", None, 404, "no property"),
    ("POST", "properties/lightState", b"true", 405, "not allowed"),
]


@pytest.mark.parametrize("method, path, body, status, message", BAD, ids=[f"{m} {p} {b!r}" for m, p, b, *_ in BAD])
def test_bad_input_is_a_4xx_problem_and_changes_nothing(left, mesh, method, path, body, status, message):
    before = state(mesh)
    headers = {"content-type": "application/json"} if body is not None else {}
    r = httpx.request(method, f"{left}/{path}", content=body, headers=headers)
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    problem = r.json()
    assert problem["status"] == status and message in problem["detail"], problem
    assert problem["instance"] == f"/light-left/{path}"
    if status == 405:
        allowed = {"properties/lightState": "GET, HEAD, PUT"}
        assert set(r.headers["allow"].split(", ")) == set(allowed[path].split(", "))
    assert state(mesh) == before


def test_unknown_thing_is_404(lab):
    for path in ("/no-such-thing", "/no-such-thing/properties/x", "/Not_A_Slug/properties/x", "/a/b/c/d/e"):
        r = httpx.get(lab.http + path)
        assert r.status_code == 404 and r.headers["content-type"] == PROBLEM, path


def test_a_10_mb_body_is_413_and_changes_nothing(left, mesh):
    before = state(mesh)
    big = b"[" + b"1," * 5_000_000 + b"1]"
    r = httpx.put(f"{left}/properties/lightColor", content=big, headers={"content-type": "application/json"})
    assert r.status_code == 413 and r.headers["content-type"] == PROBLEM

    def chunks():  # no Content-Length: refused at the chunk that crosses the limit
        yield b"["
        for _ in range(1000):
            yield b"1," * 5000
        yield b"1]"
    r = httpx.put(f"{left}/properties/lightColor", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 413 and r.headers["content-type"] == PROBLEM
    assert state(mesh) == before
    assert httpx.get(f"{left}/properties/lightState").status_code == 200, "the adapter still serves"


def test_non_json_content_type_is_415(left, mesh):
    before = state(mesh)
    r = httpx.put(f"{left}/properties/lightState", content=b"true", headers={"content-type": "text/plain"})
    assert r.status_code == 415 and r.headers["content-type"] == PROBLEM
    assert state(mesh) == before



def test_an_inputless_action_takes_an_empty_body_of_any_content_type(left, mesh):
    """`curl -X POST -d '' URL` sends application/x-www-form-urlencoded with nothing in it: nothing to decode,
    so the action runs; a body that is there and not JSON stays 415."""
    httpx.post(f"{left}/actions/switchOff").raise_for_status()
    r = httpx.post(f"{left}/actions/switchOn", content=b"",
                   headers={"content-type": "application/x-www-form-urlencoded"})
    assert r.status_code in (200, 204), r.text
    assert httpx.get(f"{left}/properties/lightState").json() is True
    before = state(mesh)
    r = httpx.post(f"{left}/actions/switchOff", content=b"a=1",
                   headers={"content-type": "application/x-www-form-urlencoded"})
    assert r.status_code == 415 and r.headers["content-type"] == PROBLEM
    assert state(mesh) == before

# --- observation ---------------------------------------------------------------------------------
def _in_background(fn):
    box: dict = {}
    t = threading.Thread(target=lambda: box.setdefault("r", fn()), daemon=True)
    t.start()
    return t, box


def test_long_poll_head_answers_at_once_and_get_waits_for_the_change(left):
    for path in ("properties/lightState/observable", "events/stateChanged"):
        # at once, without a change to wait for (node-wot's handshake gives it 1 s: no wall time asserted here)
        r = httpx.head(f"{left}/{path}", timeout=30)
        assert 200 <= r.status_code < 300, f"HEAD {path}: {r.status_code}"

    prop, pbox = _in_background(lambda: httpx.get(f"{left}/properties/lightState/observable", timeout=60))
    event, ebox = _in_background(lambda: httpx.get(f"{left}/events/stateChanged", timeout=60))
    always(lambda: prop.is_alive() and event.is_alive(), 0.5, what="a long-poll GET blocks until the next change")
    switches = iter(["switchOn", "switchOff"] * 100)  # until both GETs, registered whenever, got a change
    eventually(lambda: httpx.post(f"{left}/actions/{next(switches)}").status_code == 204
               and not prop.is_alive() and not event.is_alive(), what="both long-polls answered")
    assert pbox["r"].status_code == 200 and pbox["r"].json() in (True, False)
    assert ebox["r"].status_code == 200 and ebox["r"].json() in (True, False)


def _sse_events(url: str, count: int, trigger, headers: dict | None = None) -> tuple[list[dict], dict]:
    """Open an SSE stream, run `trigger()` once it is open, collect `count` events."""
    events: list[dict] = []
    with httpx.stream("GET", url, headers={"accept": "text/event-stream", **(headers or {})}, timeout=20) as r:
        assert r.status_code == 200, r.read()
        assert r.headers["content-type"].startswith("text/event-stream")
        lines = r.iter_lines()
        assert next(lines).startswith("retry:")
        threading.Thread(target=trigger, daemon=True).start()
        current: dict = {}
        for line in lines:
            if line == "":
                if "data" in current:
                    events.append(current)
                    if len(events) == count:
                        break
                current = {}
            elif not line.startswith(":"):
                field, _, value = line.partition(": ")
                current[field] = value if field != "data" else json.loads(value)
        return events, dict(r.headers)


def test_sse_property_stream_sends_unnamed_events(left):
    def toggle():
        for on in (True, False):
            httpx.put(f"{left}/properties/lightState", json=on)
    events, _ = _sse_events(f"{left}/properties/lightState/sse", 2, toggle)
    assert [e["data"] for e in events] == [True, False]
    assert all("event" not in e and e["id"] for e in events), "unnamed: node-wot only delivers those"


def test_sse_event_stream_delivers_state_changed(left):
    def toggle():
        httpx.post(f"{left}/actions/switchOn")
        httpx.post(f"{left}/actions/switchOff")
    events, _ = _sse_events(f"{left}/events/stateChanged/sse", 2, toggle)
    assert [e["data"] for e in events] == [True, False]


def test_thing_level_sse_streams_name_each_event(left):
    def change():
        httpx.put(f"{left}/properties/lightState", json=True)
        httpx.post(f"{left}/actions/setColor", json={"r": 0, "g": 0, "b": 1})
    events, _ = _sse_events(f"{left}/properties", 2, change)
    assert [(e["event"], e["data"]) for e in events] == [("lightState", True), ("lightColor", [0, 0, 1])]
    events, _ = _sse_events(f"{left}/events", 1, lambda: httpx.post(f"{left}/actions/switchOff"))
    assert [(e["event"], e["data"]) for e in events] == [("stateChanged", False)]


def test_non_observable_or_unknown_observation_is_404(left):
    r = httpx.get(f"{left}/properties/nothing/sse")
    assert r.status_code == 404 and r.headers["content-type"] == PROBLEM


def test_changes_from_outside_the_adapter_reach_observers_and_reads(left, mesh):
    prop, box = _in_background(lambda: httpx.get(f"{left}/properties/lightState/observable", timeout=60))
    values = iter([True, False] * 100)
    written: list[bool] = []

    def write() -> bool:  # straight on the mesh, as another Zenoh peer would, until the GET got a change
        written.append(next(values))
        mesh.write("light-left", "lightState", written[-1])
        return not prop.is_alive()
    eventually(write, what="the long-poll answered")
    assert box["r"].json() in written
    eventually(lambda: httpx.get(f"{left}/properties/lightState").json() is written[-1], what="the last write read")
