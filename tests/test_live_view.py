"""The live 3D view of a running iot-lab, in a real browser, and the lab's recording read back.

One lab (`twinmesh up iot-lab` with its live view and `--record`) for the module. The browser test
opens the view as a person would (headless Chromium, software WebGL), waits until the room is drawn,
switches a lamp on in a colour nothing else in the room has, and waits for that colour in the page;
Rerun says no error or warning about the data on the console meanwhile, and the page asks no host
but this one for anything. The recording test then changes the lamps, adds and removes an obstacle,
stops the lab and reads its recording with rerun-sdk's own reader.
"""
import json
import re
import subprocess

import numpy as np
import pytest
from labs import start_lab
from rerun_view import colour_share, room_drawn, shared_frames, viewer_page
from waiting import eventually

from recordings import RERUN, read_column

pytestmark = [pytest.mark.lab, pytest.mark.slow]

MAGENTA = (255, 0, 255)  # no body of the iot-lab has it
DRAWN_TIMEOUT = 900.0  # a software rasteriser on a busy 2-core machine needs minutes for its first frame
SHOWN_TIMEOUT = 300.0
CRATE = {"name": "crate", "size": [0.3, 0.3, 0.3], "position": [2.3, -0.42, 0.9]}
SHADE = "/world/bodies/light-left-shade"


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("live-view")
    lab = start_lab(tmp, "iot-lab", http=False, view=True, things={"world", "light-left", "light-right"},
                    extra_args=("--record", str(tmp / "lab.rrd")))
    lab.tmp = tmp
    yield lab
    lab.stop()


def view_url(lab) -> str:
    found = re.search(r"3D view (http://\S+?),? ", lab.log.read_text())
    assert found, f"no view URL in the lab's ready line:\n{lab.log.read_text()[-2000:]}"
    return found.group(1).rstrip(",")


def invoke(lab, *args: str) -> None:
    r = lab.cli(*args, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr


def magenta_pixels(pixels: np.ndarray) -> int:
    return round(colour_share(pixels, MAGENTA) * pixels.shape[0] * pixels.shape[1])


@pytest.mark.browser
@pytest.mark.timeout(DRAWN_TIMEOUT + SHOWN_TIMEOUT + 600)  # the lab's start besides
def test_the_live_view_draws_the_lab_and_a_lamp_in_the_colour_it_is_switched_on_in(lab):
    invoke(lab, "invoke", "light-left", "switchOff")
    with viewer_page(view_url(lab)) as view:
        try:
            eventually(lambda: room_drawn(view.pixels()), timeout=DRAWN_TIMEOUT, interval=5.0,
                       what="the room drawn in the view")
            assert magenta_pixels(view.pixels()) == 0
            invoke(lab, "invoke", "light-left", "setColor", json.dumps({"r": 1, "g": 0, "b": 1}))
            invoke(lab, "invoke", "light-left", "switchOn")
            eventually(lambda: magenta_pixels(view.pixels()) >= 20, timeout=SHOWN_TIMEOUT, interval=2.0,
                       what="the lamp's magenta in the view")
        except AssertionError:
            view.save(lab.tmp / "view.png")
            raise
        assert view.rerun_problems() == []
        assert view.foreign_hosts() == set(), "the page asked hosts other than this one"


def test_the_recording_holds_each_lamp_change_and_names_each_frame_once(lab):
    invoke(lab, "invoke", "light-left", "switchOff")
    invoke(lab, "invoke", "light-left", "setColor", json.dumps({"r": 1, "g": 0, "b": 0}))
    invoke(lab, "invoke", "light-left", "switchOn")
    invoke(lab, "write", "light-left", "lightColor", "[0, 1, 0]")
    invoke(lab, "invoke", "world", "addObstacle", json.dumps(CRATE))
    invoke(lab, "invoke", "world", "removeObstacle", json.dumps({"name": "crate"}))
    invoke(lab, "invoke", "light-left", "switchOff")
    assert lab.stop(), "the lab did not stop cleanly on Ctrl-C"
    path = lab.tmp / "lab.rrd"
    assert subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, timeout=120).returncode == 0
    colours = [_rgb(c[0]) for c in read_column(path, SHADE, "Boxes3D:colors")]
    red, green, off = colours.index((255, 0, 0)), colours.index((0, 255, 0)), len(colours) - 1
    assert red < green < off and colours[off] == (89, 89, 89), colours  # red, then green, then off (grey)
    assert shared_frames(path) == {}


def _rgb(packed: int) -> tuple[int, int, int]:
    return packed >> 24, (packed >> 16) & 0xFF, (packed >> 8) & 0xFF
