"""Every TD tells the truth: each form of every TD the `iot-lab` serves, performed with its op's method.

A WoT client believes the TD. So for every Thing the adapter lists (and the directory's own TD):
reads answer JSON that fits the property's schema (one, several, all); writes of a valid value are
taken (one, all at once); a property
without a write form refuses PUT with 405 and `Allow` (and one without a read form, GET); long-poll
observe forms do not answer at once like a read; SSE forms open an event stream; every action is
invoked with a value its input schema accepts and answers with its output schema, or refuses with
a problem+json the SPEC allows for a valid request (409, 422, 503); links answer with their media
type. Then the same TDs, and what `twinmesh tdgen` writes (a TD and a Thing Model), go through the
Eclipse Thingweb TD Playground: its validator (JSON-LD included, contexts from local copies) and
its assertion tester, with no failed check or assertion.
"""
from __future__ import annotations

import json
import re
from typing import Any

import httpx
import jsonschema
import pytest
from interop import npm
from waiting import eventually

from mesh.wot.units import PREFIX, QUDT_UNITS

pytestmark = pytest.mark.lab  # on the session's iot-lab, with the others conftest.SHARED_LAB names

PROBLEM = "application/problem+json"
REFUSALS = {409, 422, 503}       # SPEC §7: a valid request the device refuses, or a Thing that cannot act now
PENDING = 0.4                    # s a long-poll must stay open without a change
REGISTERED_RELATIONS = {"self", "describedby", "next", "item", "alternate", "type", "collection", "icon"}
NOT_QUANTITIES = re.compile(r"/version$|/data/properties/version$|/properties/version$")  # counters, not amounts
TEMPLATE = re.compile(r"\{\?[^}]*\}")
ACTION_STATUS = {  # the WoT Profile's ActionStatus, as twinmesh answers it
    "type": "object", "required": ["id", "action", "status", "timeRequested", "href"],
    "properties": {"status": {"enum": ["pending", "running", "completed", "failed", "cancelled"]},
                   "id": {"type": "string", "pattern": "^[0-9a-f]{32}$"}, "href": {"type": "string"},
                   "error": {"type": "object", "required": ["type", "title", "status"]}}}


@pytest.fixture(scope="module")
def lab(iot_lab):
    return iot_lab  # the session's iot-lab, its room reset, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def tds(lab) -> dict[str, dict]:
    """Every served TD once the UR10's workspace is generated, and the directory's own TD."""
    with httpx.Client(base_url=lab.http, timeout=120) as http:
        def generated() -> dict[str, dict] | None:
            listed = {td["title"]: td for td in http.get("/things").json()}
            return listed if any("workspace" in link["rel"] for link in listed.get("ur10", {}).get("links", [])) else None

        listed = eventually(generated, timeout=120, what="the UR10's workspace generated")
        return {**listed, "directory": http.get("/.well-known/wot").json()}


# --- values a schema accepts --------------------------------------------------------------------
def example(schema: dict[str, Any]) -> Any:
    """A value `schema` accepts: const, enum, default, else a middle value built from its keywords."""
    if "const" in schema:
        return schema["const"]
    if schema.get("enum"):
        return schema["enum"][0]
    if "default" in schema:
        return schema["default"]
    if schema.get("oneOf"):
        return example(schema["oneOf"][0])
    kind = schema.get("type")
    if kind == "object":
        props = schema.get("properties", {})
        return {name: example(props.get(name, {})) for name in schema.get("required", [])}
    if kind == "array":
        items = schema.get("items", {})
        if isinstance(items, list):
            return [example(i) for i in items]
        return [example(items) for _ in range(schema.get("minItems", 1))]
    if kind in ("number", "integer"):
        low, high = schema.get("minimum"), schema.get("maximum")
        value = (low + high) / 2 if low is not None and high is not None else low if low is not None else \
            high if high is not None else 0
        return int(value) if kind == "integer" else value
    if kind == "boolean":
        return False
    if kind == "string":
        pattern = schema.get("pattern")
        for candidate in ("walker", "a", "0", "walker-1"):
            if pattern is None or re.fullmatch(pattern, candidate):
                return candidate
        raise AssertionError(f"no example string for pattern {pattern!r}")
    return None


