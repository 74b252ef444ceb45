"""The live 3D view of a running iot-lab, in a real browser, and the lab's recording read back.

One lab (`twinmesh up iot-lab` with its live view and `--record`) for the module. The browser test
opens the view as a person would (headless Chromium, software WebGL), waits until the room is drawn,
switches a lamp on in a colour nothing else in the room has, and waits for that colour in the page (in a
browser that draws WebGL in software, as here, our page lays the viewer out at half size, enlarged);
Rerun says no error or warning about the data on the console meanwhile, and the page asks no host
but this one for anything. A second page, opened after the lamp went through several colours, shows
it in its current colour and in no earlier one. The recording test then changes the lamps, adds and removes an obstacle,
stops the lab and reads its recording with rerun-sdk's own reader.
"""
import json
import re
import socket
import subprocess

import numpy as np
import pytest
from labs import start_lab
from rerun_view import VIEWPORT, colour_share, in_software, room_drawn, shared_frames, viewer_page
from waiting import eventually

from recordings import RERUN, read_column

pytestmark = [pytest.mark.lab, pytest.mark.slow]

MAGENTA = (255, 0, 255)  # no body of the iot-lab has it
CYAN = (0, 255, 255)  # nor this (channels of 0 or 1 only: the view's shading keeps their hue)
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


def shows(pixels: np.ndarray, rgb: tuple[int, int, int]) -> bool:
    return colour_share(pixels, rgb) * pixels.shape[0] * pixels.shape[1] >= 20


@pytest.mark.browser
@pytest.mark.timeout(DRAWN_TIMEOUT + SHOWN_TIMEOUT + 600)  # the lab's start besides
def test_the_live_view_draws_the_lab_and_a_lamp_in_the_colour_it_is_switched_on_in(lab):
    invoke(lab, "invoke", "light-left", "switchOff")
    with viewer_page(view_url(lab)) as view:
        try:
            eventually(lambda: room_drawn(view.pixels()), timeout=DRAWN_TIMEOUT, interval=5.0,
                       what="the room drawn in the view")
            assert magenta_pixels(view.pixels()) == 0
            scale, renderer, width = view.layout()  # a software renderer draws a quarter of the pixels
            assert scale == (2 if in_software(renderer) else 1), renderer
            assert width == VIEWPORT["width"] // scale
            invoke(lab, "invoke", "light-left", "setColor", json.dumps({"r": 1, "g": 0, "b": 1}))
            invoke(lab, "invoke", "light-left", "switchOn")
            eventually(lambda: magenta_pixels(view.pixels()) >= 20, timeout=SHOWN_TIMEOUT, interval=2.0,
                       what="the lamp's magenta in the view")
        except AssertionError:
            view.save(lab.tmp / "view.png")
            raise
        assert view.rerun_problems() == []
        assert view.foreign_hosts() == set(), "the page asked hosts other than this one"


@pytest.mark.browser
@pytest.mark.timeout(DRAWN_TIMEOUT + SHOWN_TIMEOUT + 600)
def test_a_viewer_opened_late_shows_the_lamp_in_its_current_colour_not_an_earlier_one(lab):
    invoke(lab, "invoke", "light-left", "switchOn")
    for colour in ({"r": 1, "g": 0, "b": 0}, {"r": 1, "g": 0, "b": 1}, {"r": 0, "g": 1, "b": 0}):
        invoke(lab, "invoke", "light-left", "setColor", json.dumps(colour))
    invoke(lab, "write", "light-left", "lightColor", "[0, 1, 1]")  # cyan: the current colour
    with viewer_page(view_url(lab)) as view:
        try:
            eventually(lambda: room_drawn(view.pixels()), timeout=DRAWN_TIMEOUT, interval=5.0,
                       what="the room drawn in the late viewer")
            eventually(lambda: shows(view.view_pixels(), CYAN), timeout=SHOWN_TIMEOUT, interval=2.0,
                       what="the lamp's current cyan in the late viewer")
            assert not shows(view.view_pixels(), MAGENTA), "an earlier colour of the lamp is still drawn"
        except AssertionError:
            view.save(lab.tmp / "late-view.png")
            raise
        assert view.rerun_problems() == []


def test_the_view_and_its_stream_listen_on_the_views_host_only(lab):
    """`--view 127.0.0.1:PORT` (the default host): neither port answers on this machine's other addresses."""
    import psutil

    found = re.search(r"http://127\.0\.0\.1:(\d+)/\?url=rerun%2Bhttp%3A%2F%2F127\.0\.0\.1%3A(\d+)", view_url(lab))
    assert found, view_url(lab)
    ports = [int(p) for p in found.groups()]
    others = [a.address for addrs in psutil.net_if_addrs().values() for a in addrs
              if a.family == socket.AF_INET and not a.address.startswith("127.")]
    if not others:
        pytest.skip("this machine has no address but loopback")
    for port in ports:
        with socket.create_connection(("127.0.0.1", port), timeout=10):
            pass
        for address in others:
            with pytest.raises(OSError), socket.create_connection((address, port), timeout=10):
                pass


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
