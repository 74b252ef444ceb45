"""The lab in a browser (a real headless Chromium): the control page at `/` of the adapter (every Thing
of the `iot-lab` drawn from its TD, an index with a filter that jumps to each card, live values through
the adapter's SSE, fields generated from the schemas that start from the Thing's state, the raw JSON
as an option, the answer or the problem shown after a call; with HTTP auth, credentials asked once and
used for every call and the live updates) and the live 3D view `twinmesh up` serves (the Rerun web
viewer, rendered by Chromium's software rasterizer: the scene with the robots' colours, and a
picture that changes when the UR10 moves).
"""
from __future__ import annotations

import io
import json
import re
import time

import httpx
import numpy as np
import pytest
from browser import chromium
from labs import start_lab

pytestmark = [pytest.mark.lab, pytest.mark.browser]

THINGS = {"dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2", "color-sensor",
          "uarm", "ur10", "light-left", "light-right", "pan-tilt-1", "pan-tilt-2", "world", "tdgen"}
LIVE = 2000  # ms a change may take to show on the page (the 2 s)


@pytest.fixture(scope="module")
def browser():
    with chromium() as b:
        yield b


@pytest.fixture(scope="module")
def lab(tmp_path_factory, browser):
    tmp = tmp_path_factory.mktemp("page")
    lab = start_lab(tmp, None, http=True, things=THINGS, view=True,
                    extra_args=("--speed", "max", "--samples", "3000", "--tdgen-cache", str(tmp / "cache")))
    yield lab
    assert lab.stop(), "the lab did not stop cleanly"


@pytest.fixture
def page(lab, browser):
    context = browser.new_context(viewport={"width": 1400, "height": 1000})
    p = context.new_page()
    errors: list[str] = []
    p.on("pageerror", lambda e: errors.append(str(e)))
    p.goto(lab.http + "/")
    p.wait_for_selector("body[data-ready=true]", timeout=30_000)
    yield p
    context.close()
    assert not errors, f"script errors on the page: {errors}"


def section(page, thing: str):
    return page.locator(f"section[data-thing='{thing}']")


def opened(page, thing: str, action: str):
    """The action's form, unfolded as a user does (actions with an input are folded in their card)."""
    box = section(page, thing).locator(f"details[data-action={action}]")
    if box.get_attribute("open") is None:
        box.locator("summary").click()
    return box.locator(f"form[data-action={action}]")


def test_the_page_lists_every_thing_with_its_title_description_affordances_and_td_link(lab, page):
    shown = set(page.locator("section.thing").evaluate_all("els => els.map(e => e.dataset.thing)"))
    assert shown == THINGS
    assert set(page.locator("#index li").evaluate_all("els => els.map(e => e.dataset.thing)")) == THINGS
    light = section(page, "light-left")
    assert light.locator("h2").inner_text() == "light-left"
    assert "light" in light.locator(".description").inner_text().lower()
    assert light.locator("a", has_text="TD").get_attribute("href") == f"{lab.http}/light-left"
    assert opened(page, "light-left", "setColor").locator("fieldset input").count() == 3  # r, g, b from the schema
    assert light.locator("form[data-property=lightState] input[type=checkbox]").count() == 1
    go_to = opened(page, "uarm", "goTo")
    assert "mm" in go_to.locator("label[data-key=x]").inner_text()  # units and bounds shown
    assert "120 … 200" in go_to.locator("label[data-key=x]").inner_text()
    listed = httpx.get(lab.http + "/", headers={"Accept": "application/json"}).json()  # WoT clients: TD URLs still
    assert f"{lab.http}/light-left" in listed


def test_the_filter_keeps_the_matching_things_and_the_index_jumps_to_a_card(page):
    from playwright.sync_api import expect

    page.set_viewport_size({"width": 1280, "height": 800})
    visible = "els => els.filter(e => !e.hidden).map(e => e.dataset.thing).sort()"
    page.locator("#filter").fill("sensor")
    assert page.locator("section.thing").evaluate_all(visible) == ["color-sensor", "infrared-sensor-1",
                                                                     "infrared-sensor-2"]
    assert page.locator("#index li").evaluate_all(visible) == ["color-sensor", "infrared-sensor-1", "infrared-sensor-2"]
    expect(section(page, "ur10")).to_be_hidden()
    page.locator("#filter").fill("robot")  # a type: the UR10's id names it a robot
    assert page.locator("section.thing").evaluate_all(visible) == ["ur10"]
    page.locator("#filter").fill("")
    page.locator("#types button[data-type=light]").click()  # the type chips filter too
    assert page.locator("section.thing").evaluate_all(visible) == ["light-left", "light-right"]
    page.locator("#filter").fill("")
    page.locator("#filter").dispatch_event("input")
    assert len(page.locator("section.thing").evaluate_all(visible)) == len(THINGS)
    world = section(page, "world")
    expect(world).not_to_be_in_viewport()  # the last card, below the fold
    page.locator("#index a[data-thing=world]").click()
    expect(world).to_be_in_viewport()