def fits(value: Any, schema: dict[str, Any] | None) -> str | None:
    """Why `value` breaks `schema`, or None."""
    if schema is None:
        return None
    error = jsonschema.exceptions.best_match(jsonschema.Draft7Validator(schema).iter_errors(value))
    return None if error is None else f"{'/'.join(map(str, error.absolute_path))}: {error.message}"


def ops(form: dict) -> list[str]:
    op = form.get("op", [])
    return [op] if isinstance(op, str) else op


def href(form: dict, td: dict, ids: dict[str, str]) -> str:
    """The form's target, its URI template filled in (a Thing's id for `{id}`, query variables left out)."""
    url = TEMPLATE.sub("", form["href"])
    return url.replace("{id}", ids.get("light-left", ""))


# --- the walker -----------------------------------------------------------------------------------
class Walk:
    """Performs the forms of one TD and collects every answer that contradicts it."""

    def __init__(self, http: httpx.Client, td: dict, ids: dict[str, str]):
        self.http, self.td, self.ids, self.problems = http, td, ids, []
        self.performed = 0

    def wrong(self, where: str, what: str) -> None:
        self.problems.append(f"{self.td['title']}/{where}: {what}")

    def check_error(self, where: str, r: httpx.Response, allowed: set[int]) -> None:
        if r.status_code not in allowed:
            self.wrong(where, f"{r.request.method} answered {r.status_code} {r.text[:200]}")
        elif r.headers.get("content-type", "").split(";")[0] != PROBLEM:
            self.wrong(where, f"{r.status_code} without problem+json ({r.headers.get('content-type')})")

    def json_of(self, where: str, r: httpx.Response, schema: dict | None) -> Any:
        if r.headers.get("content-type", "").split(";")[0] not in ("application/json", "application/ld+json",
                                                                    "application/td+json"):
            self.wrong(where, f"content type {r.headers.get('content-type')!r}")
            return None
        value = r.json()
        if (why := fits(value, schema)) is not None:
            self.wrong(where, f"answered {json.dumps(value)[:200]}, which its schema refuses ({why})")
        return value

    def refused_with_allow(self, where: str, method: str, url: str, body: Any = None) -> None:
        r = self.http.request(method, url, json=body)
        if r.status_code != 405 or method in r.headers.get("allow", method):
            self.wrong(where, f"{method} without a form for it answered {r.status_code}, Allow "
                              f"{r.headers.get('allow')!r} (want 405 and an Allow without {method})")

    def stream_opens(self, where: str, url: str) -> None:
        with self.http.stream("GET", url, headers={"Accept": "text/event-stream"},
                              timeout=httpx.Timeout(30)) as r:  # the headers: no event is awaited
            if r.status_code != 200 or not r.headers.get("content-type", "").startswith("text/event-stream"):
                self.wrong(where, f"SSE form answered {r.status_code} {r.headers.get('content-type')!r}")
        self.performed += 1

    def long_poll_waits(self, where: str, url: str, schema: dict | None) -> None:
        try:
            r = self.http.get(url, timeout=httpx.Timeout(10, read=PENDING))
        except httpx.ReadTimeout:
            self.performed += 1
            return  # still waiting for a change, as a long-poll should
        self.performed += 1
        if r.status_code != 200:
            self.wrong(where, f"long-poll answered {r.status_code} {r.text[:200]}")
        else:
            self.json_of(where, r, schema)

    # --- per affordance kind ---
    def property(self, name: str, p: dict) -> None:
        where = f"properties/{name}"
        schema = {k: v for k, v in p.items() if k not in ("forms", "readOnly", "writeOnly")}
        read_url = write_url = current = None
        for form in p["forms"]:
            url, kinds = href(form, self.td, self.ids), ops(form)
            if "readproperty" in kinds:
                read_url = url
                r = self.http.get(url)
                self.performed += 1
                current = self.json_of(where, r, schema) if r.status_code == 200 else \
                    self.wrong(where, f"read answered {r.status_code} {r.text[:200]}")
            if "writeproperty" in kinds:
                write_url = url
            if "observeproperty" in kinds:
                if form.get("subprotocol") == "longpoll":
                    if url == read_url:
                        self.wrong(where, "the long-poll observe form has the read form's href (it answers at once)")
                    self.long_poll_waits(where, url, schema)
                elif form.get("subprotocol") == "sse":
                    self.stream_opens(where, url)
        if write_url is not None:
            value = current if read_url is not None and current is not None else example(schema)
            r = self.http.put(write_url, json=value)
            self.performed += 1
            if not 200 <= r.status_code < 300:
                self.check_error(where, r, REFUSALS)
        url = read_url or write_url
        if url and write_url is None:
            self.refused_with_allow(where, "PUT", url, current)
        if url and read_url is None:
            self.refused_with_allow(where, "GET", url)

    def action(self, name: str, a: dict) -> None:
        where = f"actions/{name}"
        status_forms = {op: f for f in a["forms"] for op in ops(f) if op in ("queryaction", "cancelaction")}
        for form in a["forms"]:
            if "invokeaction" not in ops(form):
                continue
            method = form.get("htv:methodName", "POST")
            body = example(a["input"]) if "input" in a else None
            r = self.http.request(method, href(form, self.td, self.ids),
                                  **({"json": body} if "input" in a else {}))
            self.performed += 1
            if form.get("response", {}).get("htv:statusCodeValue") == 201:  # the asynchronous form
                self.asynchronous(where, r, a, status_forms)
            elif 200 <= r.status_code < 300:
                if a.get("output") is not None and r.content:
                    self.json_of(where, r, a["output"])
            else:
                self.check_error(where, r, REFUSALS)
            if method == "POST":
                self.refused_with_allow(where, "GET", href(form, self.td, self.ids))

    def asynchronous(self, where: str, r: httpx.Response, a: dict, status_forms: dict[str, dict]) -> None:
        """201 + Location of a status that the queryaction form reads until it ends (its output fitting the
        output schema), after which the cancelaction form answers 409: nothing is left to cancel."""
        if r.status_code != 201:
            return self.check_error(where, r, REFUSALS)
        status = self.json_of(where, r, ACTION_STATUS) or {}
        if set(status_forms) != {"queryaction", "cancelaction"}:
            return self.wrong(where, f"an asynchronous invokeaction form without query and cancel forms: {status_forms}")
        query = status_forms["queryaction"]["href"].replace("{id}", status.get("id", ""))
        if r.headers.get("location") != query:
            self.wrong(where, f"Location {r.headers.get('location')!r}, the queryaction form gives {query!r}")
        for _ in range(600):
            status = self.json_of(where, self.http.get(query), ACTION_STATUS) or {}
            if status.get("status") not in ("pending", "running"):
                break
            __import__("time").sleep(0.05)
        self.performed += 1
        if status.get("status") == "completed" and a.get("output") is not None and "output" in status:
            if (why := fits(status["output"], a["output"])) is not None:
                self.wrong(where, f"the completed status's output breaks the output schema ({why})")
        elif status.get("status") == "failed" and status.get("error", {}).get("status") not in REFUSALS:
            self.wrong(where, f"failed with {status.get('error')}")
        r = self.http.request(status_forms["cancelaction"].get("htv:methodName", "DELETE"), query)
        self.performed += 1
        self.check_error(where, r, {409})

    def event(self, name: str, e: dict) -> None:
        where = f"events/{name}"
        for form in e["forms"]:
            url = href(form, self.td, self.ids)
            if form.get("subprotocol") == "sse":
                self.stream_opens(where, url)
            else:
                self.long_poll_waits(where, url, e.get("data"))

    def thing_forms(self) -> None:
        for form in self.td.get("forms", []):
            url, kinds = href(form, self.td, self.ids), ops(form)
            readable = {n for n, p in self.td.get("properties", {}).items()
                        if any("readproperty" in ops(f) for f in p["forms"])}
            if "readallproperties" in kinds:
                r = self.http.get(url)
                self.performed += 1
                values = self.json_of("forms/readallproperties", r, {"type": "object"}) or {}
                if set(values) != readable:
                    self.wrong("forms/readallproperties", f"answered {sorted(values)}, the TD reads {sorted(readable)}")
            if "readmultipleproperties" in kinds and readable:
                name = sorted(readable)[0]
                r = self.http.get(url, params={"names": name})
                self.performed += 1
                values = self.json_of("forms/readmultipleproperties", r, {"type": "object"}) or {}
                if set(values) != {name}:
                    self.wrong("forms/readmultipleproperties", f"asked for {name!r}, answered {sorted(values)}")
            if "writeallproperties" in kinds:
                writable = {n: p for n, p in self.td["properties"].items()
                            if any("writeproperty" in ops(f) for f in p["forms"])}
                now = self.http.get(url).json()
                body = {n: now[n] if n in now else example(p) for n, p in writable.items()}
                r = self.http.put(url, json=body)
                self.performed += 1
                if not 200 <= r.status_code < 300:
                    self.check_error("forms/writeallproperties", r, REFUSALS)
            if {"observeallproperties", "subscribeallevents"} & set(kinds):
                self.stream_opens(f"forms/{kinds[0]}", url)

    def links(self) -> None:
        for link in self.td.get("links", []):
            r = self.http.get(link["href"])
            self.performed += 1
            media = r.headers.get("content-type", "").split(";")[0]
            if r.status_code != 200 or (link.get("type") and media != link["type"]):
                self.wrong(f"links/{link['rel']}", f"{link['href']} answered {r.status_code} {media!r}, "
                                                    f"the TD says {link.get('type')!r}")

    def run(self) -> list[str]:
        for name, p in self.td.get("properties", {}).items():
            self.property(name, p)
        for name, a in self.td.get("actions", {}).items():
            self.action(name, a)
        for name, e in self.td.get("events", {}).items():
            self.event(name, e)
        self.thing_forms()
        self.links()
        return self.problems


