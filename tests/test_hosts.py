"""One lab across hosts: Linux network namespaces joined by a bridge, a lab on the first, `up --join` on others.

Each joining host runs a gateway (`up SCENE --join ENDPOINT`): one client of the lab's router for the
whole host, the host's devices a region south of it (Zenoh's regions). Skipped, with the reason, where
network namespaces cannot be created (they need root).
"""
from __future__ import annotations

import sys
import time
from pathlib import Path

import httpx
import pytest

from devices.things.fleet import fleet_names
from tests import netns

WHY_NOT = netns.unavailable()
pytestmark = [pytest.mark.lab, pytest.mark.skipif(WHY_NOT is not None, reason=f"network namespaces: {WHY_NOT}"),
              pytest.mark.timeout(600)]

TWINMESH = [sys.executable, "-m", "devices"]
HANG = 60.0  # s: only detects a hang; how fast a cut is seen is printed here and measured in tests/bench
# s after a cut during which the first host's own Things must keep answering: B's dead links are seen
# (1.5 s lease) and closed, which takes Zenoh up to 10 s more (a TCP linger; see ROUTER_RUNTIME)
SEEN_THROUGH = 15.0


def _listed(base: str) -> set[str]:
    try:
        return {u.rstrip("/").rsplit("/", 1)[-1] for u in httpx.get(base + "/", timeout=5).json()}
    except (httpx.HTTPError, ValueError):
        return set()


def _until(what: str, check, log: Path | None = None, timeout: float = HANG) -> float:
    """Seconds until `check()` holds (an AssertionError naming `what` after `timeout`)."""
    start = time.monotonic()
    while time.monotonic() - start < timeout:
        if check():
            return time.monotonic() - start
        time.sleep(0.1)
    raise AssertionError(f"{what} not within {timeout:.0f} s" + (f"\n{log.read_text()[-3000:]}" if log else ""))


def _lab(host: netns.Host, tmp: Path, *args: str) -> tuple[str, str, Path]:
    """`twinmesh up` on `host`, its router and adapter on the host's address; (endpoint, base URL, log)."""
    endpoint, base = f"tcp/{host.address}:7447", f"http://{host.address}:8080"
    log = tmp / f"{host.name}-lab.log"
    host.popen([*TWINMESH, "--connect", endpoint, "up", *args, "--http", f"{host.address}:8080", "--no-view"], log)
    return endpoint, base, log


def _why_unlisted(base: str, missing: set[str], log: Path) -> str:
    """What the adapter answers for Things it does not list, and what its log says of them."""
    lines = [f"{len(missing)} not listed: {sorted(missing)[:20]}"]
    text = log.read_text(errors="replace")
    for name in sorted(missing)[:5]:
        try:
            r = httpx.get(f"{base}/{name}", timeout=10)
            lines.append(f"GET /{name}: {r.status_code} {r.text[:200]}")
        except httpx.HTTPError as e:
            lines.append(f"GET /{name}: {e!r}")
        lines += [f"  log: {line}" for line in text.splitlines() if name in line][-5:]
    return "\n".join(lines + ["lab log tail:", text[-2000:]])


def _ready(log: Path, what: str) -> None:
    _until(f"{what} ready", lambda: " ready" in log.read_text(errors="replace"), log, timeout=300)


