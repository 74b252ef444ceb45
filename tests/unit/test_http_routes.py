"""The WoT HTTP adapter's routes under Starlette's TestClient, over a registry without a mesh
(tests/fake_registry.py): every affordance kind, problem+json answers, SSE and long-poll, async
actions, auth, discovery and the control page's route. The lab tests (tests/test_http_*.py) keep
one test per behaviour that needs Zenoh: a value read from a device, a Thing that leaves, Ctrl-C."""
from __future__ import annotations

import base64
import json
from collections.abc import Iterator

import anyio
import pytest
from fake_registry import FakeRegistry
from starlette.testclient import TestClient

from mesh.http.app import create_app, create_asgi
from mesh.http.credentials import Auth
from mesh.wot.problem import Refused

PROBLEM = "application/problem+json"
COLOR = {"type": "array", "items": {"type": "number", "minimum": 0, "maximum": 1}, "minItems": 3, "maxItems": 3}
LAMP = {
    "title": "lamp",
    "properties": {"lightState": {"type": "boolean", "observable": True},
                   "lightColor": {**COLOR, "observable": True},
                   "serial": {"type": "string", "readOnly": True},
                   "secret": {"type": "string", "writeOnly": True},
                   "mode": {"enum": ["a", "b"]}},
    "actions": {"switchOn": {"synchronous": True},
                "setColor": {"input": {"type": "object", "required": ["r", "g", "b"],
                                       "properties": {c: {"type": "number", "minimum": 0, "maximum": 1} for c in "rgb"}},
                             "output": COLOR},
                "refuse": {},
                "hold": {"input": {"type": "number", "minimum": 0}}},
    "events": {"stateChanged": {"data": {"type": "boolean"}}},
    "links": [{"href": "files/points.csv", "rel": "dataset-points", "type": "text/csv"}],
}


def _refuse(_):
    raise Refused("the lamp refuses", reason="always")


@pytest.fixture
def registry() -> FakeRegistry:
    reg = FakeRegistry()
    lamp = reg.add(json.loads(json.dumps(LAMP)), values={"lightState": False, "lightColor": [1, 1, 1], "mode": "a"},
                   readers={"serial": lambda: "L-001"}, files={"points.csv": (b"x,y,z\n", "text/csv")})

    def switch_on(_):
        lamp.values["lightState"] = True

    def set_color(rgb):
        lamp.values["lightColor"] = [rgb[c] for c in "rgb"]
        return lamp.values["lightColor"]

    lamp.actions.update(switchOn=switch_on, setColor=set_color, refuse=_refuse, hold=lambda s: None)
    reg.add({"title": "other", "properties": {"level": {"type": "integer"}}}, values={"level": 3})
    return reg


@pytest.fixture
def client(registry) -> Iterator[TestClient]:
    with TestClient(create_asgi(registry, view="http://127.0.0.1:9/"), raise_server_exceptions=False) as c:
        yield c


def problem(r, status: int, text: str = "") -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    body = r.json()
    assert body["status"] == status and text in body["detail"], body
    return body


# --- properties, actions ---------------------------------------------------------------------------
def test_read_write_invoke_reach_the_thing(client, registry):
    assert client.get("/lamp/properties/lightState").json() is False
    r = client.put("/lamp/properties/lightState", json=True)
    assert r.status_code == 204 and r.content == b""
    assert registry.writes == [("lamp", "lightState", True)]
    r = client.post("/lamp/actions/setColor", json={"r": 1, "g": 0.5, "b": 0})
    assert r.status_code == 200 and r.json() == [1, 0.5, 0]
    assert client.get("/lamp/properties").json() == {"lightState": True, "lightColor": [1, 0.5, 0],
                                                      "serial": "L-001", "mode": "a"}
    assert client.get("/lamp/properties", params={"names": "serial,mode"}).json() == {"serial": "L-001", "mode": "a"}


def test_an_inputless_action_takes_no_body_an_empty_one_or_null(client, registry):
    for kwargs in ({}, {"content": b"", "headers": {"content-type": "application/x-www-form-urlencoded"}},
                   {"content": b"null", "headers": {"content-type": "application/json"}}):
        registry.things["lamp"].values["lightState"] = False
        assert client.post("/lamp/actions/switchOn", **kwargs).status_code == 204
        assert registry.things["lamp"].values["lightState"] is True