def test_every_form_of_every_served_td_does_what_its_op_says(lab, tds):
    ids = {name: td.get("id", "") for name, td in tds.items()}
    problems, performed = [], 0
    with httpx.Client(timeout=120) as http:
        for name in sorted(tds):
            walk = Walk(http, tds[name], ids)
            problems += walk.run()
            performed += walk.performed
    print(f"\n{performed} forms performed on {len(tds)} TDs, {len(problems)} contradictions")
    assert performed > 150 and not problems, "\n".join(problems)


def test_the_walker_sees_a_form_the_server_does_not_serve(lab, tds):
    """The walk is not blind: a TD that promises a write nobody serves, or observes on its read
    href, is caught."""
    td = json.loads(json.dumps(tds["infrared-sensor-1"]))
    prop = td["properties"]["objectPresence"]
    prop["forms"][0]["op"] = ["readproperty", "writeproperty"]
    prop["forms"][1]["href"] = prop["forms"][0]["href"]
    with httpx.Client(timeout=60) as http:
        problems = Walk(http, td, {}).run()
    assert any("PUT" in p or "405" in p or "answered 4" in p for p in problems), problems
    assert any("long-poll observe form has the read form's href" in p for p in problems), problems


# --- units and link relations -------------------------------------------------------------------
def _numbers(schema: Any, path: str):
    if isinstance(schema, dict):
        if schema.get("type") in ("number", "integer") and "enum" not in schema and "const" not in schema:
            yield path, schema
        for key, value in schema.items():
            if key not in ("forms", "links", "securityDefinitions"):
                yield from _numbers(value, f"{path}/{key}")
    elif isinstance(schema, list):
        for i, value in enumerate(schema):
            yield from _numbers(value, f"{path}/{i}")


