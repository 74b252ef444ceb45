"""The control page's fields and read-outs (mesh/http/ui/forms.js) in a real headless Chromium, without a lab:
the script is served as the adapter serves it, and each test builds fields from a schema the way the page
does and looks at what a user would see (labels, units, bounds, the choices, the rows of a list) and what
the form would send.
"""
from __future__ import annotations

import json
from importlib import resources

import pytest
from browser import chromium

pytestmark = pytest.mark.browser  # Chromium runs the page's form code

ORIGIN = "http://control-page.test"
UI = resources.files("mesh.http") / "ui"


@pytest.fixture(scope="module")
def browser():
    with chromium() as b:
        yield b


@pytest.fixture
def page(browser):
    context = browser.new_context(viewport={"width": 900, "height": 700})
    p = context.new_page()
    errors: list[str] = []
    p.on("pageerror", lambda e: errors.append(str(e)))

    def serve(route):
        name = route.request.url.removeprefix(f"{ORIGIN}/_ui/")
        if name in ("forms.js", "style.css"):
            kind = "text/javascript" if name.endswith(".js") else "text/css"
            route.fulfill(body=(UI / name).read_bytes(), content_type=kind)
        else:
            route.fulfill(status=200, content_type="text/html", body=(
                '<!doctype html><link rel="stylesheet" href="/_ui/style.css"><form id="f"></form>'
                '<script type="module">import * as forms from "/_ui/forms.js"; window.forms = forms;'
                ' document.body.dataset.ready = "true";</script>'))

    p.route(f"{ORIGIN}/**", serve)
    p.goto(f"{ORIGIN}/")
    p.wait_for_selector("body[data-ready=true]", state="attached")
    yield p
    context.close()
    assert not errors, f"script errors on the page: {errors}"


def build(page, schema: dict, values: dict | None = None, action: str = "") -> None:
    """An editor for `schema` in the page's form (as the page builds an action's), seeded from `values`
    (a Thing's property values) when given; `window.ed` is the editor."""
    page.evaluate("""([schema, values, action]) => {
        const ed = window.forms.editor(schema, { key: "input", raw: true });
        document.getElementById("f").replaceChildren(ed.el, ...ed.tools);
        if (values) ed.seed(window.forms.guesser(values, {}, action));
        window.ed = ed;
    }""", [schema, values, action])


def sent(page):
    return page.evaluate("JSON.stringify(window.ed.get())")


MM = {"type": "number", "unit": "qudt:MilliM"}
DEG = {"type": "number", "unit": "qudt:DEG", "minimum": -360, "maximum": 360}
JOINTS = {"type": "object", "properties": {"shoulder_pan_joint": DEG, "elbow_joint": DEG},
          "required": ["shoulder_pan_joint", "elbow_joint"]}
PLAN = {"type": "object", "oneOf": [
    {"type": "object", "title": "Cartesian target", "properties": {"x": MM, "y": MM, "z": MM}, "required": ["x", "y", "z"]},
    {"type": "object", "title": "Joint target", "properties": {"joints": JOINTS}, "required": ["joints"]}]}


def test_a_number_shows_its_unit_and_bounds_and_starts_inside_them(page):
    build(page, {"type": "object", "properties": {"speed": {"type": "integer", "unit": "qudt:PERCENT", "minimum": 1,
                                                            "maximum": 100}}, "required": ["speed"]})
    speed = page.locator("label[data-key=speed]")
    assert "%" in speed.inner_text() and "1 … 100" in speed.inner_text()
    assert speed.locator("input").input_value() == "1"  # no current value yet: the lowest allowed, not 0
    assert json.loads(sent(page)) == {"speed": 1}


