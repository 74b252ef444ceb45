"""The lights lab driven from the command line, as plain Zenoh peers."""
import json
import os
import subprocess
import time

import pytest
from labs import REPO, start_lab, twinmesh_cmd

pytestmark = pytest.mark.lab


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


def test_things_lists_both_lights_and_the_td_generator(lab):
    streamed = lab.cli("things").stdout.split()  # as the answers arrive
    assert sorted(streamed) == ["light-left", "light-right", "tdgen"]  # `up` always starts tdgen
    assert lab.cli("things", "--sort").stdout.split() == ["light-left", "light-right", "tdgen"]


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
    assert r.returncode == 1 and message in r.stderr
    assert "Traceback" not in r.stderr
    assert lab.cli("read", "light-left", "lightState").stdout == before


def test_out_of_range_colour_is_refused(lab):
    before = lab.cli("read", "light-left", "lightColor").stdout
    r = lab.cli("invoke", "light-left", "setColor", '{"r": 2, "g": 0, "b": 0}')
    assert r.returncode == 1 and "input.r: 2 is above the maximum 1" in r.stderr
    assert lab.cli("read", "light-left", "lightColor").stdout == before


def test_malformed_json_names_the_problem(lab):
    r = lab.cli("invoke", "light-left", "setColor", "{bad")
    assert r.returncode == 2 and "not valid JSON" in r.stderr


def test_unknown_thing_is_reported_not_on_the_mesh(lab):
    r = lab.cli("read", "no-such-thing", "x")
    assert r.returncode == 1 and "not on the mesh" in r.stderr


def test_observe_prints_each_change(lab):
    lab.cli("invoke", "light-left", "switchOff")
    obs = subprocess.Popen(twinmesh_cmd(lab.endpoint, "observe", "light-left", "lightState", "--count", "2"),
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=REPO)
    assert "waiting for changes" in obs.stderr.readline()
    lab.cli("invoke", "light-left", "switchOn")
    lab.cli("invoke", "light-left", "switchOff")
    out, _ = obs.communicate(timeout=20)
    assert out.split() == ["true", "false"]


def test_up_stops_every_process_on_ctrl_c(tmp_path):
    lab = start_lab(tmp_path, "lights", http=False, things={"light-left"})
    children = _children(lab.proc.pid)
    assert len(children) >= 2, "router and lights run as separate processes"
    assert lab.stop(), "the lab did not stop on Ctrl-C within the grace time"
    assert lab.proc.returncode == 0
    deadline = time.monotonic() + 5  # the multiprocessing resource tracker exits just after its parent
    while [pid for pid in children if _alive(pid)] and time.monotonic() < deadline:
        time.sleep(0.1)
    left = [pid for pid in children if _alive(pid)]
    assert not left, f"processes left behind after Ctrl-C: {left}"



STARTER = """
import sys, time
sys.path.insert(0, {tests!r})
from pathlib import Path
from labs import start_lab
lab = start_lab(Path({tmp!r}), "lights", http=False, things={{"light-left"}})
print(lab.proc.pid, flush=True)
time.sleep(600)
"""


@pytest.mark.parametrize("hangups", ["heard", "ignored"])
def test_a_lab_dies_with_whoever_started_it_even_killed_hard(tmp_path, hangups):
    """A test process (or a script, an editor) that started `twinmesh up` and is then SIGKILLed leaves
    nothing running: no `up`, none of its processes, no port held; also a test run started under `nohup`
    (hang-ups ignored), whose labs `up` would otherwise take for detached on purpose."""
    import signal
    import sys

    import psutil

    def like_nohup() -> None:
        signal.signal(signal.SIGHUP, signal.SIG_IGN)

    starter = subprocess.Popen([sys.executable, "-c", STARTER.format(tests=str(REPO / "tests"), tmp=str(tmp_path))],
                               stdout=subprocess.PIPE, text=True, cwd=REPO,
                               preexec_fn=like_nohup if hangups == "ignored" else None)
    try:
        line = starter.stdout.readline()
        assert line.strip().isdigit(), f"the starter printed {line!r}"
        up = psutil.Process(int(line))
        lab = [up, *up.children(recursive=True)]
        assert len(lab) >= 3, "up, its router and the lights run"
    finally:
        starter.send_signal(signal.SIGKILL)
        starter.wait()
    gone, alive = psutil.wait_procs(lab, timeout=20)
    assert not alive, f"left behind after the starter was killed: {[(p.pid, p.name()) for p in alive]}"