def test_every_quantity_has_a_unit_from_the_vocabulary_its_context_declares(tds):
    missing, checked = [], 0
    for name, td in tds.items():
        prefixes = {k: v for c in td["@context"] if isinstance(c, dict) for k, v in c.items()}
        for path, schema in _numbers({k: td.get(k, {}) for k in ("properties", "actions", "events")}, name):
            if NOT_QUANTITIES.search(path):
                continue
            checked += 1
            unit = schema.get("unit", "")
            if not unit.startswith(f"{PREFIX}:") or prefixes.get(PREFIX) != QUDT_UNITS:
                missing.append(f"{path}: unit {unit!r}")
    assert checked > 100 and not missing, "\n".join(missing)


def test_every_link_relation_is_registered_or_a_uri(tds):
    rels = {link["rel"] for td in tds.values() for link in td.get("links", [])}
    odd = {rel for rel in rels if rel not in REGISTERED_RELATIONS and not re.match(r"^https?://", rel)}
    assert not odd, odd
    assert "https://twinmesh.dev/rel/workspace" in rels and "describedby" in rels


def instantiated(tm: dict, base: str) -> dict:
    """A TD made from a Thing Model the way TD 1.1 §10 says: its placeholders filled, the `tm:ThingModel`
    type dropped, `version.instance` given. A model as such is no Thing: no WoT consumer takes one (wotpy
    wants `version.instance`, node-wot absolute hrefs), so what the consumers are given is this."""
    td = json.loads(json.dumps(tm).replace("{{BASE_URL}}", base))
    types = [t for t in ([td["@type"]] if isinstance(td.get("@type"), str) else td.get("@type", []))
             if t != "tm:ThingModel"]
    td.pop("@type", None)
    if types:
        td["@type"] = types
    td["version"] = {"instance": str(td.get("version", {}).get("model", "1.0.0"))}
    return td


