"""`twinmesh bridge`: the real lab's Things on the mesh, proven against a mock of the real lab.

The mock (tests/interop/real-lab.mjs) is node-wot servients exposing the real lab's TDs as they are
(basic authentication, hrefs that are not the affordance names, MQTT forms beside the https ones,
long-poll events) and logging every request it receives: what reached the "real" device is read
from that log, not from the bridge's own account.
"""
from __future__ import annotations

import json
import subprocess
from pathlib import Path

import httpx
import pytest
from interop import npm
from waiting import eventually

pytestmark = [pytest.mark.lab, pytest.mark.interop, pytest.mark.timeout(600)]

CREDENTIALS = {"username": "lab", "password": "real:lab pass"}
AUTH = f"basic:{CREDENTIALS['username']}:{CREDENTIALS['password']}"
NAMES = {"uarm": "Uarm", "dobot": "WarehouseDobot", "belt-1": "ConveyorBelt1", "belt-2": "ConveyorBelt2",
         "ir-1": "InfraredSensor1", "ir-2": "InfraredSensor2", "color": "ColorSensor"}
REAL_TDS = Path(__file__).parent / "data" / "reference-tds" / "real-lab"
# a valid input for each action of the real TDs that takes one
INPUTS = {("uarm", "goTo"): {"x": 140, "y": 20, "z": 60}, ("uarm", "go"): {"x": 150, "y": -20, "z": 70, "speed": 1000},
          ("uarm", "beepWithTime"): 2, ("uarm", "turnRight"): {"y": 0}}


@pytest.fixture(scope="module")
def real_lab():
    with npm.RealLab(CREDENTIALS) as lab:
        yield lab


@pytest.fixture(scope="module")
def lab(lights):
    return lights  # the session's lights lab, lent to this module (conftest.py)


@pytest.fixture(scope="module")
def bridge(lab, real_lab):
    log = lab.log.parent / "bridge.log"
    process = lab.spawn("bridge", *[f"{name}={real_lab.url(td)}" for name, td in NAMES.items()], "--auth", AUTH,
                        "--poll", "0.5", log=log)
    lab.wait_things(set(NAMES))
    yield process
    assert process.poll() is None, f"the bridge died:\n{log.read_text()[-3000:]}"


def real_td(name: str) -> dict:
    return json.loads((REAL_TDS / f"{NAMES[name]}.json").read_text())


def without_forms(affordance: dict) -> dict:
    return {k: v for k, v in affordance.items() if k != "forms"}


def test_bridged_things_are_listed_and_served_with_the_remote_affordances(lab, bridge):
    listed = lab.cli("things").stdout.split()
    assert set(NAMES) <= set(listed) and "light-left" in listed
    for name in NAMES:
        served = httpx.get(f"{lab.http}/{name}", timeout=10).json()
        real = real_td(name)
        for kind in ("properties", "actions", "events"):
            assert sorted(served.get(kind, {})) == sorted(real.get(kind, {})), (name, kind)
            for affordance, described in real.get(kind, {}).items():
                ours = served[kind][affordance]
                for term, value in without_forms(described).items():
                    if term in ("readOnly", "writeOnly", "synchronous"):
                        continue  # what the bridge can truly do (no http write form: readOnly)
                    assert keeps(ours[term], value), (name, kind, affordance, term, ours[term], value)
                hrefs = [f["href"] for f in ours["forms"]]
                assert all(h.startswith(f"{lab.http}/{name}/") for h in hrefs), hrefs  # our forms, never MQTT


