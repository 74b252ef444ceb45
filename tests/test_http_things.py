"""Discovery over HTTP: each Thing's TD, the TDD listing, `/.well-known/wot`: all valid against the
official TD 1.1 schema (formats checked) and shaped as SPEC §5 says."""
from __future__ import annotations

from urllib.parse import quote

import httpx
import pytest
from tdschema import assert_valid_td

pytestmark = pytest.mark.lab

LIGHTS = ["light-left", "light-right"]
THINGS = [*LIGHTS, "tdgen"]  # `twinmesh up` always starts the TD generator
TD_CONTEXT_START = ["https://www.w3.org/2019/wot/td/v1", "https://www.w3.org/2022/wot/td/v1.1"]


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


def all_served_tds(base: str) -> list[dict]:
    return ([httpx.get(f"{base}/{t}").json() for t in THINGS] + httpx.get(f"{base}/things").json()
            + [httpx.get(f"{base}/.well-known/wot").json()])


def test_every_served_td_is_valid(lab):
    tds = all_served_tds(lab.http)
    assert len(tds) == 2 * len(THINGS) + 1
    for td in tds:
        assert_valid_td(td)
        assert td["@context"][:2] == TD_CONTEXT_START


def _schemas(td: dict):
    def walk(schema):
        yield schema
        for sub in (schema.get("properties") or {}).values():
            yield from walk(sub)
        if isinstance(schema.get("items"), dict):
            yield from walk(schema["items"])
    for p in td.get("properties", {}).values():
        yield from walk(p)
    for a in td.get("actions", {}).values():
        for key in ("input", "output"):
            if key in a:
                yield from walk(a[key])
    for e in td.get("events", {}).values():
        if "data" in e:
            yield from walk(e["data"])


@pytest.mark.parametrize("thing", LIGHTS)
def test_thing_td_follows_spec_5(lab, thing):
    td = httpx.get(f"{lab.http}/{thing}").json()
    assert td["title"] == thing
    assert td["id"] == f"urn:twinmesh:thing:{thing}", "the Thing's own id is kept"
    assert {"rel": "self", "href": f"{lab.http}/{thing}", "type": "application/td+json"} in td["links"]
    assert all(a["synchronous"] is True for a in td["actions"].values())
    assert all("type" in s for s in _schemas(td))
    for name, p in td["properties"].items():
        subprotocols = [f.get("subprotocol") for f in p["forms"]]
        assert subprotocols == [None, "longpoll", "sse"], name
        assert p["forms"][0]["href"] == f"{lab.http}/{thing}/properties/{name}"
    for name, e in td["events"].items():
        assert [f.get("subprotocol") for f in e["forms"]] == ["longpoll", "sse"], name
    ops = {op for f in td["forms"] for op in ([f["op"]] if isinstance(f["op"], str) else f["op"])}
    assert {"readallproperties", "observeallproperties", "subscribeallevents"} <= ops
    forms = [f for a in (*td["properties"].values(), *td["actions"].values(), *td["events"].values())
             for f in a["forms"]] + td["forms"]
    assert all(f["href"].startswith(lab.http + "/") for f in forms)


@pytest.mark.parametrize("accept", [None, "*/*", "application/json", "text/html", "application/xml"])
def test_td_is_td_json_whatever_the_accept_header(lab, accept):
    headers = {"accept": accept} if accept else {}
    for path in ("/light-left", "/.well-known/wot", f"/things/{quote('urn:twinmesh:thing:light-left', safe='')}"):
        r = httpx.get(lab.http + path, headers=headers)
        assert r.status_code == 200 and r.headers["content-type"] == "application/td+json", path


def test_things_listing_is_a_tdd_array(lab):
    r = httpx.get(f"{lab.http}/things")
    assert r.headers["content-type"] == "application/ld+json"
    assert [td["title"] for td in r.json()] == THINGS
    page = httpx.get(f"{lab.http}/things", params={"offset": 2, "limit": 1})
    assert [td["title"] for td in page.json()] == ["tdgen"] and "link" not in page.headers
    first = httpx.get(f"{lab.http}/things", params={"limit": 1})
    assert [td["title"] for td in first.json()] == ["light-left"]
    assert 'rel="next"' in first.headers["link"]
    bad = httpx.get(f"{lab.http}/things", params={"limit": "x"})
    assert bad.status_code == 400 and bad.headers["content-type"] == "application/problem+json"


def test_td_by_urlencoded_id(lab):
    r = httpx.get(f"{lab.http}/things/{quote('urn:twinmesh:thing:light-right', safe='')}")
    assert r.status_code == 200 and r.json() == httpx.get(f"{lab.http}/light-right").json()
    assert httpx.get(f"{lab.http}/things/{quote('urn:twinmesh:thing:nothing', safe='')}").status_code == 404


