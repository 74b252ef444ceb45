"""The node-wot interop harness (tests/interop) proven against node-wot's own HTTP servient.

Real processes, no mocks: servient-baseline.mjs serves a light-left equivalent and wot-client.mjs
consumes it. This also documents what node-wot's own server does on the wire (500 for invalid
input, 204 for actions without output, long-poll observation; the SSE forms are the baseline's own).
"""
import socket

import httpx
import pytest
from interop import npm

pytestmark = [pytest.mark.interop, pytest.mark.timeout(120)]

CREDENTIALS = {"username": "lab", "password": "s3cret:with colon"}


@pytest.fixture(scope="module")
def baseline():
    with npm.start_baseline_servient() as servient:
        yield servient


@pytest.fixture()
def td_url(baseline):
    """The baseline's TD URL, with the light switched off and white again."""
    url = baseline.td_url()
    td = httpx.get(url).json()
    state = td["properties"]["lightState"]["forms"][0]["href"]
    set_color = td["actions"]["setColor"]["forms"][0]["href"]
    httpx.put(state, json=False).raise_for_status()
    httpx.post(set_color, json={"r": 1, "g": 1, "b": 1}).raise_for_status()
    return url


def test_read_write_invoke(td_url):
    results = npm.run_client(td_url, [
        {"op": "readProperty", "name": "lightState"},
        {"op": "writeProperty", "name": "lightState", "value": True},
        {"op": "readProperty", "name": "lightState"},
        {"op": "invokeAction", "name": "setColor", "input": {"r": 1, "g": 0, "b": 0.5}},
        {"op": "invokeAction", "name": "switchOff"},
        {"op": "readAllProperties"},
    ])
    assert [r["op"] for r in results] == ["readProperty", "writeProperty", "readProperty", "invokeAction",
                                          "invokeAction", "readAllProperties"]
    assert all(r["ok"] for r in results), results
    assert results[0]["value"] is False
    assert results[2]["value"] is True
    assert results[3]["value"] == [1, 0, 0.5]
    assert "value" not in results[4]  # no output: node-wot's server answers 204
    assert results[5]["value"] == {"lightState": False, "lightColor": [1, 0, 0.5]}


def test_errors_are_results(td_url):
    results = npm.run_client(td_url, [
        {"op": "writeProperty", "name": "lightState", "value": "yes"},  # node-wot does not validate inputs
        {"op": "invokeAction", "name": "setColor", "input": {"r": 2, "g": 0, "b": 0}},
        {"op": "readProperty", "name": "noSuchProperty"},
        {"op": "readProperty", "name": "lightState"},
    ])
    # node-wot's own server answers invalid input with a bare 500; the client only keeps the status text.
    assert results[0] == {"i": 0, "op": "writeProperty", "ok": False, "error": "Server error: Internal Server Error"}
    assert results[1]["error"] == "Server error: Internal Server Error"
    assert "does not have property noSuchProperty" in results[2]["error"]
    assert results[3] == {"i": 3, "op": "readProperty", "ok": True, "value": False}


def test_observe_in_background_while_writing(td_url):
    # Long-poll loses changes made while no GET is parked: let each notification arrive before the next change.
    results = npm.run_client(td_url, [
        {"op": "observeProperty", "name": "lightState", "count": 2, "background": True, "id": "state"},
        {"op": "writeProperty", "name": "lightState", "value": True},
        {"op": "await", "ref": "state", "count": 1},
        {"op": "writeProperty", "name": "lightState", "value": False},
        {"op": "await", "ref": "state"},
    ])
    assert results[0] == {"i": 0, "op": "observeProperty", "id": "state", "ok": True, "started": True}
    assert results[2]["values"] == [True]
    assert results[4] == {"i": 4, "op": "await", "ok": True, "values": [True, False]}


def test_sse_delivers_back_to_back_changes(td_url):
    td = httpx.get(td_url).json()
    state_sse = npm.form_index(td, "properties", "lightState", "observeproperty", "sse")
    event_sse = npm.form_index(td, "events", "stateChanged", "subscribeevent", "sse")
    results = npm.run_client(td_url, [
        {"op": "observeProperty", "name": "lightState", "formIndex": state_sse, "count": 2, "background": True},
        {"op": "subscribeEvent", "name": "stateChanged", "formIndex": event_sse, "count": 2, "background": True},
        {"op": "writeProperty", "name": "lightState", "value": True},
        {"op": "writeProperty", "name": "lightState", "value": False},
        {"op": "await", "ref": 0},
        {"op": "await", "ref": 1},
    ])
    assert all(r["ok"] for r in results), results
    assert results[4]["values"] == results[5]["values"] == [True, False]


