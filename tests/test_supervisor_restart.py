"""A crashed part of a lab is started again while the rest keep serving; one that keeps crashing stops the lab.

A real `twinmesh up lights`: the lights' process is killed with SIGKILL (found in `ps` by its title,
`twinmesh: lights`), its Things leave and come back (in the scene's initial state), and the adapter,
router and tdgen keep their processes; then every part in turn (tdgen, recorder, adapter, lights,
router). Killed five times within a minute, the lab stops and says why.
"""
from __future__ import annotations

import os
import signal
import time

import httpx
import psutil
import pytest
from labs import start_lab

pytestmark = pytest.mark.lab


def _lights_process(lab, not_pid: int | None = None) -> psutil.Process | None:
    """The lab's `twinmesh: lights` child (its title, as `ps` shows it), other than `not_pid`; None when
    the lab has ended."""
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline and lab.proc.poll() is None:
        for child in psutil.Process(lab.proc.pid).children(recursive=True):
            try:
                if child.pid != not_pid and child.status() != psutil.STATUS_ZOMBIE and \
                        "twinmesh: lights" in " ".join(child.cmdline()):
                    return child
            except psutil.Error:  # gone, or a zombie, while we looked
                continue
        time.sleep(0.1)
    if lab.proc.poll() is None:
        raise AssertionError("no `twinmesh: lights` process under the lab")
    return None


def _reads(lab) -> bool:
    try:
        return httpx.get(f"{lab.http}/light-left/properties/lightState", timeout=2).status_code == 200
    except httpx.HTTPError:
        return False


@pytest.fixture
def lab(tmp_path):
    lab = start_lab(tmp_path, "lights", things={"light-left", "light-right", "tdgen"})
    yield lab
    lab.stop()


def test_a_killed_device_process_is_started_again_and_the_rest_keep_serving(lab):
    others = {p.pid for p in psutil.Process(lab.proc.pid).children(recursive=True)}
    victim = _lights_process(lab)
    os.kill(victim.pid, signal.SIGKILL)
    gone = time.monotonic()
    while _reads(lab) and time.monotonic() - gone < 5:  # it leaves: 503 meanwhile
        time.sleep(0.05)
    assert httpx.get(f"{lab.http}/things").status_code == 200  # the adapter serves on
    deadline = time.monotonic() + 30
    while not _reads(lab):
        assert time.monotonic() < deadline, lab.log.read_text()[-3000:]
        time.sleep(0.1)
    print(f"\nlights back {time.monotonic() - gone:.2f} s after SIGKILL")
    assert _lights_process(lab).pid != victim.pid and lab.proc.poll() is None
    still = {p.pid for p in psutil.Process(lab.proc.pid).children(recursive=True)}
    assert (others - {victim.pid}) <= still, "only the killed process was replaced"
    assert "process lights exited (code -9); starting it again" in lab.log.read_text()


def test_a_process_that_keeps_crashing_stops_the_lab_with_the_reason(lab):
    victim = _lights_process(lab)
    kills = 0
    while victim is not None:
        os.kill(victim.pid, signal.SIGKILL)
        kills += 1
        victim = _lights_process(lab, not_pid=victim.pid)  # started again, or the lab gave up
    lab.proc.wait(timeout=30)
    assert kills == 5 and lab.proc.returncode != 0
    assert "its 5th crash within 60 s; stopping the lab" in lab.log.read_text()


def test_a_killed_router_is_started_again_and_one_shot_commands_find_the_lab(lab):
    router = next(c for c in psutil.Process(lab.proc.pid).children() if "twinmesh: router" in " ".join(c.cmdline()))
    os.kill(router.pid, signal.SIGKILL)
    deadline = time.monotonic() + 30
    while True:  # a one-shot command connects to the router's endpoint: it answers once the router is back
        done = lab.cli("read", "light-left", "lightState", timeout=20)
        if done.returncode == 0:
            break
        assert time.monotonic() < deadline, done.stderr
        time.sleep(0.2)
    assert httpx.put(f"{lab.http}/light-left/properties/lightState", json=True).status_code == 204
    assert lab.cli("read", "light-left", "lightState").stdout.strip() == "true"
    assert "process router exited (code -9); starting it again" in lab.log.read_text()


def _child_titled(lab, title: str, not_pid: int | None = None, timeout: float = 30) -> psutil.Process:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        for child in psutil.Process(lab.proc.pid).children():
            try:
                if child.pid != not_pid and child.status() != psutil.STATUS_ZOMBIE and \
                        " ".join(child.cmdline()).startswith(f"twinmesh: {title}"):
                    return child
            except psutil.Error:
                continue
        time.sleep(0.1)
    raise AssertionError(f"no `twinmesh: {title}` process under the lab\n{lab.log.read_text()[-3000:]}")


@pytest.fixture
def recorded_lab(tmp_path):
    lab = start_lab(tmp_path, "lights", things={"light-left", "light-right", "tdgen"},
                    extra_args=("--record", str(tmp_path / "lab.rrd")))
    yield lab
    lab.stop()


def test_each_part_killed_in_turn_comes_back_and_the_others_keep_their_processes(recorded_lab):
    lab = recorded_lab
    for title in ("tdgen", "recorder", "adapter", "lights", "router"):
        victim = _child_titled(lab, title)
        others = {p.pid for p in psutil.Process(lab.proc.pid).children()} - {victim.pid}
        os.kill(victim.pid, signal.SIGKILL)
        _child_titled(lab, title, not_pid=victim.pid)  # started again
        deadline = time.monotonic() + 30
        while not (_reads(lab) and {"tdgen", "light-left", "light-right"} <= set(lab.cli("things").stdout.split())):
            assert time.monotonic() < deadline, f"{title}: the lab did not recover\n{lab.log.read_text()[-3000:]}"
            time.sleep(0.2)
        assert others <= {p.pid for p in psutil.Process(lab.proc.pid).children()}, f"{title}: others were replaced"
        assert f"process {title} exited (code -9); starting it again" in lab.log.read_text()
    assert lab.proc.poll() is None


def test_a_restarted_device_process_starts_from_its_scenes_initial_state(lab):
    assert httpx.put(f"{lab.http}/light-left/properties/lightState", json=True).status_code == 204
    victim = _lights_process(lab)
    os.kill(victim.pid, signal.SIGKILL)
    deadline = time.monotonic() + 30
    while not _reads(lab):
        assert time.monotonic() < deadline, lab.log.read_text()[-3000:]
        time.sleep(0.1)
    assert httpx.get(f"{lab.http}/light-left/properties/lightState").json() is False  # the scene's initial state