def test_a_chunked_body_is_read(client):
    def chunks():
        yield b'{"r": 0, '
        yield b'"g": 1, "b": 0}'
    r = client.post("/lamp/actions/setColor", content=chunks(), headers={"content-type": "application/json"})
    assert r.status_code == 200 and r.json() == [0, 1, 0]


BAD = [
    ("PUT", "properties/lightState", b"7", 400, "expected boolean"),
    ("PUT", "properties/lightState", b"", 400, "a value is required"),
    ("PUT", "properties/lightColor", b"[1, 0]", 400, "at least 3 items"),
    ("PUT", "properties/lightColor", b"[1, 0, 2]", 400, "above the maximum 1"),
    ("PUT", "properties/mode", b'"c"', 400, ""),
    ("POST", "actions/setColor", b'{"r": 2, "g": 0, "b": 0}', 400, "input.r: 2 is above the maximum 1"),
    ("POST", "actions/setColor", b'{"r": 1, "g": 0}', 400, "missing required field 'b'"),
    ("POST", "actions/setColor", b'{"r": "1", "g": 0, "b": 0}', 400, "expected number"),
    ("POST", "actions/setColor", b"", 400, "needs an input"),
    ("PUT", "properties/lightState", b"tru", 400, "not valid JSON"),
    ("PUT", "properties/lightState", b'"on"', 400, "expected boolean"),
    ("POST", "actions/setColor", b'{"r": 1, "g"', 400, "not valid JSON"),
    ("POST", "actions/switchOn", b"true", 400, "takes no input"),
    ("POST", "actions/switchOn?async=maybe", None, 400, "async must be true or false"),
    ("PUT", "properties/noSuchProperty", b"true", 404, "no property"),
    ("GET", "properties/noSuchProperty", None, 404, "no property"),
    ("POST", "actions/noSuchAction", None, 404, "no action"),
    ("GET", "events/noSuchEvent", None, 404, "no event"),
    ("GET", "properties/serial/sse", None, 404, "not observable"),
    ("GET", "properties/serial/observable", None, 404, "not observable"),
    ("GET", "properties?names=nope", None, 400, "has no property 'nope'"),
    ("PUT", "properties", b'{"nope": 1}', 400, "has no property 'nope'"),
    ("PUT", "properties", b'{"serial": "x"}', 400, "cannot be written (read-only)"),
    ("PUT", "actions/setColor", b'{"r": 0, "g": 0, "b": 0}', 405, "not allowed"),
    ("POST", "properties/lightState", b"true", 405, "not allowed"),
    ("PUT", "properties/serial", b'"x"', 405, "read-only"),
    ("GET", "properties/secret", None, 405, "write-only"),
]


@pytest.mark.parametrize("method, path, body, status, text", BAD, ids=[f"{m} {p} {b!r}" for m, p, b, *_ in BAD])
def test_bad_input_is_a_problem_naming_it_and_nothing_reaches_the_thing(client, registry, method, path, body, status,
                                                                       text):
    before = dict(registry.things["lamp"].values)
    headers = {"content-type": "application/json"} if body is not None else {}
    body_json = problem(client.request(method, f"/lamp/{path}", content=body, headers=headers), status, text)
    assert body_json["instance"] == f"/lamp/{path.split('?')[0]}"
    assert registry.writes == [] and registry.things["lamp"].values == before


@pytest.mark.parametrize("method, path, allow", [("PUT", "properties/serial", {"GET", "HEAD"}),
                                                 ("GET", "properties/secret", {"PUT"}),
                                                 ("DELETE", "properties/lightState", {"GET", "HEAD", "PUT"}),
                                                 ("PUT", "actions/setColor", {"POST"})])
def test_405_says_what_is_allowed(client, method, path, allow):
    r = client.request(method, f"/lamp/{path}", json="x")
    problem(r, 405)
    assert set(r.headers["allow"].split(", ")) == allow


