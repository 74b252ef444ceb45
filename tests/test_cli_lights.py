"""The lights lab driven from the command line, as plain Zenoh peers."""
import json

import pytest

from labs import start_lab


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    lab = start_lab(tmp_path_factory.mktemp("lights"), "lights", http=False, things={"light-left", "light-right"})
    yield lab
    assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"


def test_things_lists_both_lights(lab):
    assert lab.cli("things").stdout.split() == ["light-left", "light-right"]


def test_switch_on_then_read_shows_on(lab):
    assert lab.cli("invoke", "light-right", "switchOff").returncode == 0
    assert lab.cli("invoke", "light-right", "switchOn").returncode == 0
    assert lab.cli("read", "light-right", "lightState").stdout.strip() == "true"


def test_set_color_returns_and_stores_the_colour(lab):
    r = lab.cli("invoke", "light-left", "setColor", '{"r": 1, "g": 0.5, "b": 0}')
    assert json.loads(r.stdout) == [1.0, 0.5, 0.0]
    assert json.loads(lab.cli("read", "light-left", "lightColor").stdout) == [1.0, 0.5, 0.0]


@pytest.mark.parametrize("value, message", [
    ("7", "expected boolean"),
    ('"on"', "expected boolean"),
])
def test_invalid_write_is_refused_and_state_kept(lab, value, message):
    before = lab.cli("read", "light-left", "lightState").stdout
    r = lab.cli("write", "light-left", "lightState", value)
    assert r.returncode != 0 and message in r.stderr
    assert "Traceback" not in r.stderr
    assert lab.cli("read", "light-left", "lightState").stdout == before


def test_out_of_range_colour_is_refused(lab):
    before = lab.cli("read", "light-left", "lightColor").stdout
    r = lab.cli("invoke", "light-left", "setColor", '{"r": 2, "g": 0, "b": 0}')
    assert r.returncode != 0 and "input.r: 2 is above the maximum 1" in r.stderr
    assert lab.cli("read", "light-left", "lightColor").stdout == before


def test_malformed_json_names_the_problem(lab):
    r = lab.cli("invoke", "light-left", "setColor", "{bad")
    assert r.returncode == 2 and "not valid JSON" in r.stderr


def test_unknown_thing_is_reported_not_on_the_mesh(lab):
    r = lab.cli("read", "no-such-thing", "x")
    assert r.returncode != 0 and "not on the mesh" in r.stderr


def test_observe_prints_each_change(lab):
    import subprocess
    from labs import twinmesh_cmd, REPO
    lab.cli("invoke", "light-left", "switchOff")
    obs = subprocess.Popen(twinmesh_cmd(lab.endpoint, "observe", "light-left", "lightState", "--count", "2"),
                           stdout=subprocess.PIPE, text=True, cwd=REPO)
    import time
    time.sleep(1.5)  # the observer's subscription must be declared before the changes
    lab.cli("invoke", "light-left", "switchOn")
    lab.cli("invoke", "light-left", "switchOff")
    out, _ = obs.communicate(timeout=20)
    assert out.split() == ["true", "false"]