def test_the_belt_speed_input_shows_the_belts_speed_and_setting_it_changes_the_belt(lab, page):
    from playwright.sync_api import expect

    with httpx.Client(base_url=lab.http) as http:
        http.put("/conveyor-belt-1/properties/speed", json=100).raise_for_status()
        page.reload()
        page.wait_for_selector("body[data-ready=true]", timeout=30_000)
        belt = section(page, "conveyor-belt-1")
        form = belt.locator("form[data-property=speed]")
        expect(form.locator("input[name=speed]")).to_have_value("100")  # the belt's speed, not the minimum 1
        expect(belt.locator("output[data-property=speed]")).to_have_text("100")
        form.locator("input[name=speed]").fill("40")
        form.locator("button[type=submit]").click()
        expect(belt.locator("pre.answer[data-property=speed]")).to_contain_text("204")
        assert http.get("/conveyor-belt-1/properties/speed").json() == 40
        expect(belt.locator("output[data-property=speed]")).to_have_text("40", timeout=LIVE)
        http.put("/conveyor-belt-1/properties/speed", json=100).raise_for_status()  # by someone else
        # speed is not observable: a card on screen reads it again (every few seconds), and the input follows
        expect(belt.locator("output[data-property=speed]")).to_have_text("100", timeout=10_000)
        expect(form.locator("input[name=speed]")).to_have_value("100")


def test_inputs_start_from_the_things_state_and_follow_it_until_edited(lab, page):
    from playwright.sync_api import expect

    with httpx.Client(base_url=lab.http, timeout=60) as http:
        location = http.get("/uarm/properties/location").json()
        go_to = opened(page, "uarm", "goTo")
        for axis in "xyz":  # a move starts where the arm is
            expect(go_to.locator(f"input[name={axis}]")).to_have_value(str(location[axis]))
        pan_to = opened(page, "pan-tilt-1", "panTo").locator("input")
        target = 20.0 if http.get("/pan-tilt-1/properties/panPosition").json() < 10 else 0.0
        http.post("/pan-tilt-1/actions/panTo", json=target).raise_for_status()
        expect(pan_to).to_have_value(f"{target:g}", timeout=LIVE)  # panTo follows panPosition, live
        move_to = opened(page, "pan-tilt-1", "moveTo")  # and moveTo's panAngle too, by its name and unit
        expect(move_to.locator("input[name=panAngle]")).to_have_value(f"{target:g}")
        pan_to.fill("-30")  # the user's edit stays while the Thing moves
        http.post("/pan-tilt-1/actions/panTo", json=5.0).raise_for_status()
        expect(section(page, "pan-tilt-1").locator("output[data-property=panPosition]")).to_have_text("5", timeout=LIVE)
        assert pan_to.input_value() == "-30"
        section(page, "pan-tilt-1").locator("form[data-action=panTo] button.undo").click()
        expect(pan_to).to_have_value("5")


def test_switching_light_left_on_from_its_form_shows_true_through_sse_and_get_agrees(lab, page):
    from playwright.sync_api import expect

    with httpx.Client(base_url=lab.http) as http:
        http.post("/light-left/actions/switchOff").raise_for_status()
        value = section(page, "light-left").locator("output[data-property=lightState]")
        expect(value).to_have_text("false", timeout=LIVE)
        form = section(page, "light-left").locator("form[data-property=lightState]")
        expect(form.locator("input[type=checkbox]")).not_to_be_checked(timeout=LIVE)  # the input shows the state
        form.locator("input[type=checkbox]").check()
        form.locator("button[type=submit]").click()
        expect(value).to_have_text("true", timeout=LIVE)
        assert http.get("/light-left/properties/lightState").json() is True
        log = section(page, "light-left").locator("ol[data-event=stateChanged] li")
        expect(log.first).to_contain_text("true", timeout=LIVE)  # the event, logged live


