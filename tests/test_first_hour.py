"""A newcomer's first mistakes get clear answers: readiness, taken ports, wrong names, bad values."""
from __future__ import annotations

import os
import signal
import socket
import subprocess
import time
import uuid

import httpx
import psutil
import pytest
from labs import REPO, free_port, spawn_up, twinmesh_cmd, wait_ready

pytestmark = pytest.mark.lab


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


def run_up(endpoint: str, *args: str, timeout: float = 60, mark: str = "") -> subprocess.CompletedProcess:
    view = () if "--view" in args or "--no-view" in args else ("--view", f"127.0.0.1:{free_port()}")
    return subprocess.run(twinmesh_cmd(endpoint, "up", *args, *view), capture_output=True, text=True, timeout=timeout,
                          cwd=REPO, env={**os.environ, MARK: mark})


MARK = "TWINMESH_TEST_RUN"  # in the environment of what one test started, and so of every process it started


def left_running(mark: str) -> list[str]:
    """The processes started under `mark` that still run: only this test's (other tests, other pytest
    workers and other people's labs on the machine run twinmesh processes too)."""
    found = []
    for p in psutil.process_iter():
        try:
            if p.environ().get(MARK) == mark and p.status() != psutil.STATUS_ZOMBIE:
                found.append(" ".join(p.cmdline()))
        except (psutil.NoSuchProcess, psutil.AccessDenied):
            continue
    return found


# --- ready -------------------------------------------------------------------------------------
def test_up_prints_one_ready_line_with_count_url_and_endpoint_and_nothing_before(lab):
    lines = [line for line in lab.log.read_text().splitlines() if line.startswith("twinmesh lab")]
    assert len(lines) == 1, lab.log.read_text()
    assert "ready" in lines[0] and "3 Things" in lines[0]
    assert lab.endpoint in lines[0] and lab.http + "/" in lines[0]
    before_ready = lab.log.read_text().split(lines[0])[0]
    assert "ready" not in before_ready and "HTTP" not in before_ready


def test_wait_exits_0_once_the_lab_is_ready_and_names_it(lab):
    r = lab.cli("wait", "--timeout", "30")
    assert r.returncode == 0, r.stderr
    assert "ready" in r.stdout and "'lights'" in r.stdout and lab.endpoint in r.stdout


def test_wait_for_named_things_exits_0_when_they_answer(lab):
    r = lab.cli("wait", "--thing", "light-left", "--thing", "tdgen", "--timeout", "30")
    assert r.returncode == 0 and "light-left" in r.stdout, r.stderr


def test_wait_without_a_lab_gives_up_after_its_timeout_with_the_reason():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    r = subprocess.run(twinmesh_cmd(endpoint, "wait", "--timeout", "1"), capture_output=True, text=True,
                       timeout=60, cwd=REPO)
    assert r.returncode == 3, "no lab reachable is exit code 3"
    assert endpoint in r.stderr and "Traceback" not in r.stderr


def test_wait_takes_the_endpoint_from_the_environment(lab):
    env = {**os.environ, "TWINMESH_CONNECT": lab.endpoint}
    r = subprocess.run([*twinmesh_cmd(lab.endpoint, "wait")[:3], "wait", "--timeout", "30"], capture_output=True,
                       text=True, timeout=60, cwd=REPO, env=env)
    assert r.returncode == 0 and lab.endpoint in r.stdout, r.stderr


def test_up_then_wait_then_a_command_works_without_sleeps(tmp_path):
    """The README's script: `twinmesh up & twinmesh wait && twinmesh ...`."""
    endpoint, http = f"tcp/127.0.0.1:{free_port()}", free_port()
    log = tmp_path / "up.log"
    up = spawn_up(endpoint, log, "lights", "--http", f"127.0.0.1:{http}")
    try:
        r = wait_ready(endpoint)
        assert r.returncode == 0, r.stderr + log.read_text()
        assert subprocess.run(twinmesh_cmd(endpoint, "invoke", "light-left", "switchOn"), capture_output=True,
                              timeout=30, cwd=REPO).returncode == 0
        assert httpx.get(f"http://127.0.0.1:{http}/light-left/properties/lightState").json() is True
    finally:
        os.killpg(up.pid, signal.SIGINT)
        up.wait(30)