def test_every_affordance_reaches_the_remote_through_its_own_forms_with_the_credentials(lab, bridge, real_lab):
    real_lab.clear_log()
    expected_paths = set()
    for name in NAMES:
        real = real_td(name)
        for prop, p in real.get("properties", {}).items():
            r = httpx.get(f"{lab.http}/{name}/properties/{prop}", timeout=30)
            assert r.status_code == 200, (name, prop, r.text)
            expected_paths.add(_path(p, "readproperty"))
        for action, a in real.get("actions", {}).items():
            body = INPUTS.get((name, action))
            r = httpx.post(f"{lab.http}/{name}/actions/{action}", json=body, timeout=60) if body is not None else \
                httpx.post(f"{lab.http}/{name}/actions/{action}", timeout=60)
            assert r.status_code in (200, 204), (name, action, r.text)
            expected_paths.add(_path(a, "invokeaction"))
    r = httpx.put(f"{lab.http}/belt-1/properties/speed", json=35, timeout=30)
    assert r.status_code == 204, r.text
    assert httpx.get(f"{lab.http}/belt-1/properties/speed", timeout=30).json() == 35

    requests = real_lab.requests()
    assert requests and all(r["authorized"] for r in requests), [r for r in requests if not r["authorized"]]
    assert expected_paths <= {r["path"] for r in requests}
    assert "/uarm/actions/goto" in {r["path"] for r in requests}  # the form's href, not the name goTo
    calls = {(c["thing"], c["affordance"]) for c in real_lab.calls()}
    for name in NAMES:
        for action in real_td(name).get("actions", {}):
            assert (real_td(name)["title"], action) in calls, (name, action)
    go_to = real_lab.calls("Uarm", "goTo")[-1]
    assert go_to["input"] == INPUTS[("uarm", "goTo")]
    # goTo put it at (140, 20, 60); turnLeft and turnRight, last, moved it 10 mm and back
    assert httpx.get(f"{lab.http}/uarm/properties/location", timeout=30).json() == {"x": 140, "y": 20, "z": 60}


def keeps(served, original) -> bool:
    """Every term of `original` is in `served` with its value, at every depth (the adapter may add a
    `type` a schema left implicit, as it does for every Thing)."""
    if isinstance(original, dict):
        return isinstance(served, dict) and all(k in served and keeps(served[k], v) for k, v in original.items())
    return served == original


def _path(affordance: dict, op: str) -> str:
    for form in affordance["forms"]:
        ops = form.get("op", [])
        if form["href"].startswith("https:") and op in ([ops] if isinstance(ops, str) else ops):
            return httpx.URL(form["href"]).path
    raise LookupError(op)


def test_a_bad_input_is_400_and_never_reaches_the_remote(lab, bridge, real_lab):
    real_lab.clear_log()
    r = httpx.post(f"{lab.http}/uarm/actions/goTo", json={"x": 500, "y": 0, "z": 60}, timeout=30)
    assert r.status_code == 400 and r.headers["content-type"].startswith("application/problem+json")
    assert "maximum" in r.json()["detail"]
    assert real_lab.calls("Uarm") == []
    assert not any(q["method"] == "POST" for q in real_lab.requests())  # the bridge's polls are GETs


def toggle_until_seen(real_lab, sensor: str, follower: subprocess.Popen) -> None:
    """Toggle the remote sensor's objectPresence until `follower` (a `twinmesh subscribe --count 1`) has
    seen an event and exited: no guess at when its subscription is declared or the bridge's feed is back."""
    values = iter([True, False] * 1000)

    def seen() -> bool:
        httpx.put(f"{real_lab.base}/{sensor}/properties/objectPresence", json=next(values),
                  auth=(CREDENTIALS["username"], CREDENTIALS["password"]), timeout=10).raise_for_status()
        return follower.poll() is not None
    eventually(seen, timeout=60, interval=0.2, what=f"an event of {sensor} through the bridge")