@pytest.fixture(scope="module")
def tdgen_documents(lab, tmp_path_factory) -> dict[str, dict]:
    """What `twinmesh tdgen` writes: a TD for the lab's ur10 URL, and a Thing Model."""
    out = tmp_path_factory.mktemp("tdgen-out")
    for kind, url in (("td", f"{lab.http}/ur10"), ("tm", None)):
        done = lab.cli("tdgen", "ur10.urdf", "--samples", "500", "--workers", "1", "--no-progress",
                       "--out", str(out / kind), *(("--base-url", url) if url else ()), timeout=300)
        assert done.returncode == 0, done.stderr
    return {kind: json.loads((out / kind / f"{kind}.json").read_text()) for kind in ("td", "tm")}


# --- the Thingweb TD Playground -----------------------------------------------------------------
def test_every_served_td_and_tdgen_output_passes_the_thingweb_playground(lab, tds, tdgen_documents):
    documents = [{"name": name, "kind": "td", "document": td} for name, td in sorted(tds.items())]
    documents += [{"name": f"tdgen {kind}.json", "kind": kind, "document": document}
                  for kind, document in tdgen_documents.items()]
    results = npm.playground(documents)
    failures = []
    for r in results:
        checks = {**r["report"], **r["details"]}
        failed = [f"{k} {v}" for k, v in checks.items() if v == "failed"]
        if failed or r["failed"]:
            failures.append(f"{r['name']}: {failed} assertions {r['failed']}\n  " + "\n  ".join(r["log"][:10]))
    passed = sum(r["counts"].get("pass", 0) for r in results)
    print(f"\nThingweb Playground: {len(results)} documents, {passed} assertions passed, "
          f"JSON-LD {sum(r['report']['jsonld'] == 'passed' for r in results)}/{len(results)}")
    assert not failures, "\n".join(failures)
    assert all(r["report"]["jsonld"] == "passed" and r["report"]["schema"] == "passed" for r in results)


# --- every WoT consumer: node-wot 0.9.2 and wotpy 0.18.0 -----------------------------------------
def _readable(td: dict) -> list[str]:
    return [n for n, p in td.get("properties", {}).items()
            if not p.get("writeOnly") and any("readproperty" in ops(f) for f in p.get("forms", []))]


def _agrees(got: Any, before: Any, after: Any) -> bool:
    """A consumer's read agrees with plain HTTP reads taken just before and after it: equal to one of
    them, or, for an object whose live members (a clock) moved between the two, equal in every other."""
    if got in (before, after):
        return True
    if isinstance(got, dict) and isinstance(before, dict) and isinstance(after, dict) and set(got) == set(before):
        still = [k for k in before if before[k] == after.get(k)]
        return all(got[k] == before[k] for k in still)
    return isinstance(got, (int, float)) and isinstance(before, (int, float)) and isinstance(after, (int, float)) \
        and min(before, after) <= got <= max(before, after)  # a number that moves on (a simulation clock)


