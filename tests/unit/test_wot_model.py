"""mesh.wot and mesh.fabric.keys without a mesh: the key layout, names as key chunks, problems on the
wire, the TD model, input validation, and a consumed Thing driven through a fake protocol client
(the form it picks, what it checks before anything leaves, asynchronous invocations)."""
from __future__ import annotations

from typing import Any

import msgspec
import pytest

from mesh.fabric.keys import Keys, check_name, check_slug
from mesh.wot.consumed import NOTHING, ConsumedThing
from mesh.wot.invocation import ActionStatus
from mesh.wot.names import escaped, unescaped
from mesh.wot.problem import BadGateway, BadInput, Conflict, NotFound, Problem, Refused, TimedOut, Unavailable
from mesh.wot.thing_description import Form, decode_td, thing_id
from mesh.wot.validate import validate


# --- keys and names ---------------------------------------------------------------------------------
def test_keys_are_built_and_parsed_back_with_escaped_names():
    keys = Keys()
    assert keys.property("light-left", "lightState") == "wot/light-left/properties/lightState"
    assert keys.action("arm", "a/b") == "wot/arm/actions/a%2Fb"
    for key, expected in [(keys.property("arm", "a/b*c"), ("arm", "properties", "a/b*c")),
                          (keys.event("arm", "done"), ("arm", "events", "done")),
                          (keys.file("arm", "points.csv"), ("arm", "files", "points.csv")),
                          (keys.td("arm"), ("arm", "td", "")), (keys.alive("arm"), ("arm", "alive", ""))]:
        parsed = keys.parse(key)
        assert (parsed.thing, parsed.kind, parsed.name) == expected, key
    assert keys.everything() == "wot/**" and keys.all_alive() == "wot/*"


@pytest.mark.parametrize("key", ["other/arm/properties/x", "wot/arm/nonsense/x", "wot/arm/properties/x/y", "wot",
                                 "wot/Not_A_Slug"])
def test_keys_not_of_ours_parse_to_none(key):
    assert Keys().parse(key) is None


def test_a_prefix_of_several_chunks_is_one_prefix():
    keys = Keys("lab/7")
    parsed = keys.parse(keys.property("arm", "x"))
    assert (parsed.thing, parsed.name) == ("arm", "x") and Keys().parse(keys.property("arm", "x")) is None


@pytest.mark.parametrize("bad", ["Arm", "arm-", "-arm", "a b", "arm\n", "a/b", ""])
def test_thing_names_must_be_slugs_and_the_error_says_so(bad):
    with pytest.raises(ValueError, match="not a slug"):
        check_slug(bad)


@pytest.mark.parametrize("bad", ["a/b", "*", "a$b", "a?b", "a#b"])
def test_a_name_that_cannot_be_a_key_chunk_is_refused_by_check_name(bad):
    with pytest.raises(ValueError, match="cannot be a key expression chunk"):
        check_name(bad)


@pytest.mark.parametrize("name", ["plain", "a/b", "x y", "100%", "ü", "a*b", "$x", "q?#"])
def test_any_name_escapes_to_one_chunk_and_back(name):
    chunk = escaped(name)
    assert not set(chunk) & set("/*$?# "), chunk
    assert unescaped(chunk) == name


def test_wildcards_stay_wildcards():
    assert escaped("*") == "*" and escaped("**") == "**"


# --- problems ---------------------------------------------------------------------------------------
@pytest.mark.parametrize("cls", [BadInput, NotFound, Conflict, Refused, Unavailable, TimedOut, BadGateway])
def test_a_problem_crosses_the_wire_as_the_same_class_with_its_reason_and_extra(cls):
    sent = cls("it went wrong", reason="why", extra={"joints": [1, 2]})
    got = Problem.from_json(sent.to_json())
    assert type(got) is cls and got.status == cls.status
    assert (got.detail, got.reason, got.extra, got.slug) == ("it went wrong", "why", {"joints": [1, 2]}, cls.slug)