def test_a_oneof_input_offers_its_targets_and_fills_each_from_the_things_state(page):
    build(page, PLAN, values={"getCartesianposition": {"x": 612.5, "y": -163.9, "z": 694.2},
                              "getJointposition": {"shoulder_pan_joint": 30.0, "elbow_joint": -45.0}})
    assert page.locator("select.variant option").all_inner_texts() == ["Cartesian target", "Joint target"]
    fields = page.locator(".variant-body label.field")
    assert fields.locator(".label").all_inner_texts() == ["x", "y", "z"]
    assert "mm" in fields.first.inner_text()
    assert [fields.nth(i).locator("input").input_value() for i in range(3)] == ["612.5", "-163.9", "694.2"]
    assert json.loads(sent(page)) == {"x": 612.5, "y": -163.9, "z": 694.2}
    page.locator("select.variant").select_option(label="Joint target")
    joints = page.locator("fieldset[data-field=joints]")
    assert joints.locator("legend").inner_text() == "joints"  # the nested object, grouped
    assert joints.locator("input[name='joints.shoulder_pan_joint']").input_value() == "30"
    assert "-360 … 360" in joints.inner_text()
    assert json.loads(sent(page)) == {"joints": {"shoulder_pan_joint": 30, "elbow_joint": -45}}


def test_the_raw_json_toggle_shows_the_same_value_and_its_edits_come_back_to_the_fields(page):
    build(page, {"type": "object", "properties": {"x": MM, "y": MM}, "required": ["x", "y"]}, values={"p": {"x": 1, "y": 2}})
    page.locator("button.raw").click()
    area = page.locator("textarea.json")
    assert json.loads(area.input_value()) == {"x": 1, "y": 2}
    assert page.locator("label[data-key=x]").is_hidden()
    area.fill('{"x": 7, "y": 8}')
    assert json.loads(sent(page)) == {"x": 7, "y": 8}
    page.locator("button.raw").click()
    assert page.locator("label[data-key=x] input").input_value() == "7"
    assert page.locator("button.undo").is_visible()  # edited: live values no longer overwrite it


def test_an_enum_is_a_choice_a_boolean_a_checkbox(page):
    build(page, {"type": "object", "required": ["mode", "on"], "properties": {
        "mode": {"type": "string", "enum": ["fast", "safe"]}, "on": {"type": "boolean"}}})
    assert page.locator("label[data-key=mode] option").all_inner_texts() == ["fast", "safe"]
    page.locator("label[data-key=mode] select").select_option("\"safe\"")
    page.locator("label[data-key=on] input[type=checkbox]").check()
    assert json.loads(sent(page)) == {"mode": "safe", "on": True}


def test_an_array_gets_rows_to_add_and_remove_within_its_bounds(page):
    build(page, {"type": "array", "minItems": 1, "maxItems": 3, "items": {"type": "number", "unit": "qudt:M"}})
    rows = page.locator("fieldset.list .row")
    assert rows.count() == 1
    assert page.locator("fieldset.list .row button.remove").is_disabled()  # minItems
    page.locator("fieldset.list button.add").click()
    page.locator("fieldset.list button.add").click()
    assert rows.count() == 3 and page.locator("fieldset.list button.add").is_disabled()  # maxItems
    for i, v in enumerate(["0.5", "1", "2"]):
        rows.nth(i).locator("input").fill(v)
    rows.nth(1).locator("button.remove").click()
    assert json.loads(sent(page)) == [0.5, 2]


def test_a_position_reads_as_labelled_fields_with_units_and_a_colour_as_a_swatch(page):
    schema = {"type": "object", "properties": {"x": MM, "y": MM, "z": MM}}
    page.evaluate("""([schema]) => document.getElementById("f").replaceChildren(
        window.forms.readout(schema, {x: 612.4999, y: -163.9, z: 0}),
        window.forms.readout({type: "array", title: "Light colour", description: "RGB, each 0..1.",
                              items: {type: "number", minimum: 0, maximum: 1}}, [1, 0, 0]))""", [schema])
    x = page.locator("[data-key=x]")
    assert x.locator(".k").inner_text() == "x" and x.locator(".fv").inner_text() == "612.5"
    assert x.locator(".u").inner_text() == "mm"
    assert page.locator(".swatch").evaluate("e => getComputedStyle(e).backgroundColor") == "rgb(255, 0, 0)"
    assert page.locator("[data-key='0'] .k").inner_text() == "r"
