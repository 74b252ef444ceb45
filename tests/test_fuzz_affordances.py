"""Property-based: every affordance of every Thing of the iot-lab, driven over HTTP and over Zenoh with
inputs derived from its own schema, valid and almost valid (hypothesis + hypothesis-jsonschema).

What must hold, whatever the input: no 5xx; an input that breaks the schema gets 400 with a detail
that names the field, and the Thing's state is unchanged; the Thing keeps serving its TD. The run is
bounded (a few examples per affordance, derandomised, so CI sees the same inputs every time); a
longer one is `python tests/bench/bench_fuzz.py`.
"""
from __future__ import annotations

import math
import os
from typing import Any

import httpx
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis_jsonschema import from_schema

pytestmark = pytest.mark.lab  # on the session's iot-lab, with the others conftest.SHARED_LAB names

EXAMPLES = int(os.environ.get("TWINMESH_FUZZ_EXAMPLES", "4"))
SCHEMA_KEYS = {"type", "const", "enum", "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "minLength",
               "maxLength", "pattern", "minItems", "maxItems", "items", "properties", "required"}
# properties that change by themselves (time, poses, sensors watching the room): left out of "unchanged"
LIVE = {"simTime", "poses", "stepping", "detectColor", "color", "lux", "temperature", "objectPresence"}
# valid, but minutes of simulated time per call (the uArm at 100 mm/min): fuzzed from a brisker speed on
SLOW = {("uarm", "go", "speed"): {"minimum": 3000}}
PROFILE = settings(max_examples=EXAMPLES, deadline=None, derandomize=True, database=None,
                   suppress_health_check=list(HealthCheck))


def json_schema(schema: dict | None) -> dict:
    """The JSON Schema part of a TD data schema (no forms, units, titles; nested schemas too)."""
    if not schema:
        return {}
    out = {k: v for k, v in schema.items() if k in SCHEMA_KEYS}
    if "items" in out:
        out["items"] = json_schema(out["items"])
    if "properties" in out:
        out["properties"] = {k: json_schema(v) for k, v in out["properties"].items()}
        out.setdefault("additionalProperties", False)
    return out


def almost(schema: dict) -> st.SearchStrategy:
    """Values that break `schema` in one place, the way a clumsy client does."""
    t = schema.get("type")
    kinds = {"null": None, "string": "text", "array": [1, 2], "object": {"a": 1}, "boolean": True, "number": 1.5}
    wrong = [v for k, v in kinds.items() if k != t and not (t == "number" and k == "integer")]
    options = [st.sampled_from(wrong)]
    if t in ("number", "integer"):
        if "maximum" in schema:
            options.append(st.just(schema["maximum"] + 1000))
        if "minimum" in schema:
            options.append(st.just(schema["minimum"] - 1000))
    if t == "object" and schema.get("required"):
        first = schema["required"][0]
        wrong = [] if schema["properties"][first].get("type") == "object" else {"not": "a value"}
        valid = from_schema(schema)
        options.append(valid.map(lambda v: {k: x for k, x in v.items() if k != first}))
        options.append(valid.map(lambda v: {**v, first: wrong}))
    return st.one_of(options)


@pytest.fixture(scope="module")
def lab(iot_lab):
    return iot_lab  # the session's iot-lab, its room reset, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def tds(lab) -> dict[str, dict]:
    with httpx.Client(base_url=lab.http, timeout=60) as h:
        return {td["title"]: td for td in h.get("/things").json()}


def lab_things() -> list[str]:
    from devices.lab.scenes import scene_things

    return ["tdgen", *scene_things("iot-lab")]


def state(http: httpx.Client, thing: str, td: dict) -> dict[str, Any]:
    readable = [n for n, p in td.get("properties", {}).items() if not p.get("writeOnly") and n not in LIVE]
    return {n: http.get(f"/{thing}/properties/{n}").json() for n in readable}


