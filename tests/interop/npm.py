"""node-wot tooling for the interop tests and the HTTP benchmark: npm install, the scripted client
(wot-client.mjs), node-wot's own servient as baseline (servient-baseline.mjs), and the Thingweb
TD Playground's validator and assertion tester (td-playground.cjs).

Import as `from interop import npm` (tests/ is on sys.path). Without node/npm the helpers skip the
test locally and fail it in CI (CI=true).
"""
from __future__ import annotations

import fcntl
import hashlib
import json
import os
import queue
import shutil
import subprocess
import tempfile
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import pytest

INTEROP_DIR = Path(__file__).resolve().parent
CLIENT = INTEROP_DIR / "wot-client.mjs"
BASELINE = INTEROP_DIR / "servient-baseline.mjs"
PLAYGROUND = INTEROP_DIR / "td-playground.cjs"
CONTEXTS = INTEROP_DIR.parent / "data" / "wot" / "contexts"  # JSON-LD contexts, local copies (data/SOURCES.md)
LOCK = INTEROP_DIR / "package-lock.json"
INSTALLED = INTEROP_DIR / "node_modules" / ".package-lock.json"  # npm rewrites it on every install
INSTALL_TIMEOUT = 600


class HarnessError(RuntimeError):
    """The node side did not run as it should (bad script, crash, timeout); stderr is in the message."""


class TDConsumeError(HarnessError):
    """node-wot could not fetch or consume the TD; `.message` is node-wot's error text."""

    def __init__(self, message: str, stderr: str):
        super().__init__(f"node-wot could not consume the TD: {message}\n--- stderr ---\n{stderr}")
        self.message = message


def _unavailable(reason: str):
    if os.environ.get("CI") == "true":
        pytest.fail(f"{reason} (CI: node and npm must be installed)", pytrace=False)
    pytest.skip(reason)


def _node() -> str:
    node = shutil.which("node")
    if node is None:
        _unavailable("node is not on PATH: node-wot interop tests need Node.js >= 20")
    return node


def _tail(text: str, limit: int = 4000) -> str:
    lines = [line for line in text.splitlines() if "unknown format" not in line]  # ajv noise at import
    text = "\n".join(lines)
    return text if len(text) <= limit else "...\n" + text[-limit:]


def _installed() -> bool:
    return INSTALLED.exists() and INSTALLED.stat().st_mtime >= LOCK.stat().st_mtime


