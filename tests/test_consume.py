"""`mesh.consume()`: one Python consumer for any TD, driven by the TD's forms. The same script drives
node-wot's own servient (HTTP), a twinmesh lab through its adapter (HTTP) and the same lab's Things on
the mesh (Zenoh forms): reads, writes, actions, observations, events, multi-property reads, errors.
"""
from __future__ import annotations

import queue
from contextlib import contextmanager

import pytest
from interop import npm

import mesh
from mesh.wot.consumed import Inbox
from mesh.wot.problem import BadInput, NotFound, Problem

pytestmark = pytest.mark.lab

WAIT = 5.0  # s for a notification to arrive (hang detection, not a timing goal)


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


@contextmanager
def mesh_session(endpoint: str):
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    settings = MeshSettings(mode="client", connect=(endpoint,))
    with open_session(settings) as session:
        yield session, settings


@contextmanager
def light(where: str, lab=None):
    """light-left as a ConsumedThing: node-wot's servient, the lab's adapter, or the lab's mesh."""
    if where == "node-wot":
        with npm.start_baseline_servient() as servient, mesh.consume(servient.td_url()) as thing:
            yield thing
    elif where == "adapter":
        with mesh.consume(f"{lab.http}/light-left") as thing:
            yield thing
    else:
        with mesh_session(lab.endpoint) as (session, settings), \
                mesh.consume("light-left", session=session, settings=settings) as thing:
            yield thing


def scheme_of(thing, kind: str, name: str) -> set[str]:
    return {f.href.split(":")[0] for f in getattr(thing.td, kind)[name].forms}


@pytest.mark.parametrize("where", ["node-wot", "adapter", "mesh"])
def test_one_script_drives_node_wot_the_adapter_and_the_mesh_alike(where, request):
    lab = request.getfixturevalue("lab") if where != "node-wot" else None
    with light(where, lab) as thing:
        assert scheme_of(thing, "properties", "lightState") == ({"zenoh"} if where == "mesh" else {"http"})
        thing.invoke_action("switchOff")
        changes, events = Inbox(), Inbox()
        observing = thing.observe_property("lightState", changes)
        subscribed = thing.subscribe_event("stateChanged", events)
        try:
            thing.invoke_action("switchOn")
            assert changes.get(WAIT) is True and events.get(WAIT) is True
            assert thing.read_property("lightState") is True
            thing.write_property("lightState", False)
            assert changes.get(WAIT) is False
            assert thing.invoke_action("setColor", {"r": 0.5, "g": 0.25, "b": 0}) == [0.5, 0.25, 0]
            assert thing.read_multiple_properties(["lightColor"]) == {"lightColor": [0.5, 0.25, 0]}
            assert thing.read_all_properties() == {"lightState": False, "lightColor": [0.5, 0.25, 0]}
        finally:
            observing.stop()
            subscribed.stop()
        thing.invoke_action("switchOn")
        with pytest.raises(queue.Empty):  # stopped means stopped
            changes.get(0.5)


@pytest.mark.parametrize("where", ["node-wot", "adapter", "mesh"])
def test_bad_input_is_refused_before_it_leaves_and_names_the_field(where, request):
    lab = request.getfixturevalue("lab") if where != "node-wot" else None
    with light(where, lab) as thing:
        thing.invoke_action("setColor", {"r": 1, "g": 1, "b": 1})
        with pytest.raises(BadInput, match=r"input.r: 5 is above the maximum 1"):
            thing.invoke_action("setColor", {"r": 5, "g": 0, "b": 0})
        with pytest.raises(BadInput, match="lightState"):
            thing.write_property("lightState", "on")
        with pytest.raises(BadInput, match="needs an input"):
            thing.invoke_action("setColor")
        with pytest.raises(NotFound, match="switchOn"):  # what it has instead
            thing.invoke_action("blink")
        assert thing.read_property("lightColor") == [1, 1, 1]  # nothing was sent


def test_device_errors_come_back_as_the_problem_the_device_raised(lab):
    """Problems cross both bindings unchanged: the adapter's 503 for a gone Thing, as a Problem."""
    with mesh.consume(f"{lab.http}/light-right") as thing:
        assert thing.read_property("lightState") in (True, False)
    with mesh.consumer(base=lab.http) as things:
        with pytest.raises(Problem) as missing:
            things.thing("no-such-light")
        assert missing.value.status == 404


def test_credentials_are_sent_to_a_thing_that_needs_them():
    secret = {"username": "teacher", "password": "class-7b"}
    with npm.start_baseline_servient(credentials=secret) as servient:
        url = servient.td_url()
        with mesh.consume(url, auth="basic:teacher:class-7b") as thing:
            thing.write_property("lightState", True)
            assert thing.read_property("lightState") is True
        with mesh.consumer(auth="basic:teacher:class-7b") as with_td, mesh.consumer() as without:
            td = with_td.clients[-1].fetch_td(url)
            stranger = without.consume(td)
            with pytest.raises(Problem) as refused:
                stranger.read_property("lightState")
            assert refused.value.status == 401


def test_the_cube_workflow_has_no_consumer_of_its_own():
    """The apps drive Things through mesh.consume's Consumer only (SPEC's one consumer)."""
    import devices.apps.cube_workflow as workflow
    import devices.apps.evaluation as evaluation

    for module in (workflow, evaluation):
        own = [n for n, v in vars(module).items() if isinstance(v, type) and "Consumer" in n and v.__module__ ==
               module.__name__]
        assert own == [], f"{module.__name__} defines {own}"
    assert "httpx" not in vars(workflow) and "MeshClient" not in vars(workflow)