def test_an_unreadable_error_reply_is_a_502_quoting_it():
    got = Problem.from_json(b"<html>oops</html>")
    assert isinstance(got, BadGateway) and "oops" in got.detail


def test_a_problem_of_an_unknown_status_keeps_its_status_and_type():
    got = Problem.from_json(Problem("teapot", status=418, slug="teapot", title="I'm a teapot").to_json())
    assert (got.status, got.slug, got.title, str(got)) == (418, "teapot", "I'm a teapot", "I'm a teapot: teapot")


# --- the TD model and validation -------------------------------------------------------------------
TD = {"title": "arm", "id": thing_id("arm"),
      "properties": {"speed": {"type": "number", "minimum": 0, "maximum": 2, "forms": [
          {"href": "zenoh://wot/arm/properties/speed", "op": ["readproperty", "writeproperty"]},
          {"href": "http://h/arm/properties/speed", "op": ["readproperty", "writeproperty"]}]},
          "pose": {"type": "object", "readOnly": True, "forms": [{"href": "http://h/arm/properties/pose",
                                                                  "op": "readproperty"}]}},
      "actions": {"move": {"input": {"type": "object", "required": ["x"], "properties": {"x": {"type": "number"}}},
                           "forms": [{"href": "http://h/arm/actions/move", "op": "invokeaction"},
                                     {"href": "http://h/arm/actions/move?async=true", "op": "invokeaction"},
                                     {"href": "http://h/arm/actions/move/{id}", "op": "queryaction"},
                                     {"href": "http://h/arm/actions/move/{id}", "op": "cancelaction"}]},
                  "home": {"forms": [{"href": "http://h/arm/actions/home", "op": "invokeaction"}]}},
      "events": {"done": {"data": {"type": "string"},
                          "forms": [{"href": "http://h/arm/events/done", "op": "subscribeevent"}]}}}


def test_the_td_model_finds_affordances_and_says_what_there_is_when_one_is_missing():
    td = decode_td(TD)
    assert td.affordance("properties", "speed").maximum == 2 and td.affordance("events", "nothing") is None
    assert td.no_such("arm", "actions", "fly") == "arm has no action 'fly'; its actions: home, move"
    assert decode_td(td.to_json()) == td


def test_a_td_of_a_wrong_shape_is_refused_by_decoding():
    with pytest.raises(msgspec.ValidationError):
        decode_td({"title": "x", "properties": {"p": {"type": 7}}})


@pytest.mark.parametrize("value, text", [(3, "speed: 3 is above the maximum 2"), ("1", "expected number"),
                                         (-1, "below the minimum 0")])
def test_validation_names_the_field_and_the_rule(value, text):
    with pytest.raises(BadInput, match=text):
        validate(value, decode_td(TD).properties["speed"], "speed")


def test_validation_of_nested_input_names_the_path():
    move = decode_td(TD).actions["move"].input
    validate({"x": 1.5}, move, "input")
    with pytest.raises(BadInput, match="missing required field 'x'"):
        validate({}, move, "input")
    with pytest.raises(BadInput, match=r"input\.x"):
        validate({"x": "far"}, move, "input")