def ensure_node_modules() -> None:
    """`npm ci` in tests/interop when node_modules is missing or older than the lock file.

    Serialised by a file lock, so concurrent test runs on one work tree install once.
    """
    _node()
    npm = shutil.which("npm")
    if npm is None:
        _unavailable("npm is not on PATH: node-wot interop tests need npm to install @node-wot/*")
    if _installed():
        return
    key = hashlib.sha1(str(INTEROP_DIR).encode()).hexdigest()[:12]
    with open(Path(tempfile.gettempdir()) / f"twinmesh-npm-{key}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if _installed():
            return
        command = [npm, "ci" if LOCK.exists() else "install", "--no-audit", "--no-fund", "--loglevel=error"]
        try:
            done = subprocess.run(command, cwd=INTEROP_DIR, capture_output=True, text=True, timeout=INSTALL_TIMEOUT)
        except subprocess.TimeoutExpired:
            pytest.fail(f"{' '.join(command)} in {INTEROP_DIR} took more than {INSTALL_TIMEOUT} s", pytrace=False)
        if done.returncode != 0:
            pytest.fail(f"{' '.join(command)} in {INTEROP_DIR} failed ({done.returncode}):\n"
                        f"{_tail(done.stdout + done.stderr)}", pytrace=False)
        INSTALLED.touch()  # `npm ci` may keep the lock's own mtime on it


def _credential_args(credentials: dict | None) -> list[str]:
    if not credentials:
        return []
    if "token" in credentials:
        return ["--bearer", credentials["token"]]
    if "username" in credentials and "password" in credentials:
        return ["--basic", f"{credentials['username']}:{credentials['password']}"]
    raise ValueError(f"credentials want {{'token'}} or {{'username', 'password'}}, not {sorted(credentials)}")


def run_client(td_url: str, steps: list[dict], timeout: float = 60, credentials: dict | None = None) -> list[dict]:
    """Run the steps with node-wot against the Thing whose TD is at `td_url`.

    Returns one result per step, in order: {"i", "op", "ok", and "value" / "values" / "started", or
    "error" (node-wot's message) and "timeout": true when a wait ran out}. `credentials` is
    {"username", "password"} (basic) or {"token"} (bearer), registered under the TD's id.
    Raises TDConsumeError when node-wot rejects or cannot fetch the TD, HarnessError otherwise.
    """
    ensure_node_modules()
    command = [_node(), str(CLIENT), td_url, "-", *_credential_args(credentials)]
    try:
        done = subprocess.run(command, cwd=INTEROP_DIR, input=json.dumps(steps), capture_output=True,
                              text=True, timeout=timeout)
    except subprocess.TimeoutExpired as e:  # run() has killed and reaped the client
        stderr = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr or ""
        raise HarnessError(f"wot-client.mjs ran more than {timeout} s\n--- stderr ---\n{_tail(stderr)}") from None
    stderr = _tail(done.stderr)
    try:
        lines = [json.loads(line) for line in done.stdout.splitlines() if line.strip()]
    except json.JSONDecodeError:
        raise HarnessError(f"wot-client.mjs printed a line that is not JSON:\n{done.stdout}\n"
                           f"--- stderr ---\n{stderr}") from None
    if done.returncode == 2 and lines and lines[0].get("op") == "consume":
        raise TDConsumeError(lines[0].get("error", "?"), stderr)
    results = lines[1:]
    if done.returncode != 0 or [r.get("i") for r in results] != list(range(len(steps))):
        raise HarnessError(f"wot-client.mjs exited {done.returncode} with {len(results)} of {len(steps)} results\n"
                           f"--- stdout ---\n{done.stdout}--- stderr ---\n{stderr}")
    return results


def run_clients(things: list[tuple[str, list[dict]]], timeout: float = 300, parallel: int = 8,
                credentials: dict | None = None) -> list[list[dict] | HarnessError]:
    """`run_client` for several Things at once, from one node process (node-wot loads once; `parallel`
    Things are driven at a time): for each (TD URL, steps), its results, or the HarnessError (a
    TDConsumeError when node-wot could not consume its TD) that `run_client` would have raised."""
    ensure_node_modules()
    command = [_node(), str(CLIENT), "--many", "-", "--parallel", str(parallel), *_credential_args(credentials)]
    script = json.dumps([{"url": url, "steps": steps} for url, steps in things])
    try:
        done = subprocess.run(command, cwd=INTEROP_DIR, input=script, capture_output=True, text=True, timeout=timeout)
    except subprocess.TimeoutExpired as e:
        stderr = e.stderr.decode(errors="replace") if isinstance(e.stderr, bytes) else e.stderr or ""
        raise HarnessError(f"wot-client.mjs --many ran more than {timeout} s\n--- stderr ---\n{_tail(stderr)}") from None
    stderr = _tail(done.stderr)
    if done.returncode != 0:
        raise HarnessError(f"wot-client.mjs --many exited {done.returncode}\n--- stdout ---\n{done.stdout[-4000:]}"
                           f"--- stderr ---\n{stderr}")
    lines: list[list[dict]] = [[] for _ in things]
    for line in done.stdout.splitlines():
        if line.strip():
            entry = json.loads(line)
            lines[entry.pop("thing")].append(entry)
    out: list[list[dict] | HarnessError] = []
    for (url, steps), got in zip(things, lines):
        if got and got[0].get("op") == "consume" and not got[0].get("ok"):
            out.append(TDConsumeError(got[0].get("error", "?"), stderr))
        elif [r.get("i") for r in got[1:]] != list(range(len(steps))):
            out.append(HarnessError(f"{url}: {len(got[1:])} of {len(steps)} results\n--- stderr ---\n{stderr}"))
        else:
            out.append(got[1:])
    return out


def playground(documents: list[dict], timeout: float = 300) -> list[dict]:
    """The Thingweb TD Playground on each {"name", "kind": "td" | "tm", "document"}: one result per
    document, {"name", "report", "details", "failed" (assertion ids), "counts", "log"} (td-playground.cjs)."""
    ensure_node_modules()
    command = [_node(), str(PLAYGROUND), str(CONTEXTS)]
    try:
        done = subprocess.run(command, cwd=INTEROP_DIR, input=json.dumps(documents), capture_output=True, text=True,
                              timeout=timeout)
    except subprocess.TimeoutExpired:
        raise HarnessError(f"td-playground.cjs ran more than {timeout} s") from None
    lines = [json.loads(line) for line in done.stdout.splitlines() if line.startswith("{")]
    if done.returncode != 0 or len(lines) != len(documents):
        raise HarnessError(f"td-playground.cjs exited {done.returncode} with {len(lines)} of {len(documents)} "
                           f"results\n--- stderr ---\n{_tail(done.stderr)}")
    return lines


def form_index(td: dict, kind: str, name: str, op: str, subprotocol: str | None = None) -> int:
    """Index of the first form of td[kind][name] for `op` (and `subprotocol`), for a step's formIndex."""
    for index, form in enumerate(td[kind][name]["forms"]):
        ops = form.get("op", [])
        if op in ([ops] if isinstance(ops, str) else ops) and subprotocol in (None, form.get("subprotocol")):
            return index
    raise LookupError(f"no {op} form{f' with subprotocol {subprotocol}' if subprotocol else ''} in {kind}.{name}")


def _ready_line(process: subprocess.Popen, timeout: float) -> tuple[str, dict]:
    """The first line a node servient prints on stdout (within `timeout` s), and it as JSON ({} if not)."""
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: lines.put(process.stdout.readline()), daemon=True).start()
    try:
        line = lines.get(timeout=timeout)
    except queue.Empty:
        line = ""
    return line, json.loads(line) if line.startswith("{") else {}