def test_well_known_wot_is_a_thing_directory(lab):
    td = httpx.get(f"{lab.http}/.well-known/wot").json()
    assert td["@type"] == "ThingDirectory"
    form = td["properties"]["things"]["forms"][0]
    assert form["href"].startswith(f"{lab.http}/things")
    assert form["response"]["contentType"] == "application/ld+json"
    assert td["actions"]["retrieveThing"]["forms"][0]["htv:methodName"] == "GET"


def test_root_lists_the_td_urls(lab):
    assert httpx.get(lab.http + "/").json() == [f"{lab.http}/{t}" for t in THINGS]


def test_tds_and_listings_carry_an_etag_and_answer_304_when_the_client_has_them(lab):
    for path in ("/light-left", "/things", "/.well-known/wot", "/things/" + quote("urn:twinmesh:thing:light-left",
                                                                                    safe="")):
        first = httpx.get(lab.http + path)
        tag = first.headers["etag"]
        assert first.status_code == 200 and tag.startswith('"') and first.content
        again = httpx.get(lab.http + path, headers={"If-None-Match": tag})
        assert again.status_code == 304 and again.content == b"" and again.headers["etag"] == tag, path
        other = httpx.get(lab.http + path, headers={"If-None-Match": '"something-else"'})
        assert other.status_code == 200 and other.content == first.content


def test_several_properties_are_read_and_written_at_once_all_or_nothing(lab):
    url = f"{lab.http}/light-left/properties"
    td = httpx.get(f"{lab.http}/light-left").json()
    ops = {op for form in td["forms"] for op in ([form["op"]] if isinstance(form["op"], str) else form["op"])}
    assert {"readmultipleproperties", "writemultipleproperties", "writeallproperties"} <= ops
    r = httpx.put(url, json={"lightState": True, "lightColor": [0.1, 0.2, 0.3]})
    assert r.status_code == 204, r.text
    assert httpx.get(url).json() == {"lightState": True, "lightColor": [0.1, 0.2, 0.3]}
    assert httpx.get(url, params={"names": "lightColor"}).json() == {"lightColor": [0.1, 0.2, 0.3]}
    bad = httpx.put(url, json={"lightState": False, "lightColor": [2, 0, 0]})  # one value breaks its schema
    assert bad.status_code == 400 and "lightColor" in bad.json()["detail"]
    assert httpx.get(url).json()["lightState"] is True, "nothing is written when one value is bad"
    for body, words in (({"lightState": False, "brightness": 3}, "no property 'brightness'"), ({}, "required"),
                        ([True], "expected object")):
        r = httpx.put(url, json=body)
        assert r.status_code == 400 and words in r.json()["detail"], (body, r.text)
    assert httpx.get(url, params={"names": "nope"}).status_code == 400
    assert httpx.put(url, json={"lightState": False}).status_code == 204  # a subset: writemultipleproperties
    assert httpx.get(url).json()["lightState"] is False


def test_the_directory_tells_when_a_thing_comes_changes_and_goes(lab):
    """WoT Discovery notifications as SSE on /events: a Thing joining, its TD replaced, the Thing leaving."""
    import json
    import queue
    import threading
    import time

    from mesh.fabric.server import ExposedThing
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings
    from mesh.wot.thing_description import decode_td

    got: queue.Queue = queue.Queue()

    def listen() -> None:
        with httpx.stream("GET", f"{lab.http}/events", timeout=httpx.Timeout(5, read=30)) as r:
            got.put(("status", r.status_code))
            event = None
            for line in r.iter_lines():
                if line.startswith("event: "):
                    event = line.removeprefix("event: ")
                elif line.startswith("data: ") and event:
                    got.put((event, json.loads(line.removeprefix("data: "))))

    threading.Thread(target=listen, daemon=True).start()
    assert got.get(timeout=10) == ("status", 200)
    directory = httpx.get(f"{lab.http}/.well-known/wot").json()
    assert set(directory["events"]) == {"thing_created", "thing_updated", "thing_deleted"}
    td = {"title": "visitor", "properties": {"mood": {"type": "string", "readOnly": True}}}
    settings = MeshSettings(connect=(lab.endpoint,))
    seen = []

    def next_about_visitor() -> tuple[str, dict]:
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            kind, data = got.get(timeout=20)
            if data.get("title") == "visitor":
                seen.append(kind)
                return kind, data
        raise AssertionError(f"no event about the visitor; seen {seen}")

    with open_session(settings) as session:
        thing = ExposedThing(session, td, "visitor", settings.keys)
        thing.on_read("mood", lambda: "curious")
        with thing:
            kind, data = next_about_visitor()
            assert kind == "thing_created" and data["id"] == "urn:twinmesh:thing:visitor"
            thing.update_td(decode_td({**td, "description": "now described"}))
            assert next_about_visitor()[0] == "thing_updated"
        assert next_about_visitor()[0] == "thing_deleted"