def test_a_second_host_joins_a_lab_its_things_are_driven_from_the_first_and_a_cut_link_is_seen(tmp_path):
    with netns.hosts(2) as net:
        a, b = net.hosts
        endpoint, base, lab_log = _lab(a, tmp_path, "fleet", "--fleet", "5")
        _ready(lab_log, "the lab on host A")
        join_log = tmp_path / "b-lights.log"
        joined = b.popen([*TWINMESH, "up", "lights", "--join", endpoint], join_log)
        robot_log = tmp_path / "b-robot.log"  # a robot on B linked straight to A's router
        b.popen([*TWINMESH, "robot", "ur10.urdf", "--name", "ur10", "--samples", "300", "--speed", "max",
                 "--join", endpoint], robot_log)
        _ready(join_log, "`up lights --join` on host B")
        assert "no adapter" not in join_log.read_text()
        _until("B's lights and robot listed by A's adapter",
               lambda: {"light-left", "light-right", "ur10", *fleet_names(5)} <= _listed(base), robot_log)

        # A's adapter drives B's Things: a light, the robot's joints
        assert httpx.put(f"{base}/light-left/properties/lightState", json=True, timeout=10).status_code == 204
        assert httpx.get(f"{base}/light-left/properties/lightState", timeout=10).json() is True
        joints = httpx.get(f"{base}/ur10/properties/getJointposition", timeout=10)
        assert joints.status_code == 200, joints.text
        # no router, adapter or tdgen on B: its gateway, the lights
        ps = b.run(["ps", "-o", "args=", "--ppid", str(joined.pid)]).stdout
        titles = sorted(line.split(":", 1)[1].strip().split()[0] for line in ps.splitlines() if line.startswith("twinmesh:"))
        assert titles == ["gateway", "lights"], ps

        net.cut(b)
        cut, gone, robot_gone, own = time.monotonic(), None, None, []
        while time.monotonic() - cut < SEEN_THROUGH:  # A's own Things keep serving while the dead links are closed
            own.append(httpx.get(f"{base}/light-1/properties/lightState", timeout=10).status_code)
            if gone is None and httpx.get(f"{base}/light-left/properties/lightState", timeout=10).status_code == 503:
                gone = time.monotonic() - cut
            if robot_gone is None and httpx.get(f"{base}/ur10/properties/getJointposition",
                                                timeout=10).status_code == 503:
                robot_gone = time.monotonic() - cut
            time.sleep(0.1)
        assert gone is not None and robot_gone is not None, f"B's Things still served {SEEN_THROUGH:.0f} s after the cut"
        assert set(own) == {200}, f"A's own light-1 during the cut: {sorted(set(own))} ({len(own)} reads)"
        assert "light-left" not in _listed(base) and "ur10" not in _listed(base)
        assert set(fleet_names(5)) <= _listed(base)  # A's own Things are still listed
        net.plug(b)
        back = _until("B's light back after the link returned",
                      lambda: httpx.get(f"{base}/light-left/properties/lightState", timeout=10).status_code == 200)
        assert httpx.get(f"{base}/light-left/properties/lightState", timeout=10).json() is True  # its state kept
        robot_back = _until("B's robot back after the link returned",
                            lambda: httpx.get(f"{base}/ur10/properties/getJointposition", timeout=10).status_code == 200)
        print(f"cut link: 503 after {gone:.2f} s (the robot: {robot_gone:.2f} s), A's light-1 answered all {len(own)} "
              f"reads meanwhile; link back: served again "
              f"after {back:.2f} s (the robot: {back + robot_back:.2f} s)")