@dataclass(frozen=True)
class Baseline:
    """A running servient-baseline.mjs."""

    port: int
    things: dict[str, str]  # Thing title -> TD URL
    process: subprocess.Popen

    def td_url(self, thing: str = "light-left") -> str:
        return self.things[thing]


@contextmanager
def start_baseline_servient(port: int = 0, credentials: dict | None = None,
                            ready_timeout: float = 30) -> Iterator[Baseline]:
    """Run node-wot's own servient (a light-left equivalent) on 127.0.0.1:`port` (0: a free one).

    `credentials` ({"username", "password"}) makes it require basic auth. The process is killed on
    exit; it also exits by itself if this Python process dies (its stdin closes).
    """
    ensure_node_modules()
    command = [_node(), str(BASELINE), "--port", str(port), "--exit-with-stdin"]
    if credentials:
        command += ["--basic", f"{credentials['username']}:{credentials['password']}"]
    with tempfile.TemporaryFile("w+") as stderr:
        process = subprocess.Popen(command, cwd=INTEROP_DIR, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                   stderr=stderr, text=True)
        try:
            line, ready = _ready_line(process, ready_timeout)
            if not ready.get("ready"):
                process.kill()
                process.wait()
                stderr.seek(0)
                raise HarnessError(f"servient-baseline.mjs did not get ready in {ready_timeout} s "
                                   f"(exit {process.returncode}, said {line!r})\n--- stderr ---\n"
                                   f"{_tail(stderr.read())}")
            yield Baseline(port=ready["port"], things=ready["things"], process=process)
        finally:
            if process.poll() is None:
                process.terminate()
                try:
                    process.wait(timeout=5)
                except subprocess.TimeoutExpired:
                    process.kill()
                    process.wait()
            for pipe in (process.stdin, process.stdout):
                pipe.close()