# --- a consumed Thing over a fake client -------------------------------------------------------------
class FakeClient:
    """A protocol client for `http` that records what it performs; an action's status runs until cancelled."""

    schemes = ("http",)

    def __init__(self, accepts: bool = True):
        self.calls: list[tuple[str, Any]] = []
        self.values: dict[str, Any] = {"speed": 1.0, "pose": {"x": 0}}
        self.status: ActionStatus | None = None
        self._accepts = accepts

    def accepts(self, form: Form, op: str) -> bool:
        return self._accepts

    def read(self, form: Form) -> Any:
        self.calls.append(("read", form.href))
        return self.values[form.href.rsplit("/", 1)[1]]

    def write(self, form: Form, value: Any) -> None:
        self.calls.append(("write", form.href))
        self.values[form.href.rsplit("/", 1)[1]] = value

    def invoke(self, form: Form, input: Any) -> Any:
        self.calls.append(("invoke", form.href))
        return None if input is NOTHING else input

    def invoke_async(self, form: Form, input: Any) -> ActionStatus:
        self.calls.append(("invoke_async", form.href))
        self.status = ActionStatus("a" * 32, "move", "running", "2026-01-01T00:00:00Z")
        return self.status

    def query_action(self, href: str) -> ActionStatus:
        self.calls.append(("query", href))
        assert self.status is not None
        return self.status

    def cancel_action(self, href: str) -> ActionStatus | None:
        self.calls.append(("cancel", href))
        assert self.status is not None
        if self.status.status != "running":
            raise Conflict("already ended")
        self.status = msgspec.structs.replace(self.status, status="cancelled",
                                              error=msgspec.to_builtins(Conflict("stopped where it was").details()))
        return None  # HTTP's 204: the consumer queries the final status

    def observe(self, form: Form, callback):
        self.calls.append(("observe", form.href))
        callback("first")
        return None

    def close(self) -> None:
        pass


def test_the_first_form_a_client_accepts_is_used_and_writes_are_checked_before_they_leave():
    client = FakeClient()
    thing = ConsumedThing(TD, [client])
    assert thing.read_property("speed") == 1.0
    assert client.calls == [("read", "http://h/arm/properties/speed")], "the zenoh form is skipped: no zenoh client"
    with pytest.raises(BadInput, match="above the maximum 2"):
        thing.write_property("speed", 5)
    with pytest.raises(BadInput, match="needs an input"):
        thing.invoke_action("move")
    with pytest.raises(BadInput, match=r"input\.x"):
        thing.invoke_action("move", {"x": "far"})
    assert len(client.calls) == 1, "nothing left for a refused input"
    assert thing.invoke_action("move", {"x": 1}) == {"x": 1}
    assert thing.invoke_action("home") is None
    assert thing.read_all_properties() == {"speed": 1.0, "pose": {"x": 0}}, "one read each: no readmultiple form"


def test_missing_affordances_and_unusable_forms_are_not_found_saying_why():
    thing = ConsumedThing(TD, [FakeClient()])
    with pytest.raises(NotFound, match="arm has no property 'colour'; its properties: pose, speed"):
        thing.read_property("colour")
    with pytest.raises(NotFound, match="no writeproperty form"):
        thing.write_property("pose", {"x": 1})
    with pytest.raises(NotFound, match="offers no queryallactions form"):
        thing.query_all_actions()
    refusing = ConsumedThing(TD, [FakeClient(accepts=False)])
    with pytest.raises(NotFound, match=r"no readproperty form this consumer can use \(it offers http, zenoh\)"):
        refusing.read_property("speed")


def test_an_async_invocation_uses_the_async_form_is_queried_and_cancelled_with_its_problem():
    client = FakeClient()
    thing = ConsumedThing(TD, [client])
    invocation = thing.invoke_action_async("move", {"x": 1})
    assert client.calls[-1] == ("invoke_async", "http://h/arm/actions/move?async=true")
    assert invocation.query().status == "running" and client.calls[-1] == ("query", f"http://h/arm/actions/move/{'a' * 32}")
    assert invocation.cancel().status == "cancelled"
    with pytest.raises(Conflict, match="stopped where it was"):
        invocation.wait(timeout=5)
    with pytest.raises(NotFound, match="cannot be invoked asynchronously"):
        thing.invoke_action_async("home")


def test_observing_and_subscribing_go_through_the_observe_and_subscribe_forms():
    client = FakeClient()
    thing = ConsumedThing(TD, [client])
    seen: list = []
    thing.subscribe_event("done", seen.append)
    assert seen == ["first"] and client.calls == [("observe", "http://h/arm/events/done")]
    with pytest.raises(NotFound, match="no observeproperty form"):
        thing.observe_property("speed", seen.append)
