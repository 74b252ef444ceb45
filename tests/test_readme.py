"""The README keeps its word: every `twinmesh`, `curl` and `printf` command of its `sh` blocks runs, in order.

How each command is run, as a user following the README would run it:
- `twinmesh up ...` starts a lab (stopping the previous one) on free ports: `--zenoh`, `--http` and
  `--view` are added, and every `127.0.0.1:8080` / `127.0.0.1:7447` in later commands is rewritten to them;
- a command ending in `&` runs in the background until the end, and must not fail meanwhile;
- streams (`twinmesh observe`, `twinmesh subscribe`, `curl -N`) run for a few seconds and are then
  interrupted, as a user would press Ctrl-C; they must not fail before that;
- everything else must exit 0 (curl with `--fail-with-body`, so any 4xx/5xx fails it);
- a line whose comment says `not run by the README test` is skipped (none may hide in `sh` blocks).
Commands run in a shell in a scratch directory, with `twinmesh` from this interpreter's
environment and `TWINMESH_CACHE` in that directory (robot workspaces are generated afresh).
"""
from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from labs import REPO, free_port

pytestmark = pytest.mark.lab

README = REPO / "README.md"
RUN = ("twinmesh", "curl", "printf")
STREAMS = ("twinmesh observe", "twinmesh subscribe")
STREAM_SECONDS = 3.0
SKIP_MARK = "not run by the README test"


def readme_commands(text: str) -> list[str]:
    """The commands of the README's ```sh blocks, continuation lines joined, in order."""
    commands = []
    for block in re.findall(r"^```sh\n(.*?)^```", text, flags=re.S | re.M):
        for line in block.replace("\\\n", " ").splitlines():
            line = line.strip()
            if line.startswith(RUN):
                commands.append(line)
    return commands


def strip_comment(command: str) -> str:
    """The command without its trailing `# comment` (quotes respected)."""
    out, quote = [], None
    for i, ch in enumerate(command):
        if quote:
            quote = None if ch == quote else quote
        elif ch in "'\"":
            quote = ch
        elif ch == "#" and (i == 0 or command[i - 1].isspace()):
            return "".join(out).rstrip()
        out.append(ch)
    return command


@dataclass
class Walk:
    """The state of one walk through the README: the lab, its ports, background commands."""

    cwd: Path
    zenoh_port: int = 7447
    http_port: int = 8080
    lab: subprocess.Popen | None = None
    lab_log: str = ""
    background: list[tuple[str, subprocess.Popen]] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)

    @property
    def env(self) -> dict[str, str]:
        bin_dir = str(Path(sys.executable).parent)
        return {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
                "TWINMESH_CACHE": str(self.cwd / "cache"), "PYTHONUNBUFFERED": "1",
                "TWINMESH_CONNECT": f"tcp/127.0.0.1:{self.zenoh_port}"}

    def rewrite(self, command: str) -> str:
        return (command.replace("127.0.0.1:8080", f"127.0.0.1:{self.http_port}")
                .replace("127.0.0.1:7447", f"127.0.0.1:{self.zenoh_port}"))

    def spawn(self, command: str, log: str) -> subprocess.Popen:
        return subprocess.Popen(["bash", "-c", command], cwd=self.cwd, env=self.env, start_new_session=True,
                                stdout=open(self.cwd / log, "wb"), stderr=subprocess.STDOUT)

    def output(self, log: str) -> str:
        return (self.cwd / log).read_text(errors="replace")[-3000:]

    def run(self, n: int, original: str) -> None:
        command = strip_comment(original)
        background = command.endswith("&")
        command = command.rstrip("&").strip()
        if command.startswith("twinmesh up"):
            self.start_lab(n, command)
        elif background:
            self.background.append((original, self.spawn(self.rewrite(command), f"{n}.log")))
        elif command.startswith(STREAMS) or (command.startswith("curl") and " -N " in command):
            self.stream(n, original, command)
        else:
            self.once(n, original, command)

    def start_lab(self, n: int, command: str) -> None:
        self.stop_lab()
        self.zenoh_port, self.http_port = free_port(), free_port()
        extra = f" --zenoh tcp/127.0.0.1:{self.zenoh_port}"
        if "--http" not in command and "--no-http" not in command:
            extra += f" --http 127.0.0.1:{self.http_port}"
        if "--view" not in command and "--no-view" not in command:
            extra += f" --view 127.0.0.1:{free_port()}"
        self.lab = self.spawn(self.rewrite(command.replace("twinmesh up", "twinmesh up" + extra, 1)), f"{n}.log")
        self.lab_log = f"{n}.log"

    def stream(self, n: int, original: str, command: str) -> None:
        p = self.spawn(self.rewrite(command), f"{n}.log")
        time.sleep(STREAM_SECONDS)
        if p.poll() is not None and p.returncode != 0:
            self.failures.append(f"{original}\n  exited {p.returncode} before Ctrl-C:\n{self.output(f'{n}.log')}")
        stop(p)

    def once(self, n: int, original: str, command: str) -> None:
        command = self.rewrite(command)
        if command.startswith("curl "):
            command = "curl -sS --fail-with-body --max-time 120 " + command[len("curl "):]
        p = self.spawn(command, f"{n}.log")
        try:
            p.wait(600)
        except subprocess.TimeoutExpired:
            stop(p)
            self.failures.append(f"{original}\n  did not finish in 600 s")
            return
        if p.returncode != 0:
            lab = f"\n--- lab log ---\n{self.output(self.lab_log)}" if self.lab else ""
            self.failures.append(f"{original}\n  exit {p.returncode}:\n{self.output(f'{n}.log')}{lab}")

    def stop_lab(self) -> None:
        for original, p in self.background:
            if p.poll() is not None and p.returncode != 0:
                self.failures.append(f"{original}\n  (in the background) exited {p.returncode}")
            stop(p)
        self.background.clear()
        if self.lab is not None:
            if self.lab.poll() is not None:
                self.failures.append(f"the lab exited on its own ({self.lab.returncode}):\n{self.output(self.lab_log)}")
            stop(self.lab)
            self.lab = None


def stop(p: subprocess.Popen) -> None:
    """Ctrl-C, as a user would; kill what does not stop."""
    if p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


def test_the_readme_lists_commands_and_hides_none():
    commands = readme_commands(README.read_text())
    assert sum(c.startswith("twinmesh up") for c in commands) >= 2
    assert any(c.startswith("curl") for c in commands)
    assert not [c for c in commands if SKIP_MARK in c], "a command in an sh block is marked as not run"


def test_every_readme_command_works_as_shown(tmp_path):
    walk = Walk(tmp_path)
    try:
        for n, command in enumerate(readme_commands(README.read_text())):
            walk.run(n, command)
    finally:
        walk.stop_lab()
    assert not walk.failures, "README commands that failed:\n\n" + "\n\n".join(walk.failures)


@pytest.mark.parametrize("line, expected", [
    ("twinmesh things", "twinmesh things"),
    ("twinmesh observe a b        # one JSON value per change", "twinmesh observe a b"),
    ("curl -d '{\"a\": \"#x\"}' http://h  # c", "curl -d '{\"a\": \"#x\"}' http://h"),
])
def test_comments_are_stripped_but_not_inside_quotes(line, expected):
    assert strip_comment(line) == expected