def test_wotpy_consumes_every_served_td_and_reads_what_http_reads(lab, tds, tdgen_documents):
    """wotpy, the Python WoT runtime, consumes each Thing of the iot-lab and tdgen's TD and its TM made a TD; every
    readable property of every served Thing reads the same through wotpy as over plain HTTP."""
    import asyncio

    pytest.importorskip("wotpy", reason="wotpy is in the test extras: pip install -e '.[test]'")
    from wotpy.wot.servient import Servient
    from wotpy.wot.wot import WoT

    async def read_all() -> tuple[list[str], int]:
        wot = WoT(servient=Servient(catalogue_port=None))
        wrong, reads = [], 0
        for kind, document in tdgen_documents.items():
            try:
                wot.consume(json.dumps(document if kind == "td" else instantiated(document, f"{lab.http}/ur10")))
            except Exception as e:  # noqa: BLE001 - any failure of the consumer is the finding
                wrong.append(f"tdgen {kind}.json: not consumed: {e!r}")
        async with httpx.AsyncClient(base_url=lab.http, timeout=60) as http:
            for name, td in sorted(tds.items()):
                if name == "directory":
                    continue
                try:
                    thing = wot.consume(json.dumps(td))
                except Exception as e:  # noqa: BLE001
                    wrong.append(f"{name}: not consumed: {e!r}")
                    continue
                for prop in _readable(td):
                    before = (await http.get(f"/{name}/properties/{prop}")).json()
                    try:
                        got = await thing.read_property(prop, timeout=60)
                    except Exception as e:  # noqa: BLE001
                        wrong.append(f"{name}.{prop}: wotpy could not read it: {e!r}")
                        continue
                    after = (await http.get(f"/{name}/properties/{prop}")).json()
                    reads += 1
                    if not _agrees(got, before, after):
                        wrong.append(f"{name}.{prop}: wotpy read {got!r}, HTTP {before!r} / {after!r}")
        return wrong, reads

    wrong, reads = asyncio.run(read_all())
    assert not wrong, "\n".join(wrong)
    assert reads >= 25, f"only {reads} properties read"  # 14 Things, 26 readable properties


def test_node_wot_consumes_every_served_td_and_tdgen_output_and_reads_what_http_reads(lab, tds, tdgen_documents,
                                                                                       tmp_path):
    wrong = []
    for kind, document in tdgen_documents.items():
        path = tmp_path / f"{kind}.json"
        path.write_text(json.dumps(document if kind == "td" else instantiated(document, f"{lab.http}/ur10")))
        try:
            npm.run_client(path.as_uri(), [{"op": "readProperty", "name": "getJointposition"}])
        except npm.TDConsumeError as e:
            wrong.append(f"tdgen {kind}.json: not consumed: {e}")
    with httpx.Client(base_url=lab.http, timeout=60) as http:
        for name, td in sorted(tds.items()):
            if name == "directory":
                continue
            readable = _readable(td)
            before = {p: http.get(f"/{name}/properties/{p}").json() for p in readable}
            try:
                results = npm.run_client(f"{lab.http}/{name}", [{"op": "readProperty", "name": p} for p in readable])
            except npm.TDConsumeError as e:
                wrong.append(f"{name}: not consumed: {e}")
                continue
            after = {p: http.get(f"/{name}/properties/{p}").json() for p in readable}
            for prop, r in zip(readable, results):
                if not r["ok"]:
                    wrong.append(f"{name}.{prop}: node-wot could not read it: {r.get('error')}")
                elif not _agrees(r["value"], before[prop], after[prop]):
                    wrong.append(f"{name}.{prop}: node-wot read {r['value']!r}, HTTP {before[prop]!r} / {after[prop]!r}")
    assert not wrong, "\n".join(wrong)
