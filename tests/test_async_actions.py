"""Asynchronous actions (WoT TD 1.1 queryaction / cancelaction / queryallactions, WoT Profile status
objects) on a real lab: a UR10 at a quarter of real time, so that a move lasts long enough to be
queried while it runs and cancelled half-way, over HTTP and over Zenoh.
"""
from __future__ import annotations

import time
from concurrent.futures import ThreadPoolExecutor

import httpx
import pytest
from labs import mesh_client
from waiting import always, eventually

from mesh.wot.invocation import Invocations
from mesh.wot.problem import BadInput, Conflict, NotFound

pytestmark = pytest.mark.lab

PROBLEM = "application/problem+json"
JOINTS = ("shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint", "wrist_1_joint", "wrist_2_joint", "wrist_3_joint")



@pytest.fixture(scope="module")
def lab(lights):  # the session's lights lab, lent to this module (conftest.py)
    lab = lights
    lab.spawn("robot", "ur10.urdf", "--name", "ur10", "--samples", "3000", "--speed", "0.25",
              log=lab.tmp / "ur10.log")
    # the generated TD (Cartesian bounds) is not needed: joint moves
    eventually(lambda: httpx.get(f"{lab.http}/ur10", timeout=5).status_code == 200, timeout=120,
               what=f"the ur10 served\n{(lab.tmp / 'ur10.log')}")
    yield lab


@pytest.fixture
def http(lab):
    with httpx.Client(base_url=lab.http, timeout=60) as h:
        yield h


def goal(pan: float) -> dict[str, float]:
    """Upright, turned to `pan` degrees: a move between two such goals is a turn of the base alone."""
    return {"shoulder_pan_joint": pan, "shoulder_lift_joint": -90.0, "elbow_joint": 0.0, "wrist_1_joint": -90.0,
            "wrist_2_joint": 0.0, "wrist_3_joint": 0.0}


def joints(http) -> dict[str, float]:
    return http.get("/ur10/properties/getJointposition").json()


def until_ended(http, location: str, timeout: float = 120.0) -> dict:
    def ended() -> dict | None:
        status = http.get(location).json()
        return status if status["status"] not in ("pending", "running") else None
    return eventually(ended, timeout=timeout, what=f"{location} ended")


def at(http, pan: float) -> None:
    r = http.post("/ur10/actions/moveToJointPosition", json=goal(pan))  # synchronous: node-wot's first form
    assert r.status_code == 200, r.text


def test_the_td_offers_sync_invocation_first_then_async_query_and_cancel(http):
    td = http.get("/ur10").json()
    forms = td["actions"]["moveToJointPosition"]["forms"]
    assert [f["op"] for f in forms] == ["invokeaction", "invokeaction", "queryaction", "cancelaction"]
    assert forms[0]["href"].endswith("/ur10/actions/moveToJointPosition")  # what node-wot 0.9.2 takes
    assert forms[1]["href"].endswith("?async=true") and forms[1]["response"]["htv:statusCodeValue"] == 201
    assert forms[3]["htv:methodName"] == "DELETE" and forms[2]["href"] == forms[3]["href"]
    assert "{id}" in forms[2]["href"] and "id" in td["actions"]["moveToJointPosition"]["uriVariables"]
    assert {"op": "queryallactions", "href": str(http.base_url).rstrip("/") + "/ur10/actions",
            "contentType": "application/json", "htv:methodName": "GET"} in td["forms"]