def test_too_large_bodies_are_413_however_they_come_and_other_media_types_415(client, registry):
    problem(client.put("/lamp/properties/lightColor", content=b"[" + b"1," * 600_000 + b"1]",
                       headers={"content-type": "application/json"}), 413)

    def chunks():
        for _ in range(300):
            yield b"1," * 5000
    problem(client.put("/lamp/properties/lightColor", content=chunks(), headers={"content-type": "application/json"}),
            413, "over the limit")
    problem(client.put("/lamp/properties/lightState", content=b"true", headers={"content-type": "text/plain"}), 415)
    assert registry.writes == []


def test_a_device_refusal_keeps_its_status_and_reason(client):
    body = problem(client.post("/lamp/actions/refuse"), 422, "the lamp refuses")
    assert body["reason"] == "always"


def test_a_refused_multiple_write_puts_back_what_was_written(client, registry):
    lamp = registry.things["lamp"]
    lamp.actions["mode"] = _refuse  # the device refuses any new mode
    problem(client.put("/lamp/properties", json={"lightState": True, "mode": "b"}), 422)
    assert lamp.values["lightState"] is False and lamp.values["mode"] == "a"
    assert registry.writes == [("lamp", "lightState", True), ("lamp", "lightState", False)]


@pytest.mark.parametrize("path", ["/nothing", "/nothing/properties/x", "/Not_A_Slug/properties/x", "/a/b/c/d/e"])
def test_an_unknown_thing_or_path_is_404(client, path):
    problem(client.get(path), 404)


def test_a_thing_that_left_is_503_and_so_is_everything_during_shutdown(client, registry):
    registry.leave("other")
    problem(client.get("/other/properties/level"), 503, "has left the mesh")
    problem(client.get("/other"), 503)
    assert "other" not in [td["title"] for td in client.get("/things").json()]
    registry.closing = True
    r = client.get("/lamp/properties/lightState")
    problem(r, 503, "shutting down")
    assert r.headers["retry-after"] == "1"


# --- asynchronous actions --------------------------------------------------------------------------
def test_an_async_invocation_is_located_queried_listed_and_cancelled_once(client):
    r = client.post("/lamp/actions/hold?async=true", json=5)
    assert r.status_code == 201, r.text
    status = r.json()
    assert r.headers["location"] == status["href"] == f"http://testserver/lamp/actions/hold/{status['id']}"
    assert client.post("/lamp/actions/hold", json=5, headers={"prefer": "respond-async"}).status_code == 201
    assert client.get(f"/lamp/actions/hold/{status['id']}").json()["status"] == "running"
    listed = client.get("/lamp/actions").json()
    assert [s["id"] for s in listed["hold"]][0] == status["id"] and all(s["href"] for s in listed["hold"])
    assert client.delete(f"/lamp/actions/hold/{status['id']}").status_code == 204
    problem(client.delete(f"/lamp/actions/hold/{status['id']}"), 409, "already ended")
    problem(client.get("/lamp/actions/hold/not-an-id"), 404, "32 hex digits")
    problem(client.get(f"/lamp/actions/hold/{'0' * 32}"), 404)


# --- observation -----------------------------------------------------------------------------------
def _when_watched(client: TestClient, registry: FakeRegistry, *changes: tuple[str, str, object]) -> None:
    """Publish `changes` on the app's loop once an observer is registered (a GET long-poll blocks)."""
    async def publish() -> None:
        while registry.observers.count() == 0:
            await anyio.sleep(0.001)
        for kind, name, value in changes:
            registry.publish("lamp", kind, name, value)
    client.portal.start_task_soon(publish)


def _sse(lines: Iterator[str], count: int) -> list[dict]:
    events: list[dict] = []
    current: dict = {}
    for line in lines:
        if line == "":
            if "data" in current:
                events.append(current)
                if len(events) == count:
                    return events
            current = {}
        elif not line.startswith(":"):
            field, _, value = line.partition(": ")
            current[field] = json.loads(value) if field == "data" else value
    return events