def test_events_and_changes_of_the_remote_reach_the_mesh(lab, bridge, real_lab):
    follower = subprocess.Popen(lab.cli_args("subscribe", "ir-1", "detectedObject", "--count", "1"),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        toggle_until_seen(real_lab, "InfraredSensor1", follower)  # from before its subscription is declared
        out, err = follower.communicate(timeout=60)
    finally:
        follower.kill()
    assert json.loads(out.splitlines()[0]) in (True, False), err


def test_refused_credentials_are_502_naming_them_never_a_raw_401(lab, bridge, real_lab):
    real_lab.kill()
    other = npm.RealLab({"username": "lab", "password": "changed"}, port=real_lab.port).start()
    try:
        r = httpx.get(f"{lab.http}/uarm/properties/location", timeout=30)
        assert r.status_code == 502, r.text
        problem = r.json()
        assert "credentials" in problem["detail"] and "--auth" in problem["detail"]
        assert problem["reason"] == "remote-credentials"
    finally:
        other.kill()
        real_lab.start()


def test_a_remote_that_stops_answering_is_503_until_it_is_back(lab, bridge, real_lab):
    real_lab.kill()
    try:
        r = httpx.post(f"{lab.http}/uarm/actions/goTo", json=INPUTS[("uarm", "goTo")], timeout=30)
        assert r.status_code == 503, r.text
        assert r.json()["reason"] == "remote-unavailable"
        assert httpx.get(f"{lab.http}/belt-1/properties/speed", timeout=30).status_code == 503
        assert httpx.get(f"{lab.http}/light-left/properties/lightState", timeout=30).status_code == 200
    finally:
        real_lab.start()
    assert bridge.poll() is None
    r = httpx.post(f"{lab.http}/uarm/actions/goTo", json=INPUTS[("uarm", "goTo")], timeout=30)
    assert r.status_code == 204, r.text
    assert real_lab.calls("Uarm", "goTo")[-1]["input"] == INPUTS[("uarm", "goTo")]
    # the long-poll event feed subscribed again by itself
    follower = subprocess.Popen(lab.cli_args("subscribe", "ir-2", "detectedObject", "--count", "1"),
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        toggle_until_seen(real_lab, "InfraredSensor2", follower)
        out, err = follower.communicate(timeout=10)
    finally:
        follower.kill()
    assert out.strip() in ("true", "false"), err


def test_bad_bridge_commands_say_what_is_wrong_and_start_nothing(lab, real_lab):
    wrong = lab.cli("bridge", f"x={real_lab.url('Uarm')}", "--auth", "basic:lab:wrong", timeout=60)
    assert wrong.returncode == 2 and "credentials" in wrong.stderr and "--auth" in wrong.stderr, wrong.stderr
    nobody = lab.cli("bridge", "x=http://127.0.0.1:9/td", timeout=60)
    assert nobody.returncode == 3 and "cannot connect" in nobody.stderr, nobody.stderr
    taken = lab.cli("bridge", f"light-left={real_lab.url('Uarm')}", "--auth", AUTH, timeout=60)
    assert taken.returncode == 1 and "light-left" in taken.stderr and "already" in taken.stderr, taken.stderr
    malformed = lab.cli("bridge", "Not A Name=http://x", timeout=60)
    assert malformed.returncode == 2 and "slug" in malformed.stderr, malformed.stderr
    both = lab.cli("bridge", f"x={real_lab.url('Uarm')}", "--ca", __file__, "--insecure", timeout=60)
    assert both.returncode == 2 and "contradict" in both.stderr
    assert "x" not in lab.cli("things").stdout.split()


def self_signed(tmp: Path) -> tuple[Path, Path]:
    """A key and a self-signed certificate for the bare IP address 127.0.0.1 (as the real lab's devices have)."""
    import datetime
    import ipaddress

    from cryptography import x509
    from cryptography.hazmat.primitives import hashes, serialization
    from cryptography.hazmat.primitives.asymmetric import ec
    from cryptography.x509.oid import NameOID

    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "real lab device")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
            .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(days=1))
            .not_valid_after(now + datetime.timedelta(days=30))
            .add_extension(x509.SubjectAlternativeName([x509.IPAddress(ipaddress.ip_address("127.0.0.1"))]), False)
            .add_extension(x509.BasicConstraints(ca=True, path_length=None), True)
            .sign(key, hashes.SHA256()))
    key_file, cert_file = tmp / "device-key.pem", tmp / "device.pem"
    key_file.write_bytes(key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                                           serialization.NoEncryption()))
    cert_file.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key_file, cert_file


def test_https_to_a_bare_ip_address_needs_its_ca_or_a_loud_insecure(lab, tmp_path):
    key, cert = self_signed(tmp_path)
    with npm.RealLab(CREDENTIALS, tls=(key, cert)) as secure:
        url = secure.url("ColorSensor")
        assert url.startswith("https://127.0.0.1:")
        untrusted = lab.cli("bridge", f"color-tls={url}", "--auth", AUTH, timeout=60)
        assert untrusted.returncode == 2, untrusted.stderr
        assert "not trusted" in untrusted.stderr and "--ca" in untrusted.stderr, untrusted.stderr
        with_ca = lab.spawn("bridge", f"color-tls={url}", "--auth", AUTH, "--ca", str(cert))
        try:
            lab.wait_things({"color-tls"})
            assert httpx.get(f"{lab.http}/color-tls/properties/lux", timeout=30).json() == 1200
        finally:
            with_ca.terminate()
            with_ca.wait(timeout=30)
        insecure = subprocess.Popen(lab.cli_args("bridge", f"color-tls2={url}", "--auth", AUTH, "--insecure"),
                                    stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        try:
            lab.wait_things({"color-tls2"})
            assert httpx.get(f"{lab.http}/color-tls2/properties/temperature", timeout=30).json() == 4500
        finally:
            insecure.terminate()
            _, err = insecure.communicate(timeout=30)
        assert "WARNING" in err and "NOT checked" in err