@pytest.mark.parametrize("direct", [False, True], ids=["a-gateway-per-host", "direct"])
def test_four_hosts_make_one_fleet_that_joins_and_leaves_cleanly(tmp_path, direct):
    """Each joining host with its gateway, a client of the lab's router, or (`--direct`) none: its devices
    are clients of the lab's router."""
    per_host = 50
    with netns.hosts(4) as net:
        first, *others = net.hosts
        endpoint, base, lab_log = _lab(first, tmp_path, "fleet", "--fleet", str(per_host))
        _ready(lab_log, "the lab on host 1")
        logs, procs = [], []
        for i, host in enumerate(others, start=1):
            log = tmp_path / f"{host.name}-fleet.log"
            procs.append(host.popen([*TWINMESH, "up", "fleet", "--fleet", str(per_host), "--fleet-first",
                                     str(1 + i * per_host // 5), "--join", endpoint,
                                     *(["--direct"] if direct else [])], log))
            logs.append(log)
        for log in logs:
            _ready(log, "a joining fleet")
            assert ("linked straight to the lab's router" in log.read_text()) == direct
        ps = others[0].run(["ps", "-o", "args=", "--ppid", str(procs[0].pid)]).stdout
        assert ("twinmesh: gateway" in ps) != direct, ps
        everyone = {n for i in range(4) for n in fleet_names(per_host, 1 + i * per_host // 5)}
        assert len(everyone) == 4 * per_host
        try:
            _until("all 200 devices listed by the first host's adapter", lambda: everyone <= _listed(base))
        except AssertionError as e:
            raise AssertionError(f"{e}\n{_why_unlisted(base, everyone - _listed(base), lab_log)}") from None
        r = httpx.get(f"{base}/things?limit=50", timeout=30)
        assert r.status_code == 200 and 'rel="next"' in r.headers["link"]
        # a device of the last host answers through the first host's adapter
        last = fleet_names(per_host, 1 + 3 * per_host // 5)
        assert httpx.get(f"{base}/{last[-1]}/properties/humidity", timeout=10).status_code == 200

        # one host leaves (Ctrl-C): its devices leave the directory, the others stay
        from tests.labs import stop_process

        assert stop_process(procs[1], 30), "a joined fleet did not stop on Ctrl-C"
        assert procs[1].returncode == 0
        leaving = set(fleet_names(per_host, 1 + 2 * per_host // 5))
        _until("the leaving host's devices gone from the directory", lambda: not leaving & _listed(base))
        assert everyone - leaving <= _listed(base)
        for p in (procs[0], procs[2]):
            assert stop_process(p, 30) and p.returncode == 0
        _until("only the first host's devices left", lambda: _listed(base) - {"tdgen"} == set(fleet_names(per_host)))


def test_a_secure_lab_across_two_hosts_admits_only_holders_of_its_secrets(tmp_path):
    import shutil

    secrets_a, secrets_b = tmp_path / "secrets-a", tmp_path / "secrets-b"
    with netns.hosts(2) as net:
        a, b = net.hosts
        endpoint, base, lab_log = f"tcp/{a.address}:7447", f"http://{a.address}:8080", tmp_path / "a.log"
        a.popen([*TWINMESH, "--secrets", str(secrets_a), "--connect", endpoint, "up", "fleet", "--fleet", "5",
                 "--http", f"{a.address}:8080", "--no-view"], lab_log)
        _ready(lab_log, "the secure lab on host A")
        assert f"on Zenoh tls/{a.address}:7447" in lab_log.read_text()
        shutil.copytree(secrets_a, secrets_b)  # what an engineer copies to the second host
        join_log = tmp_path / "b.log"
        b.popen([*TWINMESH, "--secrets", str(secrets_b), "up", "lights", "--join", endpoint], join_log)
        _ready(join_log, "the secure join on host B")
        _until("B's lights listed by A's adapter", lambda: {"light-left", "light-right"} <= _listed(base), join_log)
        token = {"Authorization": f"Bearer {(secrets_a / 'http-token').read_text().strip()}"}
        assert httpx.put(f"{base}/light-left/properties/lightState", json=True, headers=token).status_code == 204
        assert httpx.get(f"{base}/light-left/properties/lightState", headers=token).json() is True
        assert httpx.get(f"{base}/light-left/properties/lightState").status_code == 401

        # a peer without the lab's secrets, on host B, reaches neither router
        stranger = tmp_path / "stranger.py"
        stranger.write_text(f"""
import json, zenoh
for endpoint in ("{endpoint}", "tls/{a.address}:7447", "tls/127.0.0.1:7447"):
    c = zenoh.Config()
    c.insert_json5("mode", '"client"')
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    c.insert_json5("transport/link/tls", json.dumps({{"root_ca_certificate": "{secrets_a / 'ca.pem'}"}}))
    try:
        zenoh.open(c)
        print("CONNECTED", endpoint)
    except zenoh.ZError:
        print("refused", endpoint)
""")
        out = b.run([sys.executable, str(stranger)]).stdout
        assert out.count("refused") == 3 and "CONNECTED" not in out, out
        assert httpx.get(f"{base}/light-left/properties/lightState", headers=token).json() is True