def test_subscribe_event_and_observe_by_form_index(td_url):
    results = npm.run_client(td_url, [
        {"op": "subscribeEvent", "name": "stateChanged", "count": 2, "background": True},
        {"op": "observeProperty", "name": "lightColor", "formIndex": 1, "background": True},
        {"op": "invokeAction", "name": "switchOn"},
        {"op": "await", "ref": 0, "count": 1},
        {"op": "invokeAction", "name": "switchOff"},
        {"op": "invokeAction", "name": "setColor", "input": {"r": 0, "g": 1, "b": 0}},
        {"op": "await", "ref": 0},
        {"op": "await", "ref": 1},
    ])
    assert all(r["ok"] for r in results), results
    assert results[6]["values"] == [True, False]
    assert results[7]["values"] == [[0, 1, 0]]


def test_foreground_observe_times_out_with_partial_result(td_url):
    [result] = npm.run_client(td_url, [{"op": "observeProperty", "name": "lightColor", "timeoutMs": 300}])
    assert result["ok"] is False and result["timeout"] is True
    assert result["values"] == []


def test_td_that_cannot_be_fetched(baseline):
    with pytest.raises(npm.TDConsumeError) as caught:
        npm.run_client(baseline.td_url().replace("light-left", "no-such-thing"), [])
    assert caught.value.message == "Client error: Not Found"


def test_several_things_from_one_process_each_get_their_own_results(td_url, baseline):
    missing = baseline.td_url().replace("light-left", "no-such-thing")
    steps = [{"op": "writeProperty", "name": "lightState", "value": True}, {"op": "readProperty", "name": "lightState"}]
    read = [{"op": "readProperty", "name": "lightColor"}]
    written, failed, colour = npm.run_clients([(td_url, steps), (missing, read), (td_url, read)], parallel=2)
    assert [r["ok"] for r in written] == [True, True] and written[1]["value"] is True
    assert isinstance(failed, npm.TDConsumeError) and failed.message == "Client error: Not Found"
    assert colour == [{"i": 0, "op": "readProperty", "ok": True, "value": [1, 1, 1]}]


def test_bad_script_is_a_harness_failure(td_url):
    with pytest.raises(npm.HarnessError, match="op must be one of"):
        npm.run_client(td_url, [{"op": "teleport"}])
    with pytest.raises(npm.HarnessError, match="ref must name an earlier background step"):
        npm.run_client(td_url, [{"op": "await", "ref": "nothing"}])


def test_basic_credentials_by_td_id():
    with npm.start_baseline_servient(credentials=CREDENTIALS) as servient:
        steps = [{"op": "writeProperty", "name": "lightState", "value": True},
                 {"op": "readProperty", "name": "lightState"}]
        anonymous = npm.run_client(servient.td_url(), steps)  # the TD itself is public
        # Without credentials node-wot fails its first request locally (a TypeError while setting up
        # basic auth), then sends the next ones without Authorization.
        assert "username" in anonymous[0]["error"]
        assert anonymous[1]["error"] == "Client error: Unauthorized"
        assert npm.run_client(servient.td_url(), steps, credentials=CREDENTIALS)[1]["value"] is True
        wrong = npm.run_client(servient.td_url(), steps[1:], credentials={**CREDENTIALS, "password": "no"})
        assert wrong[0]["error"] == "Client error: Unauthorized"
        # Long-poll carries the credentials; node-wot's SSE requests never do, and its error says nothing.
        td = httpx.get(servient.td_url()).json()
        observe = [{"op": "observeProperty", "name": "lightState", "background": True},
                   {"op": "observeProperty", "name": "lightState", "background": True,
                    "formIndex": npm.form_index(td, "properties", "lightState", "observeproperty", "sse")}]
        longpoll, sse = npm.run_client(servient.td_url(), observe, credentials=CREDENTIALS)
        assert longpoll["ok"] is True
        assert sse == {"i": 1, "op": "observeProperty", "ok": False, "error": "[object Object]"}


def test_baseline_leaves_no_process_behind():
    with npm.start_baseline_servient() as servient:
        process, port = servient.process, servient.port
        assert process.poll() is None
    assert process.poll() is not None
    with socket.socket() as probe:
        assert probe.connect_ex(("127.0.0.1", port)) != 0
