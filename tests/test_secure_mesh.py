"""`--secure`: a lab whose mesh keeps strangers out and whose Things cannot be hijacked.

A real `twinmesh up lights --secure` (TLS with mutual authentication, access control on the
router, a bearer token on HTTP); the attempts are real Zenoh sessions: plain, with TLS but no
certificate, with the consumer's credential, with a device's credential. After every refused
attempt the lights' state is checked unchanged and `/things` lists nothing new.
"""
from __future__ import annotations

import json
import os
import stat
import subprocess
import time
from contextlib import ExitStack

import httpx
import msgspec
import pytest
import zenoh

from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.session import open_session
from mesh.fabric.settings import MeshSettings
from tests.labs import Lab, start_lab, stop_process, twinmesh_cmd
from tests.waiting import always

pytestmark = [pytest.mark.lab, pytest.mark.timeout(600)]


@pytest.fixture(scope="module")
def secure(tmp_path_factory) -> tuple[Lab, str]:
    tmp = tmp_path_factory.mktemp("secure")
    secrets = str(tmp / "secrets")
    lab = start_lab(tmp, "lights", options=("--secrets", secrets), things={"light-left", "light-right", "tdgen"})
    yield lab, secrets
    lab.stop()


def _token(secrets: str) -> dict[str, str]:
    with open(os.path.join(secrets, "http-token")) as f:
        return {"Authorization": f"Bearer {f.read().strip()}"}


def _state(lab: Lab, secrets: str, thing: str = "light-left") -> object:
    r = httpx.get(f"{lab.http}/{thing}/properties/lightState", headers=_token(secrets), timeout=10)
    assert r.status_code == 200, r.text
    return r.json()


def _listed(lab: Lab) -> set[str]:
    return {td["title"] for td in httpx.get(f"{lab.http}/things", timeout=10).json()}


def _plain(endpoint: str, mode: str = "client", tls_without_certificate: str | None = None):
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")
    c.insert_json5("connect/endpoints", json.dumps([endpoint]))
    if tls_without_certificate:
        c.insert_json5("transport/link/tls", json.dumps({"root_ca_certificate": tls_without_certificate}))
    return c


def _hijack(session, prefix: str = "wot") -> list:
    """Everything a stranger would try: serve light-left's state and TD, announce a fake Thing, publish."""
    held = [session.declare_queryable(f"{prefix}/light-left/properties/lightState",
                                      lambda q: q.reply(q.key_expr, b"true")),
            session.declare_queryable(f"{prefix}/fake/td", lambda q: q.reply(q.key_expr, b'{"title": "fake"}')),
            session.liveliness().declare_token(f"{prefix}/fake"),
            session.liveliness().declare_token(f"{prefix}/light-left")]
    session.put(f"{prefix}/light-left/properties/lightState", b"true")
    session.put(f"{prefix}/light-left/td", b'{"title": "hijacked"}')
    return held


def test_the_lab_says_it_is_secure_and_keeps_its_secrets_to_its_owner(secure):
    lab, secrets = secure
    assert "secure (secrets in" in lab.log.read_text() and "on Zenoh tls/" in lab.log.read_text()
    assert stat.S_IMODE(os.stat(secrets).st_mode) == 0o700
    for root, _, files in os.walk(secrets):
        for name in files:
            assert stat.S_IMODE(os.stat(os.path.join(root, name)).st_mode) == 0o600, name


def test_http_without_the_token_is_refused_and_the_td_says_what_to_send(secure):
    lab, secrets = secure
    r = httpx.get(f"{lab.http}/light-left/properties/lightState")
    assert r.status_code == 401
    td = httpx.get(f"{lab.http}/light-left").json()
    assert any(d.get("scheme") == "bearer" for d in td["securityDefinitions"].values())
    assert _state(lab, secrets) in (True, False)


def test_without_credentials_a_zenoh_session_gets_nothing_and_changes_nothing(secure):
    lab, secrets = secure
    before = _state(lab, secrets)
    tcp = lab.endpoint  # the lab listens on tls/ at this address
    tls = "tls/" + tcp.removeprefix("tcp/")
    for endpoint in (tcp, tls):  # plain TCP to a TLS port; TLS without a certificate of the lab's CA
        with pytest.raises(zenoh.ZError):
            zenoh.open(_plain(endpoint, tls_without_certificate=os.path.join(secrets, "ca.pem")
                              if endpoint == tls else None))
    # a peer opens alone (peers need no link) and is heard by nobody
    with zenoh.open(_plain(tls, mode="peer", tls_without_certificate=os.path.join(secrets, "ca.pem"))) as peer:
        assert [r for r in peer.get("wot/light-left/properties/lightState", timeout=1) if r.ok] == []
        assert [r for r in peer.get("wot/light-left/actions/switchOn", payload=b"", timeout=1) if r.ok] == []
        held = _hijack(peer)
        always(lambda: "fake" not in _listed(lab) and _state(lab, secrets) == before, 1.0,
               what="nothing the lone peer declared is heard")
        for h in held:
            h.undeclare()


