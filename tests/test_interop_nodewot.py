"""node-wot 0.9.2, the reference WoT client, consumes the adapter's Things (tests/interop harness).

Long-poll note: a change made while no GET is parked is not seen by that observer (inherent to
long-poll), so each background observation gets its first notification awaited before the next
change, as node-wot users would have to.
"""
from __future__ import annotations

import httpx
import pytest
from interop import npm
from labs import start_lab

pytestmark = [pytest.mark.lab, pytest.mark.interop, pytest.mark.timeout(180)]

TOKEN = "n0de-wot-token"


@pytest.fixture(scope="module")
def lab(lights):
    npm.ensure_node_modules()
    return lights  # the session's lights lab, lent to this module (conftest.py)


@pytest.fixture()
def td_url(lab):
    """light-left's TD URL, the light off and white."""
    base = f"{lab.http}/light-left"
    httpx.put(f"{base}/properties/lightState", json=False).raise_for_status()
    httpx.post(f"{base}/actions/setColor", json={"r": 1, "g": 1, "b": 1}).raise_for_status()
    return base


@pytest.mark.parametrize("thing", ["light-left", "light-right"])
def test_node_wot_consumes_every_td(lab, thing):
    assert npm.run_client(f"{lab.http}/{thing}", [{"op": "readProperty", "name": "lightState"}])[0]["ok"]


def test_read_write_invoke(td_url):
    results = npm.run_client(td_url, [
        {"op": "readProperty", "name": "lightState"},
        {"op": "writeProperty", "name": "lightState", "value": True},
        {"op": "readProperty", "name": "lightState"},
        {"op": "invokeAction", "name": "setColor", "input": {"r": 1, "g": 0, "b": 0.5}},
        {"op": "invokeAction", "name": "switchOff"},
        {"op": "readProperty", "name": "lightState"},
        {"op": "readAllProperties"},
    ])
    assert all(r["ok"] for r in results), results
    assert [results[0]["value"], results[2]["value"], results[5]["value"]] == [False, True, False]
    assert results[3]["value"] == [1, 0, 0.5]
    assert "value" not in results[4]  # no output: 204
    assert results[6]["value"] == {"lightState": False, "lightColor": [1, 0, 0.5]}


def test_invalid_write_is_refused_and_state_kept(td_url):
    results = npm.run_client(td_url, [
        {"op": "writeProperty", "name": "lightState", "value": "yes"},
        {"op": "writeProperty", "name": "lightColor", "value": [2, 0, 0]},
        {"op": "invokeAction", "name": "setColor", "input": {"r": 2, "g": 0, "b": 0}},
        {"op": "readAllProperties"},
    ])
    # node-wot keeps only the status text of our 400 problem+json
    assert [r.get("error") for r in results[:3]] == ["Client error: Bad Request"] * 3, results
    assert results[3]["value"] == {"lightState": False, "lightColor": [1, 1, 1]}


@pytest.mark.parametrize("subprotocol", ["longpoll", "sse"])
def test_observe_property(td_url, subprotocol):
    td = httpx.get(td_url).json()
    index = npm.form_index(td, "properties", "lightState", "observeproperty", subprotocol)
    color = npm.form_index(td, "properties", "lightColor", "observeproperty", subprotocol)
    results = npm.run_client(td_url, [
        {"op": "observeProperty", "name": "lightState", "formIndex": index, "count": 2, "background": True},
        {"op": "observeProperty", "name": "lightColor", "formIndex": color, "count": 1, "background": True},
        {"op": "writeProperty", "name": "lightState", "value": True},
        {"op": "await", "ref": 0, "count": 1},
        {"op": "writeProperty", "name": "lightState", "value": False},
        {"op": "invokeAction", "name": "setColor", "input": {"r": 0, "g": 1, "b": 0}},
        {"op": "await", "ref": 0},
        {"op": "await", "ref": 1},
    ])
    assert all(r["ok"] for r in results), results
    assert results[6]["values"] == [True, False]
    assert results[7]["values"] == [[0, 1, 0]]


def test_default_observe_form_is_long_poll(td_url):
    """node-wot picks the first form with the op: ours is the long-poll one."""
    results = npm.run_client(td_url, [
        {"op": "observeProperty", "name": "lightState", "count": 1, "background": True},
        {"op": "invokeAction", "name": "switchOn"},
        {"op": "await", "ref": 0},
    ])
    assert results[2]["values"] == [True], results


@pytest.mark.parametrize("subprotocol", ["longpoll", "sse"])
def test_subscribe_event(td_url, subprotocol):
    td = httpx.get(td_url).json()
    index = npm.form_index(td, "events", "stateChanged", "subscribeevent", subprotocol)
    results = npm.run_client(td_url, [
        {"op": "subscribeEvent", "name": "stateChanged", "formIndex": index, "count": 2, "background": True},
        {"op": "invokeAction", "name": "switchOn"},
        {"op": "await", "ref": 0, "count": 1},
        {"op": "invokeAction", "name": "switchOff"},
        {"op": "await", "ref": 0},
    ])
    assert all(r["ok"] for r in results), results
    assert results[4]["values"] == [True, False]


def test_bearer_token_by_td_id(tmp_path):
    lab = start_lab(tmp_path, "lights", http=True, things={"light-left"}, extra_args=("--auth", f"bearer:{TOKEN}"))
    try:
        url = f"{lab.http}/light-left"
        steps = [{"op": "writeProperty", "name": "lightState", "value": True},
                 {"op": "readProperty", "name": "lightState"},
                 {"op": "observeProperty", "name": "lightState", "count": 1, "background": True},
                 {"op": "invokeAction", "name": "switchOff"},
                 {"op": "await", "ref": 2}]
        results = npm.run_client(url, steps, credentials={"token": TOKEN})
        assert all(r["ok"] for r in results), results
        assert results[1]["value"] is True and results[4]["values"] == [False]
        wrong = npm.run_client(url, steps[:2], credentials={"token": "wrong"})
        assert [r["error"] for r in wrong] == ["Client error: Unauthorized"] * 2
        # node-wot's SSE client sends no Authorization header: with auth on, SSE is refused (see auth.py)
        td = httpx.get(url).json()
        sse = npm.form_index(td, "properties", "lightState", "observeproperty", "sse")
        [refused] = npm.run_client(url, [{"op": "observeProperty", "name": "lightState", "formIndex": sse,
                                          "background": True}], credentials={"token": TOKEN})
        assert refused["ok"] is False
    finally:
        assert lab.stop(), "the lab did not stop cleanly"


def test_node_wot_uses_the_directory_td(lab):
    """/.well-known/wot is a Thing too: node-wot reads `things` (URI template with paging) and
    invokes `retrieveThing` with the id as a URI variable."""
    results = npm.run_client(f"{lab.http}/.well-known/wot", [
        {"op": "readProperty", "name": "things"},
        {"op": "readProperty", "name": "things", "uriVariables": {"offset": 1, "limit": 1}},
        {"op": "invokeAction", "name": "retrieveThing", "uriVariables": {"id": "urn:twinmesh:thing:light-left"}},
    ])
    assert all(r["ok"] for r in results), results
    assert [td["title"] for td in results[0]["value"]] == ["light-left", "light-right", "tdgen"]
    assert [td["title"] for td in results[1]["value"]] == ["light-right"]
    assert results[2]["value"]["id"] == "urn:twinmesh:thing:light-left"