def test_long_poll_head_answers_at_once_and_get_the_next_change(client, registry):
    for path in ("properties/lightState/observable", "events/stateChanged"):
        assert client.head(f"/lamp/{path}").status_code == 200
    _when_watched(client, registry, ("properties", "lightState", True))
    assert client.get("/lamp/properties/lightState/observable").json() is True
    _when_watched(client, registry, ("events", "stateChanged", False))
    assert client.get("/lamp/events/stateChanged").json() is False


@pytest.mark.parametrize("path, kind, name, named", [("properties/lightState/sse", "properties", "lightState", False),
                                                     ("events/stateChanged/sse", "events", "stateChanged", False),
                                                     ("properties", "properties", "lightColor", True),
                                                     ("events", "events", "stateChanged", True)])
def test_sse_streams_carry_each_change_named_only_on_thing_level_streams(client, registry, path, kind, name, named):
    with client.stream("GET", f"/lamp/{path}", headers={"accept": "text/event-stream"}) as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        lines = r.iter_lines()
        assert next(lines).startswith("retry:")
        values = ([0, 0, 1], [1, 0, 0]) if name == "lightColor" else (True, False)
        for value in values:
            client.portal.call(registry.publish, "lamp", kind, name, value)
        events = _sse(lines, 2)
    assert [e["data"] for e in events] == list(values)
    assert all(e["id"] for e in events)
    assert [e.get("event") for e in events] == ([name, name] if named else [None, None])


def test_a_stream_ends_when_its_thing_leaves(client, registry):
    with client.stream("GET", "/lamp/properties/lightState/sse") as r:
        lines = r.iter_lines()
        assert next(lines).startswith("retry:")
        client.portal.call(registry.leave, "lamp")
        assert [line for line in lines if line] == []  # ended, nothing more sent


def test_the_lab_stream_names_thing_kind_and_affordance(client, registry):
    with client.stream("GET", "/_lab/stream") as r:
        lines = r.iter_lines()
        assert next(lines).startswith("retry:")
        client.portal.call(registry.publish, "lamp", "properties", "lightState", True)
        (event,) = _sse(lines, 1)
    assert event["event"] == "lamp/properties/lightState" and event["data"] is True


# --- discovery, files, the control page --------------------------------------------------------------
@pytest.mark.parametrize("accept", [None, "*/*", "application/json", "text/html"])
def test_a_td_is_td_json_with_this_adapters_forms_whatever_the_accept_header(client, accept):
    r = client.get("/lamp", headers={"accept": accept} if accept else {})
    assert r.status_code == 200 and r.headers["content-type"] == "application/td+json"
    td = r.json()
    assert td["title"] == "lamp" and td["id"] == "urn:twinmesh:thing:lamp"
    assert td["properties"]["lightState"]["forms"][0]["href"] == "http://testserver/lamp/properties/lightState"
    assert {f["href"] for f in td["actions"]["hold"]["forms"]} >= {"http://testserver/lamp/actions/hold"}
    (points,) = [link for link in td["links"] if link["rel"] == "dataset-points"]
    assert points["href"] == "http://testserver/lamp/files/points.csv"


def test_tds_and_listings_carry_an_etag_and_answer_304(client):
    for path in ("/lamp", "/things", "/.well-known/wot"):
        first = client.get(path)
        again = client.get(path, headers={"if-none-match": first.headers["etag"]})
        assert again.status_code == 304 and again.content == b"", path


def test_the_listing_is_a_paged_tdd_array_and_bad_paging_is_400(client):
    r = client.get("/things")
    assert r.headers["content-type"] == "application/ld+json"
    assert [td["title"] for td in r.json()] == ["lamp", "other"]
    page = client.get("/things", params={"offset": 0, "limit": 1})
    assert [td["title"] for td in page.json()] == ["lamp"] and 'rel="next"' in page.headers["link"]
    for params in ({"offset": "²"}, {"limit": "0"}, {"offset": "-1"}, {"format": "collection"}):
        problem(client.get("/things", params=params), 400)


