"""Every JSON Schema keyword a TD may use is enforced, over HTTP and over Zenoh alike, with a detail a
person can act on and the device unchanged; and every TD term reaches the adapter's readers.

A `keywords` Thing, exposed from this test process on a `twinmesh up lights` lab, has one writable
property per keyword (multipleOf, oneOf, additionalProperties, format, uniqueItems) and an action
whose input is a oneOf. Its TD also carries TD 1.1 terms twinmesh does not use itself (titles,
created, support, schemaDefinitions, uriVariables) and an extension vocabulary's term, in the style
of the TD 1.1 specification's examples.
"""
from __future__ import annotations

import json
import time

import httpx
import pytest
from labs import start_lab

from mesh.wot.problem import Refused

pytestmark = pytest.mark.lab

PROBLEM = "application/problem+json"
GOOD = {"step": 10, "target": "home", "config": {"a": 1}, "when": "2026-11-23T10:00:00Z", "tags": ["a"]}
# property, a value the schema forbids, words the detail must hold
BAD = [
    ("step", 7, "step: 7 is not a multiple of 5"),
    ("target", 20, "target: 20 is above the maximum 10"),  # the oneOf branch a number is meant for
    ("target", "away", "target: 'away' is not one of ['home']"),
    ("target", [1], "target: list fits none of the allowed schemas (oneOf); give either schema 1 or schema 2"),
    ("config", {"a": 1, "b": 2}, "config: unexpected field 'b'"),
    ("config", {"a": "one"}, "config.a: expected integer, got 'one'"),
    ("when", "not a date", "when: 'not a date' is not a valid date-time"),
    ("tags", ["x", "x"], "tags: items must be unique"),
    ("tags", ["x", 1], "tags[1]: expected string, got 1"),
]
SOURCE_TD = {
    "@context": ["https://www.w3.org/2022/wot/td/v1.1", {"ex": "https://example.org/vocab#"}, {"@language": "en"}],
    "title": "keywords",
    "titles": {"en": "Keywords", "de": "Schlüsselwörter"},
    "id": "urn:twinmesh:thing:keywords",
    "created": "2026-11-23T08:00:00Z",
    "support": "mailto:lab@example.org",
    "ex:calibrated": True,
    "schemaDefinitions": {"percent": {"type": "integer", "minimum": 0, "maximum": 100}},
    "properties": {
        "step": {"type": "integer", "multipleOf": 5, "observable": True},
        "target": {"oneOf": [{"type": "integer", "minimum": 0, "maximum": 10}, {"type": "string", "enum": ["home"]}],
                   "descriptions": {"en": "A slot number or home", "de": "Ein Platz oder home"}},
        "config": {"type": "object", "properties": {"a": {"type": "integer"}}, "additionalProperties": False,
                   "ex:unitOfWork": "batch"},
        "when": {"type": "string", "format": "date-time"},
        "tags": {"type": "array", "items": {"type": "string"}, "uniqueItems": True},
        "history": {"type": "array", "readOnly": True,
                    "uriVariables": {"limit": {"type": "integer", "minimum": 1}}},
    },
    "actions": {
        "goTo": {"input": {"oneOf": [{"type": "string", "enum": ["home", "park"]},
                                     {"type": "object", "required": ["slot"], "additionalProperties": False,
                                      "properties": {"slot": {"type": "integer", "minimum": 0}}}]},
                 "output": {"type": "string"}},
    },
    "security": ["nosec_sc"], "securityDefinitions": {"nosec_sc": {"scheme": "nosec"}},
}


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    lab = start_lab(tmp_path_factory.mktemp("keywords"), "lights", http=True, things={"light-left", "light-right"})
    yield lab
    assert lab.stop(), "the lab did not stop cleanly"


@pytest.fixture(scope="module")
def device(lab):
    """The `keywords` Thing on the lab's mesh; yields what its handlers were given (the device's state)."""
    from mesh.fabric.server import ExposedThing
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings
    settings = MeshSettings(connect=(lab.endpoint,))
    state = dict(GOOD, calls=[])
    with open_session(settings) as session:
        thing = ExposedThing(session, SOURCE_TD, "keywords", settings.keys)
        for name in GOOD:
            thing.on_read(name, lambda n=name: state[n]).on_write(name, lambda v, n=name: state.__setitem__(n, v))

        def write_tags(tags: list[str]) -> None:  # a device that refuses a valid value (422), for the all-or-nothing test
            if "refused" in tags:
                raise Refused("keywords: the tag 'refused' is refused by the device", reason="refused-tag")
            state["tags"] = tags
        thing.on_write("tags", write_tags)
        thing.on_read("history", lambda: [])
        thing.on_action("goTo", lambda where: state["calls"].append(where) or "ok")
        with thing:
            deadline = time.monotonic() + 30
            while httpx.get(f"{lab.http}/keywords").status_code != 200:
                assert time.monotonic() < deadline, "the adapter never listed the keywords Thing"
                time.sleep(0.1)
            yield state