# --- taken ports -------------------------------------------------------------------------------
@pytest.mark.parametrize("which", ["http", "zenoh"])
def test_a_taken_port_is_one_line_naming_it_and_its_option_and_nothing_is_left_running(which):
    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        zenoh_port = port if which == "zenoh" else free_port()
        http_port = port if which == "http" else free_port()
        mark = uuid.uuid4().hex
        t0 = time.monotonic()
        r = run_up(f"tcp/127.0.0.1:{free_port()}", "lights", "--zenoh", f"tcp/127.0.0.1:{zenoh_port}",
                   "--http", f"127.0.0.1:{http_port}", mark=mark)
        took = time.monotonic() - t0
    assert r.returncode != 0 and took < 60  # a hang detector, not a timing goal
    errors = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(errors) == 1, r.stderr
    assert f"127.0.0.1:{port}" in errors[0] and ("--http" if which == "http" else "--zenoh") in errors[0]
    assert "Traceback" not in r.stderr and "ready" not in r.stdout
    assert not left_running(mark)


def test_the_router_endpoint_is_chosen_on_up_itself(tmp_path):
    """`up --zenoh` beats the global --connect (which nobody finds) for where the router listens."""
    chosen = f"tcp/127.0.0.1:{free_port()}"
    log = tmp_path / "up.log"
    up = subprocess.Popen(twinmesh_cmd(f"tcp/127.0.0.1:{free_port()}", "up", "lights", "--no-http", "--no-view",
                                       "--zenoh", chosen),
                          stdout=open(log, "wb"), stderr=subprocess.STDOUT, cwd=REPO, start_new_session=True)
    try:
        r = subprocess.run(twinmesh_cmd(chosen, "wait", "--timeout", "60"), capture_output=True, text=True,
                           timeout=90, cwd=REPO)
        assert r.returncode == 0 and chosen in r.stdout, r.stderr + log.read_text()
    finally:
        os.killpg(up.pid, signal.SIGINT)
        up.wait(30)
    assert up.returncode == 0 and chosen in log.read_text()


# --- names and values --------------------------------------------------------------------------
@pytest.mark.parametrize("args, expected", [
    (("read", "light-left", "noSuchProperty"),
     "light-left has no property 'noSuchProperty'; its properties: lightColor, lightState"),
    (("invoke", "light-left", "noSuchAction"), "light-left has no action 'noSuchAction'; its actions: setColor"),
    (("subscribe", "light-left", "noSuchEvent"), "light-left has no event 'noSuchEvent'; its events: stateChanged"),
    (("observe", "light-left", "noSuchProperty"), "light-left has no property 'noSuchProperty'"),
    (("observe", "no-such-thing", "lightState"), "no-such-thing is not on the mesh"),
    (("subscribe", "no-such-thing", "stateChanged"), "no-such-thing is not on the mesh"),
])
def test_a_wrong_name_is_named_at_once_with_what_there_is(lab, args, expected):
    r = lab.cli(*args, timeout=30)  # observe/subscribe used to wait forever
    assert r.returncode == 1 and expected in r.stderr, r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "Traceback" not in r.stderr


@pytest.mark.parametrize("method, path, expected", [
    ("GET", "/light-left/properties/noSuchProperty", "its properties: lightColor, lightState"),
    ("PUT", "/light-left/properties/noSuchProperty", "its properties: lightColor, lightState"),
    ("POST", "/light-left/actions/noSuchAction", "its actions: setColor, switchOff, switchOn"),
    ("GET", "/light-left/events/noSuchEvent", "its events: stateChanged"),
])
def test_over_http_a_wrong_name_is_a_404_listing_what_there_is(lab, method, path, expected):
    r = httpx.request(method, lab.http + path, json=True if method == "PUT" else None)
    assert r.status_code == 404 and r.headers["content-type"].startswith("application/problem+json")
    assert expected in r.json()["detail"]


@pytest.mark.parametrize("args, expected", [
    (("write", "light-left", "lightState", "{"), "VALUE is not valid JSON"),
    (("write", "light-left", "lightState", "3"), "lightState: expected boolean, got 3"),
    (("invoke", "light-left", "setColor", '{"r": 1}'), "missing required field 'g'"),
])
def test_a_bad_value_is_one_line_naming_the_field_and_the_rule(lab, args, expected):
    r = lab.cli(*args, timeout=30)
    assert r.returncode != 0 and expected in r.stderr
    assert "Traceback" not in r.stderr


def test_version_is_the_installed_distributions():
    from importlib.metadata import version

    r = subprocess.run(twinmesh_cmd("tcp/127.0.0.1:1", "--version"), capture_output=True, text=True, timeout=60,
                       cwd=REPO)
    assert r.returncode == 0 and r.stdout.split()[-1] == version("twinmesh")