def test_an_async_move_answers_201_is_running_when_queried_and_completed_after(http):
    at(http, 0)
    r = http.post("/ur10/actions/moveToJointPosition?async=true", json=goal(60))
    assert r.status_code == 201, r.text
    status = r.json()
    location = r.headers["location"]
    assert status["href"] == location and location.endswith(f"/ur10/actions/moveToJointPosition/{status['id']}")
    assert status["status"] in ("pending", "running") and status["timeRequested"].endswith("Z")
    eventually(lambda: joints(http)["shoulder_pan_joint"] > 0, what="the UR10 on its way")
    running = http.get(location).json()
    assert running["status"] == "running" and "timeStarted" in running
    assert joints(http)["shoulder_pan_joint"] < 60  # on its way
    done = until_ended(http, location)
    assert done["status"] == "completed", done
    out = done["output"]  # the answer a synchronous move gives
    assert out["path"]["joints"] == list(JOINTS) and out["path"]["points"][-1][0] == pytest.approx(60, abs=1e-6)
    assert done["timeEnded"] >= done["timeStarted"] >= done["timeRequested"]
    assert joints(http) == pytest.approx(goal(60), abs=1e-6)
    listed = http.get("/ur10/actions").json()
    assert status["id"] in [s["id"] for s in listed["moveToJointPosition"]]
    assert all(s["href"].endswith(s["id"]) for s in listed["moveToJointPosition"])


def test_a_cancelled_move_stops_short_of_the_target_and_says_cancelled(http):
    at(http, 0)
    r = http.post("/ur10/actions/moveToJointPosition", json=goal(120), headers={"Prefer": "respond-async"})
    assert r.status_code == 201 and r.headers["preference-applied"] == "respond-async", r.text
    location = r.headers["location"]
    eventually(lambda: joints(http)["shoulder_pan_joint"] >= 20, timeout=30, what="20 degrees on its way")
    cancelled = http.delete(location)
    assert cancelled.status_code == 204, cancelled.text
    status = http.get(location).json()
    assert status["status"] == "cancelled" and status["error"]["status"] == 409, status
    stopped = status["error"]["extra"]["joints"]["shoulder_pan_joint"]
    assert 20 <= stopped < 110, status  # short of the target
    always(lambda: joints(http)["shoulder_pan_joint"] == pytest.approx(stopped, abs=1e-6), 0.5,
           what="the UR10 stays where it stopped")
    again = http.delete(location)
    assert again.status_code == 409 and again.headers["content-type"].startswith(PROBLEM)
    assert again.json()["reason"] == "already-ended"
    at(http, 0)  # it serves on: a new move from where it stopped


def test_an_async_invoke_with_bad_input_is_refused_up_front_and_nothing_starts(http):
    at(http, 0)
    before = http.get("/ur10/actions").json().get("moveToJointPosition", [])
    for body in ({"shoulder_pan_joint": 10}, {**goal(10), "shoulder_pan_joint": 9999}, "up"):
        r = http.post("/ur10/actions/moveToJointPosition?async=true", json=body)
        assert r.status_code == 400 and r.headers["content-type"].startswith(PROBLEM), r.text
        assert "location" not in r.headers and "input" in r.json()["detail"]
    assert http.get("/ur10/actions").json().get("moveToJointPosition", []) == before
    assert joints(http)["shoulder_pan_joint"] == pytest.approx(0, abs=1e-6)
    assert http.post("/ur10/actions/moveToJointPosition?async=perhaps", json=goal(10)).status_code == 400


def test_unknown_or_malformed_invocation_ids_are_404_and_never_reach_the_mesh(http):
    for id in ("0" * 32, "*", "abc;cancel", "0123", "f" * 33, "F" * 32):
        for method in ("GET", "DELETE"):
            r = http.request(method, f"/ur10/actions/moveToJointPosition/{id}")
            assert r.status_code == 404 and r.headers["content-type"].startswith(PROBLEM), (id, method, r.text)
    assert http.get("/ur10/actions/noSuchAction/" + "0" * 32).status_code == 404