@pytest.fixture(scope="module")
def zenoh(lab):
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    settings = MeshSettings(connect=(lab.endpoint,), mode="client")
    with open_session(settings) as session:
        yield MeshClient(session, settings)


@pytest.mark.parametrize("prop, value, detail", BAD, ids=[f"{p}-{v!r}" for p, v, _ in BAD])
def test_http_refuses_what_the_schema_forbids(lab, device, prop, value, detail):
    before = device[prop]
    r = httpx.put(f"{lab.http}/keywords/properties/{prop}", json=value)
    assert r.status_code == 400 and r.headers["content-type"] == PROBLEM, r.text
    assert r.json()["detail"] == detail
    assert device[prop] == before, "the device was changed by a refused write"


@pytest.mark.parametrize("prop, value, detail", BAD, ids=[f"{p}-{v!r}" for p, v, _ in BAD])
def test_zenoh_refuses_what_the_schema_forbids(device, zenoh, prop, value, detail):
    from mesh.wot.problem import BadInput

    before = device[prop]
    with pytest.raises(BadInput) as refused:
        zenoh.write("keywords", prop, value)
    assert refused.value.detail == detail
    assert device[prop] == before, "the device was changed by a refused write"


@pytest.mark.parametrize("prop, value", [("step", 25), ("target", 3), ("config", {}), ("when", "2026-01-01T00:00:00+01:00"),
                                         ("tags", ["b", "c"])])
def test_values_the_schema_allows_reach_the_device(lab, device, prop, value):
    r = httpx.put(f"{lab.http}/keywords/properties/{prop}", json=value)
    assert r.status_code == 204, r.text
    assert device[prop] == value
    httpx.put(f"{lab.http}/keywords/properties/{prop}", json=GOOD[prop])


def test_action_input_oneof(lab, device, zenoh):
    from mesh.wot.problem import BadInput

    calls = len(device["calls"])
    assert httpx.post(f"{lab.http}/keywords/actions/goTo", json={"slot": 4}).json() == "ok"
    assert zenoh.invoke("keywords", "goTo", "park") == "ok"
    r = httpx.post(f"{lab.http}/keywords/actions/goTo", json={"slot": 4, "speed": 9})
    assert r.status_code == 400 and "input: unexpected field 'speed'" in r.json()["detail"]  # the object branch's rule
    with pytest.raises(BadInput):
        zenoh.invoke("keywords", "goTo", "garage")
    assert device["calls"][calls:] == [{"slot": 4}, "park"], "only the valid inputs reached the device"


def _lost(source, served, path="td"):
    """Where `served` lacks or changed a term of `source` (forms, links and security are the server's)."""
    from mesh.wot.thing_description import REWRITTEN_TERMS

    if isinstance(source, dict):
        if not isinstance(served, dict):
            return [f"{path}: became {type(served).__name__}"]
        return [lost for k, v in source.items() if k not in REWRITTEN_TERMS
                for lost in (_lost(v, served[k], f"{path}.{k}") if k in served else [f"{path}.{k}: missing"])]
    return [] if source == served else [f"{path}: {source!r} became {served!r}"]


def test_the_adapter_serves_every_term_the_thing_said(lab, device):
    served = httpx.get(f"{lab.http}/keywords").json()
    assert _lost(SOURCE_TD, served) == []
    assert "https://www.w3.org/2022/wot/td/v1.1" in served["@context"]
    assert {"ex": "https://example.org/vocab#"} in served["@context"], "the extension's prefix is lost"


def test_our_own_tds_lose_nothing_through_the_adapter(lab, zenoh):
    for thing in ("light-left", "tdgen"):
        source = json.loads(zenoh.td_bytes(thing))
        served = httpx.get(f"{lab.http}/{thing}").json()
        assert _lost(source, served) == [], thing


def test_a_multi_property_write_a_device_refuses_halfway_puts_back_what_it_wrote(lab, device):
    """writemultipleproperties is all or nothing even when the device refuses a valid value: `step` is
    written first, `tags` refused (422), and `step` gets its old value back."""
    before = {"step": device["step"], "tags": device["tags"]}
    r = httpx.put(f"{lab.http}/keywords/properties", json={"step": before["step"] + 5, "tags": ["refused"]})
    assert r.status_code == 422 and r.json()["reason"] == "refused-tag", r.text
    assert {"step": device["step"], "tags": device["tags"]} == before
    ok = httpx.put(f"{lab.http}/keywords/properties", json={"step": before["step"] + 5, "tags": ["fine"]})
    assert ok.status_code == 204 and device["step"] == before["step"] + 5 and device["tags"] == ["fine"]