REAL_LAB = INTEROP_DIR / "real-lab.mjs"
REAL_LAB_TDS = INTEROP_DIR.parent / "data" / "reference-tds" / "real-lab"


class RealLab:
    """A mock of the real lab (real-lab.mjs): node-wot servients exposing the real lab's TDs behind basic
    authentication, with a request log. `kill()` and `start()` again keep its port, as a real device
    that goes down and comes back at the same address."""

    def __init__(self, credentials: dict | None = None, port: int = 0, ready_timeout: float = 30,
                 tls: tuple[Path, Path] | None = None, extra_tds: Path | None = None):
        """`tls`: (key, certificate) PEM files: serve https with them. `extra_tds`: a folder of more TDs
        to serve beside the real lab's (a real UR10 for the robot guard)."""
        self.credentials, self.port, self.ready_timeout, self.tls = credentials, port, ready_timeout, tls
        self.extra_tds = extra_tds
        self.things: dict[str, str] = {}  # TD file name (Uarm, WarehouseDobot, ...) -> TD URL
        self.process: subprocess.Popen | None = None
        self._stderr = tempfile.TemporaryFile("w+")

    def start(self) -> "RealLab":
        ensure_node_modules()
        command = [_node(), str(REAL_LAB), "--tds", str(REAL_LAB_TDS), "--port", str(self.port), "--exit-with-stdin"]
        if self.credentials:
            command += ["--basic", f"{self.credentials['username']}:{self.credentials['password']}"]
        if self.extra_tds:
            command += ["--tds", str(self.extra_tds)]
        if self.tls:
            command += ["--tls-key", str(self.tls[0]), "--tls-cert", str(self.tls[1])]
        process = subprocess.Popen(command, cwd=INTEROP_DIR, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                   stderr=self._stderr, text=True)
        line, ready = _ready_line(process, self.ready_timeout)
        if not ready.get("ready"):
            process.kill()
            process.wait()
            self._stderr.seek(0)
            raise HarnessError(f"real-lab.mjs did not get ready in {self.ready_timeout} s (said {line!r})\n"
                               f"--- stderr ---\n{_tail(self._stderr.read())}")
        self.process, self.port, self.things = process, ready["port"], ready["things"]
        return self

    @property
    def base(self) -> str:
        return f"{'https' if self.tls else 'http'}://127.0.0.1:{self.port}"

    def url(self, thing: str) -> str:
        return self.things[thing]

    def log(self) -> list[dict]:
        """Every request received ({seq, method, path, authorized}) and handler call ({seq, thing, affordance,
        input}), in order, since the last `clear_log` (or start)."""
        import httpx

        return httpx.get(f"{self.base}/_log", timeout=10, verify=False).json()  # our own mock

    def calls(self, thing: str | None = None, affordance: str | None = None) -> list[dict]:
        return [e for e in self.log() if "affordance" in e and thing in (None, e["thing"])
                and affordance in (None, e["affordance"])]

    def requests(self) -> list[dict]:
        return [e for e in self.log() if "method" in e]

    def clear_log(self) -> None:
        import httpx

        httpx.delete(f"{self.base}/_log", timeout=10, verify=False)

    def kill(self) -> None:
        process, self.process = self.process, None
        if process is not None and process.poll() is None:
            process.kill()
            process.wait()
        if process is not None:
            for pipe in (process.stdin, process.stdout):
                pipe.close()

    def __enter__(self) -> "RealLab":
        return self.start()

    def __exit__(self, *exc) -> None:
        self.kill()
        self._stderr.close()
