"""A Thing whose TD links a twin says so on the mesh (`Keys.twin`), so that the tdgen service follows
robots alone: a mesh of thousands of other devices costs it nothing per device."""
from __future__ import annotations

import msgspec
import pytest
from labs import free_port
from waiting import eventually

from mesh.fabric.directory import Directory
from mesh.fabric.server import ExposedThing
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from mesh.messages.relations import TWIN
from mesh.wot.thing_description import decode_td, thing_id


def _td(name: str, twin: bool):
    links = [{"href": "files/twin.json", "rel": TWIN, "type": "application/json"}] if twin else []
    return decode_td({"title": name, "id": thing_id(name), "links": links,
                      "properties": {"on": {"type": "boolean", "readOnly": True}}})


@pytest.fixture
def mesh():
    settings = MeshSettings(connect=(f"tcp/127.0.0.1:{free_port()}",), wait_for_router=False)
    with open_session(settings.as_router()):
        yield settings


def _thing(session, settings: MeshSettings, name: str, twin: bool) -> ExposedThing:
    thing = ExposedThing(session, _td(name, twin), name, settings.keys).on_read("on", lambda: True)
    return thing.on_file("twin.json", lambda: b"{}", "application/json") if twin else thing


def test_only_things_that_link_a_twin_hold_the_twin_token(mesh):
    with open_session(mesh) as observer, open_session(mesh) as a, open_session(mesh) as b:
        everyone = Directory(observer, mesh.keys)
        twins = Directory(observer, mesh.keys, tokens="twin")
        lamp, robot = _thing(a, mesh, "lamp-1", twin=False), _thing(b, mesh, "arm-1", twin=True)
        with lamp, robot:
            assert everyone.wait_for({"lamp-1", "arm-1"}, timeout=10)
            assert twins.wait_for({"arm-1"}, timeout=10)
            assert twins.alive() == ["arm-1"]  # the lamp never shows up among the twins
            robot.update_td(_td("arm-1", twin=False))  # its TD no longer links a twin: the token goes
            eventually(lambda: twins.alive() == [], what="the twin token withdrawn")
            assert everyone.is_alive("arm-1")
            robot.update_td(_td("arm-1", twin=True))
            assert twins.wait_for({"arm-1"}, timeout=10)
        eventually(lambda: twins.alive() == [] and everyone.alive() == [], what="both gone once destroyed")
        twins.close()
        everyone.close()


def test_a_late_follower_learns_the_twins_already_there(mesh):
    with open_session(mesh) as a, open_session(mesh) as b, open_session(mesh) as observer:
        with _thing(a, mesh, "arm-2", twin=True), _thing(b, mesh, "lamp-2", twin=False):
            other = Directory(observer, mesh.keys)
            assert other.wait_for({"arm-2", "lamp-2"}, timeout=10)
            twins = Directory(observer, mesh.keys, tokens="twin")  # declared after both joined
            assert twins.wait_for({"arm-2"}, timeout=10)
            assert msgspec.json.encode(twins.alive()) == b'["arm-2"]'
            twins.close()
            other.close()