def test_a_td_by_its_urlencoded_id_the_directorys_td_and_the_root(client):
    assert client.get("/things/urn%3Atwinmesh%3Athing%3Alamp").json()["title"] == "lamp"
    problem(client.get("/things/urn%3Anothing"), 404)
    directory = client.get("/.well-known/wot").json()
    assert "ThingDirectory" in json.dumps(directory["@type"])
    assert client.get("/").json() == ["http://testserver/lamp", "http://testserver/other"]


def test_a_linked_file_comes_with_its_type_and_names_with_key_characters_are_404(client):
    r = client.get("/lamp/files/points.csv")
    assert r.status_code == 200 and r.content == b"x,y,z\n" and r.headers["content-type"].startswith("text/csv")
    for name in ("nothing.csv", "a*b", "a$b", "**"):
        problem(client.get(f"/lamp/files/{name}"), 404)


def test_the_control_page_is_served_to_browsers_with_its_files_and_settings(client):
    page = client.get("/", headers={"accept": "text/html"})
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html") and b"<" in page.content
    assert client.get("/_ui/app.js").headers["content-type"].startswith("text/javascript")
    assert client.get("/_ui/config.json").json() == {"view": "http://127.0.0.1:9/"}
    problem(client.get("/_ui/secrets.txt"), 404)


def test_a_cached_fresh_value_is_answered_by_the_fast_path_and_the_same_otherwise(client, registry):
    registry.cache[("lamp", "lightState")] = b"true"
    assert client.get("/lamp/properties/lightState").json() is True
    assert client.get("/lamp/properties/lightState", headers={"origin": "http://x"}).json() is False  # full way


def test_the_app_starts_and_closes_its_registry_with_its_lifespan(registry):
    with TestClient(create_app(registry)):
        assert registry.started and not registry.closed
    assert registry.closing and registry.closed


# --- auth ------------------------------------------------------------------------------------------
BEARER = {"authorization": "Bearer s3cret"}


@pytest.fixture
def secured(registry) -> Iterator[TestClient]:
    with TestClient(create_asgi(registry, Auth("bearer", "s3cret")), raise_server_exceptions=False) as c:
        yield c


@pytest.mark.parametrize("headers", [{}, {"authorization": "Bearer wrong"},
                                     {"authorization": "Basic " + base64.b64encode(b"u:s3cret").decode()}])
@pytest.mark.parametrize("method, path", [("GET", "/lamp/properties/lightState"), ("PUT", "/lamp/properties/lightState"),
                                          ("POST", "/lamp/actions/switchOn"), ("GET", "/lamp/events/stateChanged"),
                                          ("GET", "/lamp/files/points.csv"), ("GET", "/_lab/stream")])
def test_without_the_credentials_every_affordance_is_401_with_a_challenge(secured, registry, headers, method, path):
    r = secured.request(method, path, headers=headers, json=True if method == "PUT" else None)
    problem(r, 401, "credentials")
    assert r.headers["www-authenticate"] == 'Bearer realm="twinmesh"'
    assert registry.writes == []


def test_with_the_credentials_it_works_and_discovery_stays_public(secured, registry):
    registry.cache[("lamp", "lightState")] = b"false"  # the fast path checks them too
    assert secured.get("/lamp/properties/lightState", headers=BEARER).json() is False
    assert secured.put("/lamp/properties/lightState", json=True, headers=BEARER).status_code == 204
    td = secured.get("/lamp").json()
    assert td["security"] == ["bearer_sc"] and td["securityDefinitions"]["bearer_sc"]["scheme"] == "bearer"
    for path in ("/things", "/.well-known/wot", "/", "/_ui/app.js"):
        assert secured.get(path).status_code == 200, path


def test_a_script_gets_a_challenge_no_browser_answers_with_a_dialog(secured):
    r = secured.get("/lamp/properties/lightState", headers={"x-requested-with": "fetch"})
    assert r.status_code == 401 and r.headers["www-authenticate"].startswith("X-Page-Bearer")


def test_cors_preflights_are_answered_without_credentials(secured):
    r = secured.options("/lamp/properties/lightState",
                        headers={"origin": "http://page", "access-control-request-method": "PUT"})
    assert r.status_code == 200 and r.headers["access-control-allow-origin"] == "*"
