"""The Rerun logger: what a real recording of the lights lab contains, read back with rerun's reader."""
import json
import subprocess
from pathlib import Path

import pytest
from labs import start_lab, stop_process

from mesh.recorder import mapping
from mesh.wot.thing_description import DataSchema
from recordings import RERUN, read_column, scalars, texts, wait_for_line

pytestmark = pytest.mark.lab

LEFT = "/things/light-left"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    lab = start_lab(tmp_path_factory.mktemp("rec-lab"), "lights", http=False, things={"light-left", "light-right"})
    yield lab
    assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"


@pytest.fixture(scope="module")
def recording(lab, tmp_path_factory) -> Path:
    """Record while light-left is switched on, off, on and recoloured; stop with Ctrl-C."""
    tmp = tmp_path_factory.mktemp("rec")
    path, log = tmp / "not-yet" / "lights.rrd", tmp / "recorder.log"
    assert lab.cli("invoke", "light-left", "switchOff").returncode == 0
    recorder = lab.spawn("record", str(path), log=log)
    wait_for_line(log, "recording to", recorder)
    for action in ("switchOn", "switchOff", "switchOn"):
        assert lab.cli("invoke", "light-left", action).returncode == 0
    assert lab.cli("invoke", "light-left", "setColor", '{"r": 1, "g": 0.5, "b": 0}').returncode == 0
    assert stop_process(recorder), f"the recorder did not stop on Ctrl-C:\n{log.read_text()}"
    assert recorder.returncode == 0, log.read_text()
    assert "recording saved" in log.read_text()
    return path


def test_recording_stopped_with_ctrl_c_verifies(recording):
    r = subprocess.run([RERUN, "rrd", "verify", str(recording)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_three_switches_are_recorded_in_order_after_the_value_at_join(recording):
    assert scalars(recording, f"{LEFT}/properties/lightState") == [0.0, 1.0, 0.0, 1.0]


def test_state_changed_events_are_in_the_things_text_log(recording):
    assert texts(recording, f"{LEFT}/events") == ["stateChanged: true", "stateChanged: false", "stateChanged: true"]


def test_action_calls_are_in_the_things_text_log(recording):
    calls = texts(recording, f"{LEFT}/actions")
    assert [c.split("(")[0] for c in calls] == ["switchOn", "switchOff", "switchOn", "setColor"]
    assert calls[-1].startswith('setColor({"r":1,"g":0.5,"b":0}) -> [1.0,0.5,0.0]')


def test_joins_are_in_the_mesh_log(recording):
    assert {"light-left joined", "light-right joined"} <= set(texts(recording, "/mesh/log"))


def test_set_color_shows_as_swatch_and_channels(recording):
    channels = [scalars(recording, f"{LEFT}/properties/lightColor/{c}")[-1] for c in "rgb"]
    assert channels == [1.0, 0.5, 0.0]
    swatch = read_column(recording, f"{LEFT}/properties/lightColor", "Image:buffer")[-1][0]
    assert swatch == [255, 128, 0] * (mapping.SWATCH_PIXELS ** 2)


def test_each_things_td_is_a_document(recording):
    doc = read_column(recording, f"{LEFT}/td", "TextDocument:text")[-1][0]
    assert doc.startswith("# light-left") and "`lightState` (boolean" in doc
    assert json.loads(doc.split("```json", 1)[1].split("```", 1)[0])["title"] == "light-left"


def test_record_refuses_a_directory(lab, tmp_path):
    r = lab.cli("record", str(tmp_path), timeout=30)
    assert r.returncode != 0 and "is a directory" in r.stderr
    assert "Traceback" not in r.stderr


def test_a_recorder_asked_where_it_is_tells_and_goes_on_recording(lab, tmp_path):
    """`kill -USR1 PID` prints every thread's stack (for a process that does not stop); the recording goes on
    and Ctrl-C, even several in a row, still closes the file."""
    import os
    import signal

    path, log = tmp_path / "usr1.rrd", tmp_path / "recorder.log"
    recorder = lab.spawn("record", str(path), log=log)
    wait_for_line(log, "recording to", recorder)
    os.kill(recorder.pid, signal.SIGUSR1)
    stacks = wait_for_line(log, "recorder/logger.py", recorder)  # the writer's and fetcher's loops
    assert "Thread 0x" in stacks and recorder.poll() is None
    assert lab.cli("invoke", "light-right", "switchOn").returncode == 0
    for _ in range(3):
        os.kill(recorder.pid, signal.SIGINT)
    assert recorder.wait(30) == 0, log.read_text()
    assert "recording saved" in log.read_text()
    r = subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, text=True, timeout=60)
    assert r.returncode == 0, r.stdout + r.stderr


def test_up_with_record_writes_a_verified_recording(tmp_path):
    path = tmp_path / "up.rrd"
    lab = start_lab(tmp_path, "lights", http=False, things={"light-left"}, extra_args=("--record", str(path)))
    try:
        wait_for_line(lab.log, "recording to", lab.proc)
        assert lab.cli("invoke", "light-left", "switchOn").returncode == 0
    finally:
        assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"
    assert subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, timeout=60).returncode == 0
    assert scalars(path, f"{LEFT}/properties/lightState")[-1] == 1.0


# --- the mapping rules, without a mesh ------------------------------------------------------------
def _logged(entries: list[mapping.Entry]) -> dict[str, list[str]]:
    out: dict[str, list[str]] = {}
    for e in entries:
        if not e.static:
            out.setdefault(e.path, []).append(type(e.archetype).__name__)
    return out


def test_object_of_numbers_becomes_one_entity_with_a_series_per_field_named_with_its_unit():
    schema = DataSchema(type="object", properties={"x": DataSchema(type="number", unit="mm"),
                                                   "busy": DataSchema(type="boolean")})
    entries = mapping.property_entries("uarm", "location", {"x": 192.0, "busy": True}, schema)
    assert _logged(entries) == {"things/uarm/properties/location": ["Scalars"]}
    style, values = entries
    assert style.static and style.archetype.names.as_arrow_array().to_pylist() == ["x (mm)", "busy"]
    assert values.archetype.scalars.as_arrow_array().to_pylist() == [192.0, 1.0]


def test_an_object_with_other_fields_becomes_one_entity_per_field():
    entries = mapping.property_entries("t", "status", {"speed": 2.0, "mode": "auto"})
    assert _logged(entries) == {"things/t/properties/status/speed": ["Scalars"],
                                "things/t/properties/status/mode": ["TextLog"]}


def test_colour_scale_comes_from_the_schema():
    schema = DataSchema(type="array", items=DataSchema(type="number", minimum=0, maximum=255))
    colour = mapping._colour([255, 128, 0], schema)
    assert colour.rgb8 == (255, 128, 0)
    assert _logged(mapping.property_entries("color-sensor", "color", [255, 128, 0], schema)) == {
        "things/color-sensor/properties/color": ["Image"],
        **{f"things/color-sensor/properties/color/{c}": ["Scalars"] for c in "rgb"}}


def test_strings_and_other_values_become_text_lines():
    assert _logged(mapping.property_entries("t", "mode", "auto")) == {"things/t/properties/mode": ["TextLog"]}
    assert _logged(mapping.property_entries("t", "list", [{"a": 1}])) == {"things/t/properties/list": ["TextLog"]}
    assert mapping.property_entries("t", "unknown", None) == []
