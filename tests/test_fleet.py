"""`twinmesh up fleet`: virtual devices for load tests, on a mesh whose cost grows linearly.

Real labs (`twinmesh up fleet` as a subprocess), real Zenoh sessions and the real HTTP adapter.
"""
from __future__ import annotations

import json
import os
import subprocess
import threading
import time
from pathlib import Path

import httpx
import msgspec
import pytest

from devices.things.fleet import fleet_names
from devices.things.lights import light_td
from devices.things.platform_things import twin_td
from tests.labs import Lab, start_lab

pytestmark = [pytest.mark.lab, pytest.mark.slow, pytest.mark.timeout(600)]  # fleets of 60 to 240 devices


@pytest.fixture(scope="module")
def fleet(tmp_path_factory) -> Lab:
    lab = start_lab(tmp_path_factory.mktemp("fleet"), scene="fleet", extra_args=("--fleet", "200"))
    yield lab
    lab.stop()


def _listed_over_paging(base: str, limit: int = 64) -> list[str]:
    titles, url = [], f"{base}/things?limit={limit}"
    while url:
        r = httpx.get(url, timeout=30)
        assert r.status_code == 200, r.text
        titles += [td["title"] for td in r.json()]
        nxt = r.headers.get("link", "")
        url = base + nxt.split(">")[0].lstrip("<") if 'rel="next"' in nxt else ""
    return titles


def test_a_fleet_of_200_starts_and_every_device_is_listed_on_zenoh_and_over_http(fleet):
    names = fleet_names(200)
    assert names[:5] == ["belt-1", "infrared-1", "color-1", "light-1", "climate-1"] and names[-1] == "climate-40"
    r = fleet.cli("things")
    assert r.returncode == 0, r.stderr
    assert set(names) <= set(r.stdout.split())
    assert set(names) <= set(_listed_over_paging(fleet.http))
    listed = httpx.get(fleet.http + "/", timeout=10).json()
    assert len(listed) == 201  # and the lab's tdgen
    # spread over one process per core, each named in ps
    children = subprocess.run(["ps", "-o", "args=", "--ppid", str(fleet.proc.pid)], capture_output=True,
                              text=True).stdout.split("\n")
    fleet_procs = [c for c in children if c.startswith("twinmesh: fleet ")]
    assert len(fleet_procs) == min(os.cpu_count() or 1, 40), children


def _affordances(td: dict) -> dict:
    """What a client relies on: each affordance's schema, without forms and texts."""
    drop = {"forms", "title", "description", "synchronous", "uriVariables"}
    return {kind: {name: {k: v for k, v in a.items() if k not in drop} for name, a in td.get(kind, {}).items()}
            for kind in ("properties", "actions", "events")}


@pytest.mark.parametrize("device,lab_td", [
    ("belt-3", lambda: twin_td("conveyor-belt-1")), ("infrared-3", lambda: twin_td("infrared-sensor-1")),
    ("color-3", lambda: twin_td("color-sensor")), ("light-3", lambda: light_td("light-left"))])
def test_a_fleet_device_serves_the_affordances_of_the_labs_device(fleet, device, lab_td):
    served = httpx.get(f"{fleet.http}/{device}", timeout=10).json()
    lab = msgspec.to_builtins(lab_td())
    assert served["title"] == device and served["id"] == f"urn:twinmesh:thing:{device}"
    assert _affordances(served) == _affordances(lab)


def _sse(url: str, count: int, seconds: float, opened: threading.Event | None = None) -> list[object]:
    """Up to `count` data items of an SSE stream, within `seconds`; `opened` is set at its first line
    (the adapter registers a stream before it answers: every later change is in it)."""
    got: list[object] = []

    def read() -> None:
        with httpx.stream("GET", url, timeout=seconds + 5) as r:
            for line in r.iter_lines():
                if opened is not None:
                    opened.set()
                if line.startswith("data:"):
                    got.append(json.loads(line[5:]))
                    if len(got) >= count:
                        return
    t = threading.Thread(target=read, daemon=True)
    t.start()
    t.join(seconds)
    return got