def test_over_zenoh_a_move_is_started_queried_and_cancelled_and_wildcards_only_read(lab, http):
    at(http, 0)
    with mesh_client(lab.endpoint) as c:
        started = c.invoke_async("ur10", "moveToJointPosition", goal(90))
        assert started.status in ("pending", "running")
        eventually(lambda: joints(http)["shoulder_pan_joint"] > 0, what="the UR10 on its way")
        assert c.query_action("ur10", "moveToJointPosition", started.id).status == "running"
        # cancelling acts: a query on a wildcard key may read the calls but not cancel
        replies = list(c.session.get(f"wot/*/actions/moveToJointPosition?id={started.id};cancel", timeout=5))
        assert replies and all(r.ok is None for r in replies)
        assert c.query_action("ur10", "moveToJointPosition", started.id).status == "running"
        assert started.id in [s.id for s in c.query_all_actions("ur10")["moveToJointPosition"]]
        ended = c.cancel_action("ur10", "moveToJointPosition", started.id)
        assert ended.status == "cancelled" and ended.error is not None and ended.error["status"] == 409
        with pytest.raises(Conflict):
            c.cancel_action("ur10", "moveToJointPosition", started.id)
        with pytest.raises(BadInput):
            c.invoke_async("ur10", "moveToJointPosition", {"shoulder_pan_joint": 1})
        with pytest.raises(NotFound):
            c.query_action("ur10", "moveToJointPosition", "0" * 32)
    assert joints(http)["shoulder_pan_joint"] < 85


def test_finished_invocations_are_kept_for_a_bounded_time_and_count():
    with ThreadPoolExecutor(2) as pool:
        kept = Invocations(pool, keep=3, keep_for=0.5)
        ids = [kept.start("blink", lambda i=i: i).id for i in range(5)]
        eventually(lambda: all(s.status == "completed" for s in kept.all()), timeout=5)
        assert [s.output for s in kept.all()] == [2, 3, 4]  # the oldest two went first
        with pytest.raises(NotFound):
            kept.get(ids[0])
        eventually(lambda: kept.all() == [], timeout=5, what="finished invocations forgotten after keep_for")
        with pytest.raises(NotFound):
            kept.get(ids[4])


def test_a_cancel_that_meets_an_action_finishing_by_itself_is_409_with_the_final_status():
    """The action ends `completed` while the DELETE waits (it does not heed cancellation): the answer is
    the documented 409 for an ended action, with its final status, never a 202 that shows `completed`."""
    import threading

    started = threading.Event()

    def stubborn() -> str:
        started.set()
        time.sleep(0.3)  # finishes on its own, whatever is asked
        return "done"

    with ThreadPoolExecutor(2) as pool:
        kept = Invocations(pool)
        status = kept.start("blink", stubborn)
        assert started.wait(5)
        with pytest.raises(Conflict) as ended:
            kept.cancel(status.id, wait=5.0)
        assert ended.value.status == 409 and ended.value.extra["status"] == "completed"
        assert ended.value.extra["final"]["output"] == "done"
        with pytest.raises(Conflict):  # and once more, after the end
            kept.cancel(status.id)


@pytest.mark.parametrize("binding", ["http", "zenoh"])
def test_consume_starts_queries_waits_for_and_cancels_async_moves(lab, http, binding):
    import mesh

    at(http, 0)
    with mesh_client(lab.endpoint) as c:
        ur10 = (mesh.consume(f"{lab.http}/ur10") if binding == "http"
                else mesh.consume("ur10", session=c.session, settings=c.settings))
        with ur10:
            move = ur10.invoke_action_async("moveToJointPosition", goal(30))
            assert move.query().status in ("pending", "running")
            out = move.wait(timeout=60)
            assert move.status.status == "completed" and out["path"]["points"][-1][0] == pytest.approx(30, abs=1e-6)
            move = ur10.invoke_action_async("moveToJointPosition", goal(150))
            eventually(lambda: ur10.read_property("getJointposition")["shoulder_pan_joint"] > 32,
                       what="the second move under way")
            assert move.cancel().status == "cancelled"
            with pytest.raises(Conflict):
                move.wait()
            assert 30 < ur10.read_property("getJointposition")["shoulder_pan_joint"] < 140
            assert move.id in [s.id for s in ur10.query_all_actions()["moveToJointPosition"]]
            with pytest.raises(BadInput):  # refused before it leaves
                ur10.invoke_action_async("moveToJointPosition", {"shoulder_pan_joint": 1})
