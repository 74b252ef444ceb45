"""Every byte from outside is hostile: no client input reaches a 5xx, a wildcard never acts, a forged
value is not served or recorded, a killed parent leaves no orphan, a killed recorder's file is repaired."""
from __future__ import annotations

import os
import signal
import subprocess
import time

import httpx
import msgspec
import psutil
import pytest
from labs import REPO, free_port, spawn_up, twinmesh_cmd, wait_ready
from waiting import always

from recordings import RERUN, scalars, wait_for_line

pytestmark = pytest.mark.lab

PROBLEM = "application/problem+json"
DEEP = b"[" * 5000 + b"]" * 5000
HUGE = b"9" * 400


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


@pytest.fixture
def http(lab):
    with httpx.Client(base_url=lab.http, timeout=30) as h:  # one connection: it must survive every answer
        yield h


@pytest.fixture
def zenoh_session(lab):
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    with open_session(MeshSettings(mode="client", connect=(lab.endpoint,))) as session:
        yield session


def replies(session, key: str, payload: bytes | None = None) -> list[tuple[str, bool, bytes]]:
    """(key, ok, payload) of every reply to one query."""
    kwargs = {"timeout": 5.0} if payload is None else {"timeout": 5.0, "payload": payload}
    out = []
    for r in session.get(key, **kwargs):
        if r.ok is not None:
            out.append((str(r.ok.key_expr), True, r.ok.payload.to_bytes()))
        else:
            out.append(("", False, r.err.payload.to_bytes()))
    return out


# --- HTTP --------------------------------------------------------------------------------------
@pytest.mark.parametrize("method, path, body", [
    ("PUT", "/light-left/properties/lightColor", DEEP),
    ("PUT", "/light-left/properties/lightColor", b'"\xff"'),
    ("PUT", "/light-left/properties/lightColor", b'{"\xff": 1}'),
    ("POST", "/light-left/actions/setColor", b'{"r": ' + HUGE + b', "g": 0, "b": 0}'),
    ("POST", "/light-left/actions/setColor", b'{"r": 1e999, "g": 0, "b": 0}'),
    ("PUT", "/light-left/properties/lightState", HUGE),
])
def test_malformed_bodies_get_400_and_the_connection_stays_usable(http, method, path, body):
    before = http.get("/light-left/properties/lightColor").json()
    r = http.request(method, path, content=body, headers={"Content-Type": "application/json"})
    assert r.status_code == 400 and r.headers["content-type"].startswith(PROBLEM), r.text
    assert r.json()["detail"]
    assert http.get("/light-left/properties/lightColor").json() == before  # same connection, nothing changed


@pytest.mark.parametrize("name", ["a%23b", "%24%2A", "%2A%2A", "a%0A", "%3F"])
def test_file_names_with_key_characters_are_404_and_never_reach_zenoh(http, name):
    r = http.get(f"/light-left/files/{name}")
    assert r.status_code == 404 and r.headers["content-type"].startswith(PROBLEM), r.text


def test_a_page_offset_that_is_not_ascii_digits_is_400(http):
    r = http.get("/things?offset=%C2%B2")
    assert r.status_code == 400 and "offset" in r.json()["detail"]


# --- Zenoh -------------------------------------------------------------------------------------
def test_an_input_less_action_refuses_a_payload_over_zenoh(lab, zenoh_session):
    lab.cli("invoke", "light-left", "switchOff", check=True)
    (key, ok, payload), = replies(zenoh_session, "wot/light-left/actions/switchOn", b"\xff{{")
    assert not ok and msgspec.json.decode(payload)["status"] == 400
    assert lab.cli("read", "light-left", "lightState").stdout.strip() == "false"


def test_deep_nesting_over_zenoh_is_400_not_500(zenoh_session):
    (key, ok, payload), = replies(zenoh_session, "wot/light-left/properties/lightColor", DEEP)
    assert not ok and msgspec.json.decode(payload)["status"] == 400


def test_a_wildcard_query_may_read_but_never_acts_and_replies_name_the_thing(lab, zenoh_session):
    for light in ("light-left", "light-right"):
        lab.cli("invoke", light, "switchOff", check=True)
    acted = replies(zenoh_session, "wot/*/actions/*", b"null")
    assert acted and all(not ok for _, ok, _ in acted)
    assert all(msgspec.json.decode(p)["status"] == 400 for _, _, p in acted)
    for light in ("light-left", "light-right"):
        assert lab.cli("read", light, "lightState").stdout.strip() == "false"  # nothing switched on
    read = replies(zenoh_session, "wot/*/properties/lightState")
    assert sorted(k for k, ok, _ in read if ok) == ["wot/light-left/properties/lightState",
                                                    "wot/light-right/properties/lightState"]


def test_a_wildcard_within_a_thing_gets_one_reply_per_affordance_and_an_unknown_key_none(zenoh_session):
    # a Thing serves all its keys through one queryable (wot/<thing>/**) and routes each query itself
    read = replies(zenoh_session, "wot/light-left/properties/*")
    assert sorted(k for k, ok, _ in read if ok) == ["wot/light-left/properties/lightColor",
                                                    "wot/light-left/properties/lightState"]
    assert len(read) == 2
    everything = {k for k, ok, _ in replies(zenoh_session, "wot/light-left/**") if ok}
    assert {"wot/light-left/td", "wot/light-left/properties/lightState"} <= everything
    assert replies(zenoh_session, "wot/light-left/properties/nosuch") == []
    assert replies(zenoh_session, "wot/light-left/unknown/key/here") == []