def test_a_goto_outside_the_uarm_range_shows_the_400_detail_and_nothing_moves(lab, page):
    from playwright.sync_api import expect

    with httpx.Client(base_url=lab.http) as http:
        before = http.get("/uarm/properties/location").json()
        form = opened(page, "uarm", "goTo")
        form.locator("input[name=x]").fill("5000")
        form.locator("input[name=y]").fill("0")
        form.locator("input[name=z]").fill("80")
        form.locator("button[type=submit]").click()
        answer = section(page, "uarm").locator("pre.answer[data-action=goTo]")
        expect(answer).to_contain_text("400", timeout=10_000)
        expect(answer).to_contain_text("input.x: 5000 is above the maximum 200")
        assert answer.get_attribute("data-ok") == "false"
        assert http.get("/uarm/properties/location").json() == before


def test_plan_move_offers_its_targets_as_fields_and_answers_from_the_fields_or_the_raw_json(lab, page):
    from playwright.sync_api import expect

    with httpx.Client(base_url=lab.http) as http:
        joints = http.get("/ur10/properties/getJointposition").json()
    form = opened(page, "ur10", "planMove")
    assert form.locator("select.variant option").all_inner_texts() == ["Cartesian target", "Pose target",
                                                                       "Joint target"]
    assert form.locator(".variant-body label.field .label").all_inner_texts() == ["x", "y", "z"]
    assert "mm" in form.locator("label[data-key=x]").inner_text()
    form.locator("select.variant").select_option(label="Joint target")
    group = form.locator("fieldset[data-field=joints]")
    expect(group.locator("input[name='joints.elbow_joint']")).to_have_value(f"{joints['elbow_joint']:g}")
    assert group.locator("input").count() == 6
    group.locator("input[name='joints.shoulder_pan_joint']").fill("15")
    form.locator("button[type=submit]").click()
    answer = section(page, "ur10").locator("pre.answer[data-action=planMove]")
    expect(answer).to_contain_text("200", timeout=60_000)
    assert answer.get_attribute("data-ok") == "true"
    form.locator("button.raw").click()
    raw = form.locator("textarea.json")
    asked = json.loads(raw.input_value())
    assert asked["joints"]["shoulder_pan_joint"] == 15
    raw.fill(json.dumps({"joints": {**asked["joints"], "shoulder_pan_joint": 9999}}))
    form.locator("button[type=submit]").click()
    expect(answer).to_contain_text("400", timeout=60_000)  # the adapter's problem, its title and detail
    expect(answer).to_contain_text("shoulder_pan_joint")


def test_a_ur10_move_from_the_page_shows_its_answer_and_the_joints_as_labelled_fields(lab, page):
    from playwright.sync_api import expect

    form = opened(page, "ur10", "moveToJointPosition")
    form.locator("input[name=shoulder_pan_joint]").fill("30")
    form.locator("input[name=shoulder_lift_joint]").fill("-90")
    form.locator("button[type=submit]").click()
    answer = section(page, "ur10").locator("pre.answer[data-action=moveToJointPosition]")
    expect(answer).to_contain_text("200", timeout=60_000)
    expect(answer).to_contain_text('"reached"')
    assert answer.get_attribute("data-ok") == "true"
    with httpx.Client(base_url=lab.http) as http:
        assert http.get("/ur10/properties/getJointposition").json()["shoulder_pan_joint"] == pytest.approx(30, abs=1e-6)
    joints = section(page, "ur10").locator("output[data-property=getJointposition]")
    pan = joints.locator("[data-key=shoulder_pan_joint]")
    expect(pan.locator(".fv")).to_have_text("30", timeout=LIVE)
    assert pan.locator(".k").inner_text() == "shoulder_pan_joint" and pan.locator(".u").inner_text() == "°"