def test_a_consumer_reads_and_invokes_but_cannot_hijack_a_thing(secure):
    lab, secrets = secure
    settings = MeshSettings(connect=(lab.endpoint,), secrets=secrets)
    # the consumer's credential (the default role); another consumer's view decides: the hijacker's own
    # session may well hear its own queryable, which fools nobody else
    with open_session(settings) as session, open_session(settings) as others:
        client, other = MeshClient(session, settings), MeshClient(others, settings)
        client.invoke("light-left", "switchOff")
        assert client.read("light-left", "lightState") is False
        held = _hijack(session)
        always(lambda: other.read("light-left", "lightState") is False and _state(lab, secrets) is False, 1.0,
               what="the consumer's hijack changes nothing for anyone else")
        assert "fake" not in _listed(lab) and "hijacked" not in json.dumps(httpx.get(f"{lab.http}/light-left").json())
        client.invoke("light-left", "switchOn")
        assert _state(lab, secrets) is True
        for h in held:
            h.undeclare()


def test_a_device_serves_its_own_keys_only(secure):
    lab, secrets = secure
    settings = MeshSettings(connect=(lab.endpoint,), secrets=secrets)
    before = _state(lab, secrets, "light-right")
    with ExitStack() as stack:
        # light-left's own credential (a second process holding it): it may not speak for light-right
        session = stack.enter_context(open_session(settings, thing="light-left"))
        stack.callback(lambda: [h.undeclare() for h in held])
        held = [session.declare_queryable("wot/light-right/properties/lightState",
                                          lambda q: q.reply(q.key_expr, msgspec.json.encode(not before))),
                session.liveliness().declare_token("wot/impostor")]
        consumer = stack.enter_context(open_session(settings))

        def replies() -> list[bytes]:
            return [r.ok.payload.to_bytes() for r in consumer.get("wot/light-right/properties/lightState", timeout=2)
                    if r.ok]

        # the real light alone answers, while the impostor's declarations reach the router and after
        always(lambda: replies() == [msgspec.json.encode(before)], 1.0, what="light-right answered by itself alone")
        assert "impostor" not in _listed(lab)


def test_the_cli_finds_the_credentials_and_works(secure):
    lab, _ = secure
    assert lab.cli("write", "light-right", "lightState", "true").returncode == 0
    assert lab.cli("read", "light-right", "lightState").stdout.strip() == "true"
    assert {"light-left", "light-right", "tdgen"} <= set(lab.cli("things").stdout.split())
    # without --secure, a command finds this account's secrets by itself (XDG_DATA_HOME/twinmesh/secrets)...
    home = lab.log.parent / "xdg"
    (home / "twinmesh").mkdir(parents=True, exist_ok=True)
    if not (home / "twinmesh" / "secrets").exists():
        (home / "twinmesh" / "secrets").symlink_to(os.path.abspath(secrets_of(lab)))
    env = {k: v for k, v in os.environ.items() if not k.startswith("TWINMESH_")}
    found = subprocess.run(twinmesh_cmd(lab.endpoint, "read", "light-right", "lightState"), capture_output=True,
                           text=True, timeout=60, env={**env, "XDG_DATA_HOME": str(home)})
    assert found.returncode == 0 and found.stdout.strip() == "true", found.stderr
    # ... and where this account has none, it says what to do
    plain = subprocess.run(twinmesh_cmd(lab.endpoint, "read", "light-right", "lightState"), capture_output=True,
                           text=True, timeout=60, env={**env, "XDG_DATA_HOME": str(lab.log.parent / "empty")})
    assert plain.returncode != 0 and "--secure" in plain.stderr


def secrets_of(lab: Lab) -> str:
    return lab.options[lab.options.index("--secrets") + 1]


def test_a_robot_started_later_gets_its_credential_and_is_served(secure):
    lab, secrets = secure
    log = lab.log.parent / "secure-robot.log"
    robot = lab.spawn("robot", "ur10.urdf", "--name", "ur10-secure", "--samples", "300", "--speed", "max", log=log)
    try:
        deadline = time.monotonic() + 120
        while "ur10-secure" not in _listed(lab):
            assert time.monotonic() < deadline, log.read_text()[-3000:] + lab.log.read_text()[-3000:]
            time.sleep(0.5)
        assert os.path.exists(os.path.join(secrets, "devices", "ur10-secure.pem"))
        r = httpx.get(f"{lab.http}/ur10-secure/properties/getJointposition", headers=_token(secrets), timeout=30)
        assert r.status_code == 200, r.text
        assert _state(lab, secrets, "light-left") in (True, False)  # the lab serves on after the router's reload
    finally:
        stop_process(robot)