def test_a_forged_publication_is_not_served_and_a_forged_td_changes_nothing(lab, http, zenoh_session):
    lab.cli("invoke", "light-right", "switchOff", check=True)
    http.get("/light-right/properties/lightState")
    zenoh_session.put("wot/light-right/properties/lightState", b"{{{not json")
    zenoh_session.put("wot/light-right/properties/lightState", b'"on"')  # JSON, but not a boolean
    zenoh_session.put("wot/light-right/td", b"{{")
    zenoh_session.put("wot/light-right/td", msgspec.json.encode({"title": "light-right"}))  # no affordances
    def still_served() -> bool:  # the garbage reaches the adapter and the light meanwhile: neither takes it
        r = http.get("/light-right/properties/lightState")
        return r.status_code == 200 and r.json() is False

    always(still_served, 1.0, what="light-right still read as off")
    td = http.get("/light-right")
    assert td.status_code == 200 and "switchOn" in td.json()["actions"]
    assert "light-right" in [t["title"] for t in http.get("/things").json()]


# --- processes and recordings ------------------------------------------------------------------
def test_killing_up_with_sigkill_leaves_no_orphan_and_the_ports_free(tmp_path):
    endpoint, port = f"tcp/127.0.0.1:{free_port()}", free_port()
    log = tmp_path / "up.log"
    up = spawn_up(endpoint, log, "lights", "--http", f"127.0.0.1:{port}")
    try:
        assert wait_ready(endpoint).returncode == 0, log.read_text()
        children = psutil.Process(up.pid).children(recursive=True)
        assert len(children) >= 4
        up.send_signal(signal.SIGKILL)
        up.wait(10)
        gone, alive = psutil.wait_procs(children, timeout=10)  # a hang detector; the contract is 2 s
        assert not alive, [" ".join(p.cmdline()) for p in alive]
    finally:
        try:
            os.killpg(up.pid, signal.SIGKILL)  # whatever is left, if the test failed
        except ProcessLookupError:
            pass
    again = spawn_up(endpoint, tmp_path / "again.log", "lights", "--http", f"127.0.0.1:{port}")
    try:
        r = wait_ready(endpoint)
        assert r.returncode == 0, r.stderr + (tmp_path / "again.log").read_text()
    finally:
        os.killpg(again.pid, signal.SIGINT)
        again.wait(30)


def test_a_recording_cut_by_sigkill_is_repaired_and_loses_at_most_a_second(lab, tmp_path):
    path, log = tmp_path / "cut.rrd", tmp_path / "recorder.log"
    recorder = lab.spawn("record", str(path), log=log)
    wait_for_line(log, "recording to", recorder)
    for state in ("switchOn", "switchOff") * 5:
        lab.cli("invoke", "light-left", state, check=True)
    time.sleep(1.0)  # at most this is lost
    os.killpg(recorder.pid, signal.SIGKILL)
    recorder.wait(10)
    assert subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, timeout=60).returncode != 0
    r = subprocess.run(twinmesh_cmd(lab.endpoint, "record", "--repair", str(path)), capture_output=True, text=True,
                       timeout=120, cwd=REPO)
    assert r.returncode == 0 and "repaired" in r.stdout, r.stderr
    assert subprocess.run([RERUN, "rrd", "verify", str(path)], capture_output=True, timeout=60).returncode == 0
    assert (tmp_path / "cut.rrd.broken").exists()
    assert scalars(path, "/things/light-left/properties/lightState")[-10:] == [1.0, 0.0] * 5


def test_repairing_something_that_is_no_recording_is_one_line(tmp_path):
    bogus = tmp_path / "bogus.rrd"
    bogus.write_bytes(b"not a recording")
    r = subprocess.run(twinmesh_cmd("tcp/127.0.0.1:1", "record", "--repair", str(bogus)), capture_output=True,
                       text=True, timeout=120, cwd=REPO)
    assert r.returncode == 1 and "Traceback" not in r.stderr and str(bogus) in r.stderr
    assert bogus.read_bytes() == b"not a recording"


def test_a_simulation_that_stops_stepping_says_so_and_tells_its_process():
    import threading

    from devices.sim.pybullet_world import World

    died = threading.Event()
    world = World(speed=None)
    world.on_death(died.set)
    world.start()
    try:
        assert world.stepping
        world.add_pre_step(lambda dt: 1 / 0)  # a bug in the stepping thread
        assert died.wait(10)
        assert not world.stepping
    finally:
        world.close()


def test_speed_factors_outside_the_sane_range_are_refused_by_the_world_and_the_cli():
    from devices.sim.pybullet_world import World

    world = World(speed=1.0)
    try:
        for bad in (1e-13, 0.0, -1.0, 1e9):
            with pytest.raises(ValueError):
                world.speed = bad
        assert world.speed == 1.0
    finally:
        world.close()
    r = subprocess.run(twinmesh_cmd("tcp/127.0.0.1:1", "up", "lights", "--speed", "1e-9"), capture_output=True,
                       text=True, timeout=60, cwd=REPO)
    assert r.returncode == 2 and "0.01..1000" in r.stderr and "Traceback" not in r.stderr