def test_with_http_auth_the_page_asks_once_and_uses_the_credentials_for_calls_and_live_updates(browser, tmp_path):
    from playwright.sync_api import expect

    lab = start_lab(tmp_path, "lights", http=True, things={"light-left", "light-right"},
                    extra_args=("--auth", "basic:teacher:class-7b"))
    try:
        context = browser.new_context()
        page = context.new_page()
        page.goto(lab.http + "/")
        login = page.locator("#login")
        expect(login).to_be_visible(timeout=10_000)
        login.locator("input[name=user]").fill("teacher")
        login.locator("input[name=secret]").fill("class-7b")
        login.locator("button").click()
        page.wait_for_selector("body[data-ready=true]", timeout=30_000)
        expect(login).to_be_hidden()
        value = section(page, "light-left").locator("output[data-property=lightState]")
        expect(value).to_have_text("false", timeout=LIVE)
        section(page, "light-left").locator("form[data-action=switchOn] button").click()
        expect(value).to_have_text("true", timeout=LIVE)  # the live stream carries the credentials too
        answer = section(page, "light-left").locator("pre.answer[data-action=switchOn]")
        expect(answer).to_contain_text("204")
        assert httpx.get(f"{lab.http}/light-left/properties/lightState").status_code == 401
        context.close()
    finally:
        assert lab.stop()


# --- the live 3D view -------------------------------------------------------------------------------
VIEW_3D = (0, 40, 700, 760)  # x0, y0, x1, y1 of the 3D view in a 1200 x 800 window (the layout's left pane)
UR_BLUE = (0.35, 0.55, 0.8)  # the UR10's `ur_blue` material (tdgen/robot/models/ur10.urdf)


def picture(page) -> np.ndarray:
    from PIL import Image

    x0, y0, x1, y1 = VIEW_3D
    return np.asarray(Image.open(io.BytesIO(page.screenshot())).convert("RGB"))[y0:y1, x0:x1].astype(int)


def ur_blue_pixels(rgb: np.ndarray) -> int:
    """Pixels of the UR10's blue, however lit: its hue (about 213 degrees) and a clear saturation."""
    import colorsys

    target = colorsys.rgb_to_hsv(*UR_BLUE)[0]
    flat = rgb.reshape(-1, 3) / 255.0
    mx, mn = flat.max(axis=1), flat.min(axis=1)
    sat = np.where(mx > 0, (mx - mn) / np.maximum(mx, 1e-9), 0)
    hue = np.array([colorsys.rgb_to_hsv(*p)[0] for p in flat[(sat > 0.3) & (mx > 0.35)]])
    return int(np.sum(np.abs(hue - target) < 0.03))


def settled(page, timeout: float = 120.0) -> np.ndarray:
    """The 3D view once two pictures 2 s apart are the same (the viewer caught up with the stream)."""
    deadline = time.monotonic() + timeout
    last = picture(page)
    while time.monotonic() < deadline:
        page.wait_for_timeout(2000)
        now = picture(page)
        if ur_blue_pixels(now) > 100 and np.count_nonzero(np.abs(now - last).sum(axis=2) > 30) < 50:
            return now
        last = now
    raise AssertionError("the 3D view did not settle on a picture of the lab")


@pytest.fixture
def view_page(lab, browser):
    url = re.search(r"3D view (http://\S+)", lab.log.read_text())
    assert url, f"`twinmesh up` printed no 3D view URL:\n{lab.log.read_text()[-2000:]}"
    context = browser.new_context(viewport={"width": 1200, "height": 800})
    p = context.new_page()
    p.goto(url.group(1))
    yield p
    context.close()


def test_the_3d_view_renders_the_lab_with_the_robots_colours_and_changes_when_the_ur10_moves(lab, view_page):
    before = settled(view_page)
    colours = len(np.unique(before.reshape(-1, 3), axis=0))
    assert colours > 200, f"a blank view ({colours} colours)"
    assert ur_blue_pixels(before) > 100  # the UR10, drawn from its URDF with its materials
    with httpx.Client(base_url=lab.http, timeout=120) as http:
        now = http.get("/ur10/properties/getJointposition").json()
        pan = 0.0 if abs(now["shoulder_pan_joint"] - 90) < 45 else 90.0  # a quarter turn of the base
        r = http.post("/ur10/actions/moveToJointPosition", json={**now, "shoulder_pan_joint": pan,
                                                                  "shoulder_lift_joint": -90.0, "elbow_joint": 0.0})
        assert r.status_code == 200, r.text
    after = settled(view_page)
    changed = np.count_nonzero(np.abs(after - before).sum(axis=2) > 30)
    assert changed > 500, f"only {changed} pixels of the 3D view changed after the UR10 moved"
    print(f"\n3D view: {colours} colours, {ur_blue_pixels(before)} UR-blue pixels; {changed} pixels changed by the move")
