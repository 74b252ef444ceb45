"""`twinmesh virtual`: any TD as a Thing on the mesh, proven with a corpus nobody here wrote.

The corpus (tests/data/td-corpus, sources in tests/data/SOURCES.md, the real lab's TDs, and one TD
per JSON Schema construct of tests/data/tds/keywords) is
served by one `twinmesh virtual` on a running lab; node-wot 0.9.2 then consumes each through the
adapter, reads every readable property, writes every writable one and reads it back, invokes every
action with a valid input drawn from its schema and subscribes to every event; every value that
comes back is checked against the original TD's schema here, and each served TD against the
original document (every term at every depth; only forms and the Thing-level terms the adapter
writes are ours).
"""
from __future__ import annotations

import json
import re
import subprocess
import time
from pathlib import Path

import httpx
import pytest
from interop import npm
from jsonschema import Draft7Validator
from labs import mesh_client, start_lab
from waiting import subscribed

from mesh.wot.problem import BadInput
from mesh.wot.schema_values import SchemaValues
from mesh.wot.validate import validate

pytestmark = [pytest.mark.lab, pytest.mark.interop, pytest.mark.timeout(900)]

DATA = Path(__file__).parent / "data"
CORPUS_DIRS = [DATA / "reference-tds" / "real-lab", *sorted(p for p in (DATA / "td-corpus").iterdir()
                                                              if p.is_dir() and p.name != "refused"),
               DATA / "tds" / "keywords"]  # one TD per JSON Schema construct (tests/data/tds/SOURCES.md)
REFUSED = DATA / "td-corpus" / "refused"
# Events the virtual Thing emits on Zenoh (`twinmesh subscribe` gets them) but the HTTP adapter never hands to a
# long-poll or SSE subscriber (found 2026-11-27; the adapter's, not the generator's): data schemas with
# patternProperties, and with definitions and a $ref
ADAPTER_DROPS: tuple[str, ...] = ()  # problems of the adapter known and not yet fixed (none)
THING_TERMS = {"forms", "links", "base", "security", "securityDefinitions", "@context", "id", "title"}


def corpus() -> dict[str, Path]:
    """name on the mesh -> TD file, for every TD of the corpus."""
    out: dict[str, Path] = {}
    for folder in CORPUS_DIRS:
        for path in sorted(folder.iterdir()):
            stem = re.sub(r"\.(td\.)?json(ld)?$", "", path.name)
            name = re.sub(r"[^a-z0-9]+", "-", f"{folder.name[:6]}-{stem}".lower()).strip("-")[:60].strip("-")
            assert name not in out, name
            out[name] = path
    return out


CORPUS = corpus()


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def served(lab):
    log = lab.tmp / "virtual.log"
    process = lab.spawn("virtual", *[f"{name}={path}" for name, path in CORPUS.items()], "--seed", "11",
                        "--events-every", "1", log=log)
    lab.wait_things(set(CORPUS), timeout=300)
    yield process
    assert process.poll() is None, f"twinmesh virtual died:\n{log.read_text()[-3000:]}"


def original(name: str) -> dict:
    return json.loads(CORPUS[name].read_text())


def schema_of(affordance: dict) -> dict:
    return {k: v for k, v in affordance.items() if k != "forms"}


def invalid(value, schema) -> str | None:
    """Why `value` breaks `schema` by jsonschema's own judgement (draft 7, formats checked; stricter than
    the adapter's input check on a fractional multipleOf, as node-wot's ajv is), or by twinmesh's."""
    errors = list(Draft7Validator(schema, format_checker=Draft7Validator.FORMAT_CHECKER).iter_errors(value))
    if errors:
        return errors[0].message
    try:
        validate(value, schema, path="value")
        return None
    except BadInput as e:
        return e.detail


DECODED = ("type", "enum", "const", "oneOf")  # what node-wot's value() needs at a schema's top ("No schema type defined")