def test_a_running_belt_carries_parcels_past_its_beam_and_colour_sensor(fleet):
    base = fleet.http
    assert httpx.get(f"{base}/infrared-5/properties/objectPresence").json() is False
    events: list[object] = []
    opened = threading.Event()
    watcher = threading.Thread(target=lambda: events.extend(_sse(f"{base}/infrared-5/events/detectedObject/sse", 2, 20,
                                                                 opened)))
    watcher.start()
    assert opened.wait(20), "the event stream did not open"
    assert httpx.put(f"{base}/belt-5/properties/speed", json=100).status_code == 204
    assert httpx.post(f"{base}/belt-5/actions/startBeltForward").status_code == 200
    colours = []
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline and not any(c != [0, 0, 0] for c in colours):
        if httpx.get(f"{base}/infrared-5/properties/objectPresence").json():
            colours.append(httpx.get(f"{base}/color-5/properties/color").json())
        time.sleep(0.05)
    watcher.join()
    httpx.post(f"{base}/belt-5/actions/stopBelt")
    assert events[:2] == [True, False], events  # a parcel arrived at the beam, then left it
    assert any(c != [0, 0, 0] for c in colours), colours  # the colour sensor saw it
    # another station's belt never moved
    assert httpx.get(f"{base}/infrared-6/properties/objectPresence").json() is False


def test_bad_input_to_a_fleet_device_is_refused_and_changes_nothing(fleet):
    base = fleet.http
    r = httpx.put(f"{base}/belt-7/properties/speed", json=250)
    assert r.status_code == 400 and r.headers["content-type"] == "application/problem+json"
    assert httpx.get(f"{base}/belt-7/properties/speed").json() == 100
    r = httpx.put(f"{base}/climate-7/properties/interval", json=0)
    assert r.status_code == 400 and r.headers["content-type"] == "application/problem+json"
    assert httpx.get(f"{base}/climate-7/properties/interval").json() == 1.0
    assert httpx.put(f"{base}/infrared-7/properties/objectPresence", json=True).status_code == 405


def test_a_climate_sensor_publishes_a_noisy_reading_every_interval(fleet):
    base = fleet.http
    readings = _sse(f"{base}/climate-9/properties/temperature/sse", 4, 8)
    assert len(readings) >= 3, readings
    assert all(isinstance(t, float) and 15 <= t <= 30 for t in readings)
    assert len(set(readings)) > 1  # noise: not one value repeated
    assert httpx.put(f"{base}/climate-9/properties/interval", json=0.2).status_code == 204
    fast = _sse(f"{base}/climate-9/properties/temperature/sse", 10, 4)
    assert len(fast) == 10, fast


def test_a_light_of_the_fleet_switches_like_the_labs(fleet):
    r = fleet.cli("invoke", "light-11", "switchOn")
    assert r.returncode == 0, r.stderr
    assert fleet.cli("read", "light-11", "lightState").stdout.strip() == "true"
    assert fleet.cli("read", "light-12", "lightState").stdout.strip() == "false"


def _fleet_process_figures(lab: Lab) -> tuple[int, int, int]:
    """File descriptors, threads and fleet processes of a lab's fleet processes, summed."""
    out = subprocess.run(["ps", "-o", "pid=,args=", "--ppid", str(lab.proc.pid)], capture_output=True,
                         text=True).stdout
    pids = [int(line.split()[0]) for line in out.splitlines() if "twinmesh: fleet " in line]
    fds = sum(len(os.listdir(f"/proc/{p}/fd")) for p in pids)
    threads = sum(len(os.listdir(f"/proc/{p}/task")) for p in pids)
    return fds, threads, len(pids)


@pytest.mark.skipif(not Path("/proc/self/fd").exists(), reason="needs /proc to count descriptors")
def test_descriptors_and_threads_per_device_stay_bounded_as_the_fleet_doubles(tmp_path):
    figures = {}
    for n in (60, 120, 240):
        lab = start_lab(tmp_path, scene="fleet", http=False, extra_args=("--fleet", str(n)))
        try:
            time.sleep(1)
            figures[n] = _fleet_process_figures(lab)
        finally:
            lab.stop()
    (f60, t60, p60), (f120, t120, _), (f240, t240, _) = figures[60], figures[120], figures[240]
    per_device = [(f120 - f60) / 60, (f240 - f120) / 120]
    print(f"fleet processes: {p60}; fds {f60}/{f120}/{f240}, threads {t60}/{t120}/{t240} at 60/120/240 devices")
    # each device costs its one link to the router, not one per other device (the old topology's N²/2)
    assert all(d <= 2 for d in per_device), figures
    # threads are the process's, not the devices'
    assert t240 - t60 <= 8 * p60, figures


def test_direct_without_join_is_refused_naming_the_option():
    from click.testing import CliRunner

    from devices.cli.main import main

    result = CliRunner().invoke(main, ["up", "fleet", "--fleet", "5", "--direct"])
    assert result.exit_code == 2 and "--direct is for --join" in result.output, result.output
