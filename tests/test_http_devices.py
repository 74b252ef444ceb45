"""The adapter against devices other than the lights: a `probe` Thing with linked files, read-only,
write-only, slow and refusing affordances and schemas without `type`. The probe
device and the helper that starts it are in probe.py.
"""
from __future__ import annotations

import threading
import time
from urllib.parse import quote

import httpx
import pytest
from labs import free_port, interrupt
from probe import CSV, STL, poll, spawn_device
from tdschema import assert_valid_td

pytestmark = pytest.mark.lab


@pytest.fixture(scope="module")
def lab(lights):  # the session's lights lab, lent to this module (conftest.py)
    lab = lights
    spawn_device(lab, "probe", "probe")
    listed, waited = poll(lambda: "probe" in [t["title"] for t in httpx.get(f"{lab.http}/things").json()], 10)
    assert waited is not None, "the adapter did not list the probe"
    yield lab


@pytest.fixture(scope="module")
def td(lab):
    return httpx.get(f"{lab.http}/probe").json()


def test_probe_td_is_valid_and_every_schema_has_a_type(td):
    assert_valid_td(td)
    assert td["properties"]["mode"]["type"] == "string"
    assert td["actions"]["add"]["input"]["type"] == "object"
    assert all(a["synchronous"] is True for a in td["actions"].values())


def test_only_allowed_ops_are_in_the_forms(td):
    assert td["properties"]["serial"]["forms"][0]["op"] == ["readproperty"]
    assert td["properties"]["secret"]["forms"][0]["op"] == ["writeproperty"]
    assert len(td["properties"]["serial"]["forms"]) == 1, "not observable: no observe forms"


def test_relative_links_become_adapter_urls_and_files_download(lab, td):
    links = {link["rel"]: link for link in td["links"]}
    assert links["self"]["href"] == f"{lab.http}/probe"
    assert links["workspace"]["href"] == f"{lab.http}/probe/files/workspace.stl"
    assert links["describedby"]["href"] == "https://www.w3.org/TR/wot-thing-description11/"
    for rel, body, media in [("workspace", STL, "model/stl"), ("dataset-points", CSV, "text/csv")]:
        r = httpx.get(links[rel]["href"])
        assert r.status_code == 200 and r.content == body
        assert r.headers["content-type"].startswith(media)


def test_unknown_file_is_404(lab):
    r = httpx.get(f"{lab.http}/probe/files/nothing.bin")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"


def test_read_only_and_write_only_are_405_with_allow(lab):
    r = httpx.put(f"{lab.http}/probe/properties/serial", json="X")
    assert r.status_code == 405 and r.headers["allow"] == "GET, HEAD"
    assert r.headers["content-type"] == "application/problem+json"
    r = httpx.get(f"{lab.http}/probe/properties/secret")
    assert r.status_code == 405 and r.headers["allow"] == "PUT"
    assert httpx.put(f"{lab.http}/probe/properties/secret", json="hunter2").status_code == 204
    assert httpx.get(f"{lab.http}/probe/properties/serial").json() == "P-001"


def test_device_refusal_keeps_its_status_and_reason(lab):
    r = httpx.post(f"{lab.http}/probe/actions/refuse")
    assert r.status_code == 422 and r.headers["content-type"] == "application/problem+json"
    body = r.json()
    assert body["reason"] == "always" and body["detail"] == "the probe refuses everything"


def test_inferred_input_type_still_validates(lab):
    assert httpx.post(f"{lab.http}/probe/actions/add", json={"a": 1, "b": 2}).json() == 3
    r = httpx.post(f"{lab.http}/probe/actions/add", json={"a": "1", "b": 2})
    assert r.status_code == 400 and "input.a: expected integer" in r.json()["detail"]
    r = httpx.post(f"{lab.http}/probe/actions/add", json=[1, 2])
    assert r.status_code == 400 and "expected object" in r.json()["detail"]


def test_enum_without_type_is_enforced(lab):
    r = httpx.put(f"{lab.http}/probe/properties/mode", json="c")
    assert r.status_code == 400 and "is not one of" in r.json()["detail"]
    assert httpx.put(f"{lab.http}/probe/properties/mode", json="b").status_code == 204
    assert httpx.get(f"{lab.http}/probe/properties/mode").json() == "b"


def test_device_that_does_not_answer_in_time_is_504(lab):
    started = time.monotonic()
    r = httpx.get(f"{lab.http}/probe/properties/slow", timeout=30)
    took = time.monotonic() - started
    assert r.status_code == 504, f"{r.status_code} {r.text} after {took:.1f} s"
    assert r.headers["content-type"] == "application/problem+json"


def test_td_by_id_and_gone_probe_is_503(lab):
    second = spawn_device(lab, "probe", "probe-2")
    url = f"{lab.http}/things/{quote('urn:twinmesh:thing:probe-2', safe='')}"
    r, waited = poll(lambda: (x := httpx.get(url)).status_code == 200 and x, 5)
    assert waited is not None, f"/things/<id> did not serve probe-2: {r}"
    assert r.headers["content-type"] == "application/td+json" and r.json()["title"] == "probe-2"
    second.kill()
    gone, waited = poll(lambda: httpx.get(url).status_code == 503, 5)
    assert gone, "a TD whose Thing left must answer 503"
    assert httpx.get(f"{lab.http}/probe-2").status_code == 503
    assert "probe-2" not in [t["title"] for t in httpx.get(f"{lab.http}/things").json()]
    assert httpx.get(f"{lab.http}/things/{quote('urn:nothing', safe='')}").status_code == 404


HOLD = 4  # s; the device itself cannot stop before its handler returns


def test_adapter_stops_on_ctrl_c_with_an_action_in_flight(lab, tmp_path):
    port = free_port()
    adapter = lab.spawn("adapter", "--http", f"127.0.0.1:{port}", log=tmp_path / "adapter.log")
    base = f"http://127.0.0.1:{port}"
    _, ready = poll(lambda: _ok(f"{base}/probe"), 30, every=0.2)
    assert ready is not None, (tmp_path / "adapter.log").read_text()
    box: dict = {}
    caller = threading.Thread(target=lambda: box.setdefault("r", _call(f"{base}/probe/actions/hold", HOLD)),
                              daemon=True)
    caller.start()
    time.sleep(0.5)  # the action is running on the device, its query blocked in a worker thread
    started = time.monotonic()
    interrupt(adapter, tmp_path / "adapter.log")
    caller.join(5)
    assert box["r"] == 503, "a request cut short by the shutdown is told so"
    time.sleep(max(0.0, HOLD - (time.monotonic() - started)))  # let the probe finish it: it stops cleanly then


def _ok(url: str) -> bool:
    try:
        return httpx.get(url, timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


def _call(url: str, seconds: float):
    try:
        return httpx.post(url, json=seconds, timeout=90).status_code
    except httpx.HTTPError as e:
        return type(e).__name__
