"""Optional security: `--auth bearer:TOKEN` on `twinmesh up`, `TWINMESH_HTTP_AUTH=basic:...` on
`twinmesh adapter`. Affordances need the credentials (401 problem+json with WWW-Authenticate
otherwise); the TDs stay public and declare the scheme."""
from __future__ import annotations

import base64
import json

import httpx
import pytest
from labs import free_port, start_lab
from probe import poll
from tdschema import assert_valid_td

pytestmark = pytest.mark.lab

TOKEN = "t0ken-for-tests"
BASIC = ("lab", "pa:ss word")


@pytest.fixture(scope="module")
def lab(tmp_path_factory):
    lab = start_lab(tmp_path_factory.mktemp("auth"), "lights", http=True, things={"light-left"},
                    extra_args=("--auth", f"bearer:{TOKEN}"))
    yield lab
    assert lab.stop(), "the lab did not stop cleanly"


def bearer(token: str = TOKEN) -> dict:
    return {"authorization": f"Bearer {token}"}


def test_tds_are_public_and_declare_bearer(lab):
    td = httpx.get(f"{lab.http}/light-left").json()
    assert_valid_td(td)
    assert td["security"] == ["bearer_sc"]
    assert td["securityDefinitions"]["bearer_sc"]["scheme"] == "bearer"
    listing = httpx.get(f"{lab.http}/things").json()
    assert listing and all(t["security"] == ["bearer_sc"] for t in listing)
    assert httpx.get(f"{lab.http}/.well-known/wot").status_code == 200


@pytest.mark.parametrize("headers", [{}, bearer("wrong"), {"authorization": "Basic " + base64.b64encode(
    TOKEN.encode()).decode()}, {"authorization": TOKEN}], ids=["none", "wrong-token", "wrong-scheme", "no-scheme"])
@pytest.mark.parametrize("method, path, body", [
    ("GET", "properties/lightState", None),
    ("PUT", "properties/lightState", b"true"),
    ("POST", "actions/switchOn", None),
    ("GET", "properties", None),
    ("HEAD", "properties/lightState/observable", None),
    ("GET", "properties/lightState/sse", None),
    ("GET", "events/stateChanged/sse", None),
])
def test_without_the_token_401_problem(lab, headers, method, path, body):
    r = httpx.request(method, f"{lab.http}/light-left/{path}", content=body,
                      headers={**headers, "content-type": "application/json"})
    assert r.status_code == 401
    assert r.headers["www-authenticate"].startswith("Bearer ")
    if method != "HEAD":
        assert r.headers["content-type"] == "application/problem+json" and r.json()["status"] == 401


def test_with_the_token_it_works(lab):
    base = f"{lab.http}/light-left"
    assert httpx.put(f"{base}/properties/lightState", json=False, headers=bearer()).status_code == 204
    assert httpx.post(f"{base}/actions/switchOn", headers=bearer()).status_code == 204
    assert httpx.get(f"{base}/properties/lightState", headers=bearer()).json() is True
    with httpx.stream("GET", f"{base}/properties/lightState/sse", headers=bearer(), timeout=10) as r:
        lines = r.iter_lines()
        assert r.status_code == 200 and next(lines).startswith("retry:")
        httpx.post(f"{base}/actions/switchOff", headers=bearer())
        data = next(line for line in lines if line.startswith("data:"))
    assert json.loads(data.removeprefix("data:")) is False


def test_basic_from_the_environment(lab, tmp_path, monkeypatch):
    monkeypatch.setenv("TWINMESH_HTTP_AUTH", f"basic:{BASIC[0]}:{BASIC[1]}")
    port = free_port()
    lab.spawn("adapter", "--http", f"127.0.0.1:{port}", log=tmp_path / "adapter.log")
    base = f"http://127.0.0.1:{port}/light-left"

    def served():
        try:
            return httpx.get(base, timeout=2).status_code == 200
        except httpx.HTTPError:
            return False
    _, ready = poll(served, 30)
    assert ready is not None, (tmp_path / "adapter.log").read_text()
    td = httpx.get(base).json()
    assert td["security"] == ["basic_sc"] and td["securityDefinitions"]["basic_sc"]["scheme"] == "basic"
    r = httpx.get(f"{base}/properties/lightState")
    assert r.status_code == 401 and r.headers["www-authenticate"].startswith("Basic ")
    assert httpx.get(f"{base}/properties/lightState", auth=("lab", "wrong")).status_code == 401
    assert httpx.get(f"{base}/properties/lightState", auth=BASIC).status_code == 200


def test_a_bad_auth_option_is_refused_before_starting(lab):
    r = lab.cli("adapter", "--auth", "digest:x", "--http", f"127.0.0.1:{free_port()}", timeout=30)
    assert r.returncode == 2 and "bearer:TOKEN or basic:USER:PASS" in r.stderr
