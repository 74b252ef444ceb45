"""The HTTP binding's client (`mesh.http.http_client.HttpClient`) consuming a Thing from the TD the
adapter serves, in-process: the adapter's app over the fake registry through Starlette's TestClient
(an httpx client), so the forms the adapter writes are the ones the consumer performs."""
from __future__ import annotations

from collections.abc import Iterator

import pytest
from fake_registry import FakeRegistry
from starlette.testclient import TestClient

from mesh.http.app import create_asgi
from mesh.http.http_client import HttpClient
from mesh.wot.consumed import ConsumedThing
from mesh.wot.problem import BadInput, Conflict, NotFound, Refused, Unavailable

ARM = {
    "title": "arm",
    "properties": {"speed": {"type": "number", "minimum": 0, "maximum": 2, "observable": True},
                   "serial": {"type": "string", "readOnly": True}},
    "actions": {"move": {"input": {"type": "number"}, "output": {"type": "number"}},
                "jam": {}},
}


@pytest.fixture
def registry() -> FakeRegistry:
    reg = FakeRegistry()
    arm = reg.add(dict(ARM), values={"speed": 1.0, "serial": "A-7"})

    def jam(_):
        raise Refused("the arm is jammed", reason="jammed")

    arm.actions.update(move=lambda x: x * 2, jam=jam)
    return reg


@pytest.fixture
def arm(registry) -> Iterator[ConsumedThing]:
    with TestClient(create_asgi(registry), raise_server_exceptions=False) as http:
        client = HttpClient()
        client.http.close()
        client.http = http  # the consumer's requests go to the app in this process
        yield ConsumedThing(client.fetch_td("http://testserver/arm"), [client])


def test_a_consumer_reads_writes_and_invokes_through_the_served_forms(arm, registry):
    assert arm.read_property("speed") == 1.0
    arm.write_property("speed", 1.5)
    assert registry.writes == [("arm", "speed", 1.5)]
    assert arm.read_all_properties() == {"speed": 1.5, "serial": "A-7"}
    assert arm.invoke_action("move", 21) == 42


def test_problems_come_back_as_the_same_classes(arm, registry):
    with pytest.raises(BadInput):
        arm.write_property("speed", 7)  # refused before it leaves
    with pytest.raises(Refused, match="jammed") as refused:
        arm.invoke_action("jam")
    assert refused.value.reason == "jammed"
    with pytest.raises(NotFound):
        arm.read_property("colour")
    registry.leave("arm")
    with pytest.raises(Unavailable, match="left the mesh"):
        arm.read_property("speed")
    assert registry.writes == []


def test_an_async_invocation_is_followed_by_its_location_and_cancelled(arm):
    invocation = arm.invoke_action_async("move", 3)
    assert invocation.query().status == "running"
    assert invocation.cancel().status == "cancelled"
    with pytest.raises(Conflict):
        invocation.cancel()
    assert invocation.id in [s.id for s in arm.query_all_actions()["move"]]