def test_up_can_be_asked_to_outlive_its_starter(tmp_path):
    import signal
    import sys

    import psutil
    from labs import free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    script = ("import subprocess, sys; p = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, "
              "stderr=subprocess.DEVNULL, start_new_session=True); print(p.pid, flush=True)")
    out = subprocess.run([sys.executable, "-c", script, *twinmesh_cmd(endpoint, "up", "lights", "--no-http",
                                                                         "--no-view", "--outlive-parent")],
                         capture_output=True, text=True, cwd=REPO, timeout=60)
    up = psutil.Process(int(out.stdout.strip()))  # its starter has ended already
    try:
        ready = subprocess.run(twinmesh_cmd(endpoint, "wait", "--timeout", "120"), capture_output=True, text=True,
                               cwd=REPO, timeout=150)
        assert ready.returncode == 0 and up.is_running(), ready.stderr
    finally:
        up.send_signal(signal.SIGINT)
        up.wait(30)

def _children(pid: int) -> list[int]:
    out = subprocess.run(["ps", "-o", "pid=", "--ppid", str(pid)], capture_output=True, text=True).stdout
    return [int(x) for x in out.split()]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
        return True
    except ProcessLookupError:
        return False


def test_no_lab_is_a_clear_message_not_a_traceback():
    from labs import free_port

    r = subprocess.run(twinmesh_cmd(f"tcp/127.0.0.1:{free_port()}", "read", "light-left", "lightState"),
                       capture_output=True, text=True, cwd=REPO, timeout=60)
    assert r.returncode == 3 and "no lab reachable" in r.stderr and "Traceback" not in r.stderr


@pytest.mark.parametrize("words, expected", [
    (["read", "light-l"], {"light-left"}),
    (["read", "light-left", ""], {"lightState", "lightColor"}),
    (["invoke", "light-left", "s"], {"switchOn", "switchOff", "setColor"}),
    (["subscribe", "light-left", ""], {"stateChanged"}),
])
def test_tab_completes_thing_and_affordance_names_from_the_lab(lab, words, expected):
    """bash: eval "$(_TWINMESH_COMPLETE=bash_source twinmesh)"; the names come from the running lab."""
    import os
    import sys
    from pathlib import Path

    line = ["twinmesh", "--connect", lab.endpoint, *words]
    env = {**os.environ, "_TWINMESH_COMPLETE": "bash_complete", "COMP_WORDS": " ".join(line),
           "COMP_CWORD": str(len(line) - 1)}
    r = subprocess.run([str(Path(sys.executable).with_name("twinmesh"))], env=env, capture_output=True, text=True,
                       timeout=60)
    offered = {item.split(",", 1)[1] for item in r.stdout.split()}
    assert offered == expected, (r.stdout, r.stderr)


def test_tab_completion_without_a_lab_offers_nothing_quickly():
    import os
    import sys
    from pathlib import Path

    from labs import free_port

    line = ["twinmesh", "--connect", f"tcp/127.0.0.1:{free_port()}", "read", ""]
    env = {**os.environ, "_TWINMESH_COMPLETE": "bash_complete", "COMP_WORDS": " ".join(line), "COMP_CWORD": "4"}
    r = subprocess.run([str(Path(sys.executable).with_name("twinmesh"))], env=env, capture_output=True, text=True,
                       timeout=30)
    assert r.returncode == 0 and r.stdout.strip() == "" and "Traceback" not in r.stderr