def steps_for(td: dict, values: SchemaValues) -> list[tuple[dict, str, dict | None]]:
    """(node-wot step, what it checks, the schema its value must follow)."""
    steps = []
    for prop, p in (td.get("properties") or {}).items():
        raw = not any(term in p for term in DECODED)  # node-wot reads such a property only as bytes
        if not p.get("writeOnly"):
            steps.append(({"op": "readProperty", "name": prop, **({"raw": True} if raw else {})}, f"read {prop}",
                          schema_of(p)))
        if not p.get("readOnly"):
            value = values.value(schema_of(p))
            steps.append(({"op": "writeProperty", "name": prop, "value": value}, f"write {prop}", None))
            if not p.get("writeOnly"):
                steps.append(({"op": "readProperty", "name": prop}, f"read back {prop}={json.dumps(value)}",
                              {"const": value}))
    for action, a in (td.get("actions") or {}).items():
        if isinstance(a.get("output"), dict) and not any(term in a["output"] for term in DECODED):
            continue  # node-wot cannot read such an output (checked over HTTP: tests/test_schema_values_cli.py)
        step = {"op": "invokeAction", "name": action}
        if isinstance(a.get("input"), dict):
            step["input"] = values.value(a["input"])
        steps.append((step, f"invoke {action}", a.get("output") if isinstance(a.get("output"), dict) else None))
    for event, e in (td.get("events") or {}).items():
        if isinstance(e.get("data"), dict) and not any(term in e["data"] for term in DECODED):
            continue  # nor such event data
        steps.append(({"op": "subscribeEvent", "name": event, "count": 1, "timeoutMs": 15000}, f"event {event}",
                      e.get("data") if isinstance(e.get("data"), dict) else None))
    return steps


def checked(name: str, planned: list[tuple[dict, str, dict | None]], results: list[dict] | npm.HarnessError) -> list[str]:
    """What went wrong driving one virtual Thing with node-wot (empty: everything right)."""
    if isinstance(results, npm.HarnessError):
        return [f"{name}: {str(results)[:400]}"]
    problems = []
    for (step, what, schema), result in zip(planned, results):
        if not result.get("ok"):
            problems.append(f"{name}: {what}: node-wot: {result.get('error')}")
            continue
        got = result["values"][0] if step["op"] == "subscribeEvent" else \
            json.loads(result["raw"]) if "raw" in result else result.get("value")
        if schema is not None and (step["op"] != "invokeAction" or "value" in result):
            why = invalid(got, schema)
            if why is not None:
                problems.append(f"{name}: {what}: {json.dumps(got)[:100]} breaks its schema: {why}")
    return problems


def test_node_wot_drives_every_virtual_thing_of_the_corpus_and_every_value_is_valid(lab, served):
    # one node process drives them all, several at a time: node-wot loads once, the event waits overlap
    plans = {name: steps_for(original(name), SchemaValues(7)) for name in CORPUS}
    driven = [name for name in CORPUS if plans[name]]
    results = npm.run_clients([(f"{lab.http}/{name}", [s for s, _, _ in plans[name]]) for name in driven], timeout=600)
    problems = [p for name, result in zip(driven, results) for p in checked(name, plans[name], result)]
    print(f"{len(CORPUS)} TDs, {sum(map(len, plans.values()))} node-wot interactions, {len(problems)} problems")
    known = [p for p in problems if p.startswith(ADAPTER_DROPS)]
    if known:
        print("known, the adapter's:\n" + "\n".join(known))
    assert [p for p in problems if p not in known] == [], "\n".join(problems)


def _lost(source, served, path: str, depth: int = 0) -> list[str]:
    """Where `served` lacks or changed a term of `source`: only forms, and the Thing-level terms the
    adapter writes (its id, title, links, security), are the server's."""
    if isinstance(source, dict):
        if not isinstance(served, dict):
            return [f"{path}: became {type(served).__name__}"]
        skip = THING_TERMS if depth == 0 else {"forms"} if depth == 2 and path.split(".")[1] in (
            "properties", "actions", "events") else set()
        return [lost for k, v in source.items() if k not in skip
                for lost in (_lost(v, served[k], f"{path}.{k}", depth + 1) if k in served else [f"{path}.{k}: missing"])]
    if isinstance(source, list):
        if not isinstance(served, list) or len(served) != len(source):
            return [f"{path}: {source!r} became {served!r}"]
        return [lost for i, (a, b) in enumerate(zip(source, served)) for lost in _lost(a, b, f"{path}[{i}]", depth + 1)]
    return [] if source == served and type(source) is type(served) else [f"{path}: {source!r} became {served!r}"]