def targets(thing: str, td: dict) -> list[tuple[str, str, dict, dict]]:
    """(kind, name, JSON schema of the input, the schema valid inputs are drawn from) for every writable
    property and every action with input."""
    out = [("properties", n, json_schema(p)) for n, p in td.get("properties", {}).items() if not p.get("readOnly")]
    out += [("actions", n, json_schema(a["input"])) for n, a in td.get("actions", {}).items() if a.get("input")]
    return [(kind, name, schema, _brisk(thing, name, schema)) for kind, name, schema in out]


def _brisk(thing: str, name: str, schema: dict) -> dict:
    drawn = {**schema, "properties": {k: dict(v) for k, v in schema.get("properties", {}).items()}}
    for (t, a, field), bounds in SLOW.items():
        if (t, a) == (thing, name):
            drawn["properties"][field].update(bounds)
    return drawn


def rest(http: httpx.Client, thing: str, td: dict) -> None:
    """Stop what a valid input may have left moving (a continuous pan, a running belt): the `stop...`
    actions without input, so that an invalid input's "nothing changed" is the device's doing."""
    for name, action in td.get("actions", {}).items():
        if name.startswith("stop") and not action.get("input"):
            http.post(f"/{thing}/actions/{name}", timeout=120)


def send(http: httpx.Client, thing: str, kind: str, name: str, value: Any) -> httpx.Response:
    method = "PUT" if kind == "properties" else "POST"
    return http.request(method, f"/{thing}/{kind}/{name}", json=value, timeout=120)


def _finite(value: Any) -> bool:
    if isinstance(value, float):
        return math.isfinite(value)
    if isinstance(value, dict):
        return all(_finite(v) for v in value.values())
    if isinstance(value, list):
        return all(_finite(v) for v in value)
    return True


@pytest.mark.parametrize("thing", lab_things())
def test_every_affordance_survives_valid_and_almost_valid_inputs_over_http(lab, tds, thing):
    td = tds[thing]
    with httpx.Client(base_url=lab.http, timeout=120) as http:
        for kind, name, schema, drawn in targets(thing, td):
            @PROFILE
            @given(value=from_schema(drawn).filter(_finite))
            def valid(value: Any) -> None:
                r = send(http, thing, kind, name, value)
                assert r.status_code < 500, (name, value, r.status_code, r.text)
                if r.status_code >= 400:
                    assert r.headers["content-type"].startswith("application/problem+json"), r.text
                rest(http, thing, td)

            @PROFILE
            @given(value=almost(schema))
            def invalid(value: Any) -> None:
                before = state(http, thing, td)
                r = send(http, thing, kind, name, value)
                assert r.status_code == 400, (name, value, r.status_code, r.text)
                detail = r.json()["detail"]
                assert detail and (name in detail or "input" in detail), detail
                assert state(http, thing, td) == before, (name, value)

            valid()
            invalid()
        assert http.get(f"/{thing}").status_code == 200  # still serving


@pytest.mark.parametrize("thing", lab_things())
def test_every_affordance_survives_the_same_inputs_over_zenoh(lab, tds, thing):
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings
    from mesh.wot.problem import Problem

    settings_ = MeshSettings(mode="client", connect=(lab.endpoint,), action_timeout=120)
    td = tds[thing]
    with open_session(settings_) as session:
        client = MeshClient(session, settings_)

        def call(kind: str, name: str, value: Any) -> int:
            try:
                if kind == "properties":
                    client.write(thing, name, value)
                else:
                    client.invoke(thing, name, value)
            except Problem as p:
                return p.status
            return 200

        for kind, name, schema, drawn in targets(thing, td):
            @PROFILE
            @given(value=from_schema(drawn).filter(_finite))
            def valid(value: Any) -> None:
                assert call(kind, name, value) < 500, (name, value)

            @PROFILE
            @given(value=almost(schema))
            def invalid(value: Any) -> None:
                assert call(kind, name, value) == 400, (name, value)

            valid()
            invalid()
        assert client.td_bytes(thing)