def test_the_served_td_is_the_original_forms_aside(lab, served):
    lost = []
    for name in CORPUS:
        doc = httpx.get(f"{lab.http}/{name}", timeout=30).json()
        lost += _lost(original(name), doc, name)
        for kind in ("properties", "actions", "events"):
            for affordance, a in doc.get(kind, {}).items():
                assert all(f["href"].startswith(f"{lab.http}/{name}/") for f in a["forms"]), (name, affordance)
    # the adapter's own view of what a Thing may do: a property with no write handler is readOnly
    lost = [line for line in lost if not line.endswith(("readOnly: False became True", "writeOnly: False became True"))]
    assert lost == [], "\n".join(lost)


def test_writes_are_kept_and_observers_see_them(lab, served):
    name = next(n for n, path in CORPUS.items() if path.name == "virtual_light_left.td.json")  # the thesis's
    prop, p = "lightColor", original(name)["properties"]["lightColor"]
    values = SchemaValues(3)
    first = values.value(schema_of(p))
    second = next(v for v in (values.value(schema_of(p)) for _ in range(50)) if v != first)
    assert httpx.put(f"{lab.http}/{name}/properties/{prop}", json=first, timeout=30).status_code == 204
    observer = subprocess.Popen(lab.cli_args("observe", name, prop, "--count", "1"), stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
    try:
        assert "waiting for changes" in observer.stderr.readline()  # its subscriber declared...
        with mesh_client(lab.endpoint) as mesh:  # ...and known to the lab's router, which passes changes on
            subscribed(mesh.session, mesh.keys.property(name, prop))
        assert httpx.put(f"{lab.http}/{name}/properties/{prop}", json=second, timeout=30).status_code == 204
        out, err = observer.communicate(timeout=60)
    finally:
        observer.kill()
    assert json.loads(out) == second, err
    assert httpx.get(f"{lab.http}/{name}/properties/{prop}", timeout=30).json() == second
    r = httpx.put(f"{lab.http}/{name}/properties/{prop}", json={"not": "valid"}, timeout=30)
    assert r.status_code == 400 and httpx.get(f"{lab.http}/{name}/properties/{prop}", timeout=30).json() == second


def test_a_name_that_is_no_key_chunk_is_reached_and_the_td_keeps_it(lab, tmp_path):
    td = {"@context": "https://www.w3.org/2022/wot/td/v1.1", "title": "Odd names", "security": "nosec_sc",
          "securityDefinitions": {"nosec_sc": {"scheme": "nosec"}},
          "properties": {"level/left": {"type": "integer", "minimum": 0, "maximum": 9, "default": 4, "forms": [
              {"href": "http://example.org/level"}]}, "Temperatur (°C)": {"type": "number", "minimum": 0.5,
                                                                         "maximum": 1.5, "multipleOf": 0.01,
                                                                         "readOnly": True, "forms": [
              {"href": "http://example.org/t"}]}}}
    path = tmp_path / "odd.json"
    path.write_text(json.dumps(td))
    process = lab.spawn("virtual", f"odd-names={path}", "--seed", "1")
    try:
        lab.wait_things({"odd-names"})
        doc = httpx.get(f"{lab.http}/odd-names", timeout=30).json()
        assert set(doc["properties"]) == {"level/left", "Temperatur (°C)"}
        level = doc["properties"]["level/left"]["forms"][0]["href"]
        assert level.endswith("/properties/level%2Fleft")
        assert httpx.get(level, timeout=30).json() == 4
        assert httpx.put(level, json=7, timeout=30).status_code == 204 and httpx.get(level, timeout=30).json() == 7
        temperature = httpx.get(doc["properties"]["Temperatur (°C)"]["forms"][0]["href"], timeout=30).json()
        assert invalid(temperature, schema_of(td["properties"]["Temperatur (°C)"])) is None
        assert lab.cli("read", "odd-names", "level/left").stdout.strip() == "7"
    finally:
        process.terminate()
        process.wait(timeout=30)


def test_the_same_seed_gives_the_same_values(lab):
    name, path = next((n, p) for n, p in CORPUS.items() if "HueIndoorSensor1" in p.name)
    td = original(name)
    readable = [k for k, v in td["properties"].items() if not v.get("writeOnly")]
    seen = []
    for _ in range(2):
        process = lab.spawn("virtual", f"seeded={path}", "--seed", "42")
        try:
            lab.wait_things({"seeded"})
            seen.append({k: httpx.get(f"{lab.http}/seeded/properties/{k}", timeout=30).json() for k in readable})
        finally:
            process.terminate()
            process.wait(timeout=30)
        deadline = time.monotonic() + 30
        while "seeded" in lab.cli("things").stdout.split() and time.monotonic() < deadline:
            time.sleep(0.5)
    assert seen[0] == seen[1] and seen[0]


def test_what_cannot_be_served_starts_nothing_and_says_why_in_one_line(lab, served):
    good = next(iter(CORPUS.values()))
    model = lab.cli("virtual", f"a={good}", f"b={REFUSED / 'w3c-td-1.1-example-0-thing-model.json'}")
    assert model.returncode == 2 and "Thing Model" in model.stderr and len(model.stderr.strip().splitlines()) == 1
    broken = lab.cli("virtual", f"c={REFUSED / 'webthings-2024-gateway.td.json'}")
    assert broken.returncode == 2, broken.stderr
    assert "/actions/updateThing/forms/0/response" in broken.stderr and "rule required" in broken.stderr
    assert not {"a", "b", "c"} & set(lab.cli("things").stdout.split())
    taken = lab.cli("virtual", f"light-left={good}")
    assert taken.returncode == 1 and "light-left" in taken.stderr and "already on the mesh" in taken.stderr
    missing = lab.cli("virtual", "d=/no/such/td.json")
    assert missing.returncode == 2 and "/no/such/td.json" in missing.stderr


def test_read_only_numbers_drift_within_their_bounds_and_a_bridged_name_is_named(lab, tmp_path):
    name, path = next((n, p) for n, p in CORPUS.items() if p.name == "virtual_PanTilt1.json")
    td = original(name)
    numeric = {k: v for k, v in td["properties"].items() if v.get("readOnly") and v.get("type") in ("number", "integer")}
    assert numeric, "the thesis's pan-tilt has read-only angles"
    process = lab.spawn("virtual", f"drifting={path}", "--drift", "--seed", "2")
    try:
        lab.wait_things({"drifting"})
        seen = {k: set() for k in numeric}
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not all(len(v) > 2 for v in seen.values()):
            for k in numeric:
                value = httpx.get(f"{lab.http}/drifting/properties/{k}", timeout=30).json()
                assert invalid(value, schema_of(numeric[k])) is None, (k, value)
                seen[k].add(value)
            time.sleep(0.5)
        assert all(len(v) > 2 for v in seen.values()), seen
        clash = lab.cli("virtual", f"drifting={path}")
        assert clash.returncode == 1 and "drifting" in clash.stderr and "already on the mesh" in clash.stderr
    finally:
        process.terminate()
        process.wait(timeout=30)


def test_up_thing_adds_a_virtual_thing_to_the_lab_it_starts_and_its_recording(tmp_path):
    from recordings import scalars, wait_for_line

    path = next(p for p in CORPUS.values() if p.name == "virtual_light_left.td.json")
    recording = tmp_path / "lab.rrd"
    lab = start_lab(tmp_path, "lights", things={"thesis-light"},
                    extra_args=("--thing", f"thesis-light={path}", "--record", str(recording)))
    try:
        wait_for_line(lab.log, "recording to", lab.proc)
        assert "thesis-light" in lab.cli("things").stdout.split()
        assert httpx.put(f"{lab.http}/thesis-light/properties/lightState", json=True, timeout=30).status_code == 204
        assert httpx.get(f"{lab.http}/thesis-light/properties/lightState", timeout=30).json() is True
        taken = lab.cli("up", "lights", "--thing", f"light-left={path}", "--no-http", "--no-view")
        assert taken.returncode == 2 and "light-left" in taken.stderr and "already has" in taken.stderr
    finally:
        assert lab.stop()
    # the recorder (and so the live view, which shows what it records) has the virtual Thing like the twins
    assert scalars(recording, "/things/thesis-light/properties/lightState")[-1] == 1.0
