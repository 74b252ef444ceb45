"""The docs keep their word: every `sh` and `python` block of README.md and of every page under docs/ runs.

A block that cannot run (it needs the real lab, several hosts, or installs twinmesh) says so, with the reason,
in an HTML comment on the line before its fence: `<!-- not run: REASON -->`. Every line of any other `sh` block
must be a command this test runs (`twinmesh`, `curl`, `printf`), so nothing hides in a block.

How each command is run, as a user following the page would run it:
- `twinmesh up ...` starts a lab on free ports: `--zenoh`, `--http` and `--view` are added, and every
  `127.0.0.1:8080` / `127.0.0.1:7447` in later commands and `python` blocks is rewritten to them. A page whose
  `up` command is the running lab's shares that lab (pages run grouped by the lab they start); any other stops it;
- a command ending in `&` runs in the background until the end of its page, and must not fail meanwhile;
- streams (`twinmesh observe`, `twinmesh subscribe`, `curl -N`) run for a few seconds and are then interrupted, as a
  user would press Ctrl-C; they must not fail before that;
- everything else must exit 0 (curl with `--fail-with-body`, so any 4xx/5xx fails it), a `python` block too.
Commands run in a shell in a scratch directory, with `twinmesh` from this interpreter's environment and
`TWINMESH_CACHE` and `XDG_DATA_HOME` (a secure lab's secrets) in that directory (robot workspaces are generated
afresh), the compiled code where this environment keeps it (`NUMBA_CACHE_DIR`: compiled once per machine, as for a
user's every start after the first; an empty one started a background compile of a minute of CPU per run, which
tests/test_first_start.py covers), and `twinmesh wait` given 600 s instead of 120 (`TWINMESH_WAIT_TIMEOUT`): a
busy machine starts labs slowly.
"""
from __future__ import annotations

import os
import re
import shlex
import signal
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import pytest
from labs import REPO, free_port

from tdgen.robot.cores import compiled_code_dir

README = REPO / "README.md"
DOCS = REPO / "docs"
RUN = ("twinmesh", "curl", "printf")
STREAMS = ("twinmesh observe", "twinmesh subscribe")
STREAM_SECONDS = 3.0
VALUED = {"--prefix", "--connect", "--listen", "--mode", "--secrets"}  # the global options that take a value
BLOCK = re.compile(r"(?:<!--\s*not run:(?P<reason>(?:(?!-->).)*)-->[ \t]*\n)?"  # the mark, right before the fence
                   r"^```(?P<kind>sh|python)[^\n]*\n(?P<body>.*?)^```", flags=re.S | re.M)


@dataclass(frozen=True)
class Block:
    kind: str          # "sh" or "python"
    body: str
    line: int          # of the opening fence, 1-based
    not_run: str | None = None  # the reason, for a block marked `<!-- not run: ... -->`


def blocks(text: str) -> list[Block]:
    """The page's `sh` and `python` blocks, in order."""
    return [Block(m["kind"], m["body"], text.count("\n", 0, m.start("kind")) + 1,
                  None if m["reason"] is None else m["reason"].strip())
            for m in BLOCK.finditer(text)]


def sh_lines(body: str) -> list[str]:
    """The lines of an `sh` block that do something, continuation lines joined, comments left out."""
    lines = (line.strip() for line in body.replace("\\\n", " ").splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def pages() -> list[Path]:
    """README first, then every docs page; grouped by the lab each starts first, so that pages share labs."""
    found = [README, *sorted(DOCS.rglob("*.md"))]
    return sorted(found, key=lambda page: lab_order(page.read_text()))


def lab_order(text: str) -> tuple[str, int]:
    """The page's first lab; a page that goes on to another lab comes last among those that share its first."""
    labs = [strip_comment(line).rstrip("&").strip() for block in blocks(text) if block.kind == "sh" and block.not_run is None
            for line in sh_lines(block.body) if up_at(strip_comment(line).rstrip("&")) is not None]
    return (labs[0], len(set(labs))) if labs else ("", 0)


def up_at(command: str) -> int | None:
    """Where `up` is among the command's words, when the command starts a lab (`twinmesh [global options] up`)."""
    words = shlex.split(command)
    i = 1
    while i < len(words) and words[0] == "twinmesh" and words[i].startswith("-"):
        i += 2 if words[i] in VALUED else 1
    return i if words[:1] == ["twinmesh"] and i < len(words) and words[i] == "up" else None


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
    """The state of a walk through the pages: the lab, its ports, background commands."""

    cwd: Path
    zenoh_port: int = 7447
    http_port: int = 8080
    lab: subprocess.Popen | None = None
    lab_command: str = ""
    lab_log: str = ""
    n: int = 0
    background: list[tuple[str, subprocess.Popen]] = field(default_factory=list)
    failures: list[str] = field(default_factory=list)

    @property
    def env(self) -> dict[str, str]:
        bin_dir = str(Path(sys.executable).parent)
        return {**os.environ, "PATH": bin_dir + os.pathsep + os.environ.get("PATH", ""),
                "TWINMESH_CACHE": str(self.cwd / "cache"), "XDG_DATA_HOME": str(self.cwd / "data"),
                "NUMBA_CACHE_DIR": str(compiled_code_dir()),
                "PYTHONUNBUFFERED": "1", "TWINMESH_CONNECT": f"tcp/127.0.0.1:{self.zenoh_port}",
                "TWINMESH_WAIT_TIMEOUT": "600"}  # `wait --timeout`: a lab starts slowly on a busy machine

    def rewrite(self, command: str) -> str:
        return (command.replace("127.0.0.1:8080", f"127.0.0.1:{self.http_port}")
                .replace("127.0.0.1:7447", f"127.0.0.1:{self.zenoh_port}"))

    def spawn(self, argv: list[str], log: str) -> subprocess.Popen:
        return subprocess.Popen(argv, cwd=self.cwd, env=self.env, start_new_session=True,
                                stdout=open(self.cwd / log, "wb"), stderr=subprocess.STDOUT)

    def shell(self, command: str, log: str) -> subprocess.Popen:
        return self.spawn(["bash", "-c", command], log)

    def output(self, log: str) -> str:
        return (self.cwd / log).read_text(errors="replace")[-3000:]

    def page(self, page: Path) -> None:
        where = page.relative_to(REPO)
        for block in blocks(page.read_text()):
            if block.not_run is not None:
                continue
            if block.kind == "python":
                self.python(f"{where}:{block.line}", block.body)
            else:
                for line in sh_lines(block.body):
                    self.run(f"{where}:{block.line}: {line}")
        self.stop_background()
        if self.lab is not None and self.lab.poll() is not None:  # said on the page that started it, not the next
            self.failures.append(f"the lab exited on its own ({self.lab.returncode}):\n{self.output(self.lab_log)}")
            self.lab, self.lab_command = None, ""

    def run(self, original: str) -> None:
        self.n += 1
        command = strip_comment(original.split(": ", 1)[1])
        background = command.endswith("&")
        command = command.rstrip("&").strip()
        if up_at(command) is not None:
            self.start_lab(command)
        elif background:
            self.background.append((original, self.shell(self.rewrite(command), f"{self.n}.log")))
        elif command.startswith(STREAMS) or (command.startswith("curl") and " -N " in command):
            self.stream(original, command)
        else:
            if command.startswith("curl "):
                command = "curl -sS --fail-with-body --max-time 120 " + command[len("curl "):]
            self.once(original, self.shell(self.rewrite(command), f"{self.n}.log"))

    def python(self, where: str, body: str) -> None:
        self.n += 1
        script = self.cwd / f"block-{self.n}.py"
        script.write_text(self.rewrite(body))
        self.once(f"{where}: the python block", self.spawn([sys.executable, script.name], f"{self.n}.log"))

    def start_lab(self, command: str) -> None:
        if command == self.lab_command and self.lab is not None and self.lab.poll() is None:
            return  # the same lab: shared, as a reader would keep it running between pages
        self.stop_lab()
        self.zenoh_port, self.http_port = free_port(), free_port()
        extra = f" --zenoh tcp/127.0.0.1:{self.zenoh_port}"
        if "--http" not in command and "--no-http" not in command:
            extra += f" --http 127.0.0.1:{self.http_port}"
        if "--view" not in command and "--no-view" not in command:
            extra += f" --view 127.0.0.1:{free_port()}"
        self.n += 1
        words = shlex.split(command)
        at = up_at(command) + 1
        self.lab = self.shell(self.rewrite(shlex.join(words[:at] + extra.split() + words[at:])), f"{self.n}.log")
        self.lab_command, self.lab_log = command, f"{self.n}.log"

    def stream(self, original: str, command: str) -> None:
        log = f"{self.n}.log"
        p = self.shell(self.rewrite(command), log)
        try:  # it streams until Ctrl-C: its end (an error) is the event, the window as long as a user watches
            p.wait(timeout=STREAM_SECONDS)
        except subprocess.TimeoutExpired:
            pass
        if p.poll() is not None and p.returncode != 0:
            self.failures.append(f"{original}\n  exited {p.returncode} before Ctrl-C:\n{self.output(log)}")
        stop(p)

    def once(self, original: str, p: subprocess.Popen) -> None:
        log = f"{self.n}.log"
        try:
            p.wait(600)
        except subprocess.TimeoutExpired:
            stop(p)
            self.failures.append(f"{original}\n  did not finish in 600 s")
            return
        if p.returncode != 0:
            lab = f"\n--- lab log ---\n{self.output(self.lab_log)}" if self.lab else ""
            self.failures.append(f"{original}\n  exit {p.returncode}:\n{self.output(log)}{lab}")

    def stop_background(self) -> None:
        for original, p in self.background:
            if p.poll() is not None and p.returncode != 0:
                self.failures.append(f"{original}\n  (in the background) exited {p.returncode}")
            stop(p)
        self.background.clear()

    def stop_lab(self) -> None:
        self.stop_background()
        if self.lab is not None:
            if self.lab.poll() is not None:
                self.failures.append(f"the lab exited on its own ({self.lab.returncode}):\n{self.output(self.lab_log)}")
            stop(self.lab)
            self.lab, self.lab_command = None, ""


def stop(p: subprocess.Popen) -> None:
    """Ctrl-C, as a user would; kill what does not stop."""
    if p.poll() is None:
        os.killpg(p.pid, signal.SIGINT)
        try:
            p.wait(20)
        except subprocess.TimeoutExpired:
            os.killpg(p.pid, signal.SIGKILL)
            p.wait()


@pytest.fixture(scope="module")
def walk(tmp_path_factory):
    w = Walk(tmp_path_factory.mktemp("docs-walk"))
    yield w
    w.stop_lab()


PAGES = pages()


@pytest.mark.lab
@pytest.mark.slow  # the pages together take minutes: the module starts first (conftest.py)
@pytest.mark.timeout(1800)  # a page that starts a lab waits for it: minutes on a busy machine
@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(REPO)) for p in PAGES])
def test_every_block_of_the_page_works_as_shown(walk, page):
    walk.failures.clear()
    walk.page(page)
    if page == PAGES[-1]:
        walk.stop_lab()
    assert not walk.failures, f"{page.relative_to(REPO)}: blocks that failed:\n\n" + "\n\n".join(walk.failures)


@pytest.mark.parametrize("page", PAGES, ids=[str(p.relative_to(REPO)) for p in PAGES])
def test_every_block_runs_or_says_why(page):
    for block in blocks(page.read_text()):
        where = f"{page.relative_to(REPO)}:{block.line}"
        if block.not_run is not None:
            assert block.not_run, f"{where}: a block marked not run must say why"
        elif block.kind == "sh":
            foreign = [line for line in sh_lines(block.body) if not line.startswith(RUN)]
            assert not foreign, f"{where}: lines this test cannot run in an unmarked sh block: {foreign}"


def test_the_readme_shows_a_lab_a_request_and_python():
    readme = blocks(README.read_text())
    run = [line for b in readme if b.kind == "sh" and b.not_run is None for line in sh_lines(b.body)]
    assert any(up_at(line.rstrip("&")) is not None for line in run)
    assert any(line.startswith("curl") for line in run)
    assert any(b.kind == "python" and b.not_run is None for b in readme)
    assert len(README.read_text().splitlines()) <= 200, "the README is a front page: 200 lines at most"


def test_a_marked_block_is_left_out_and_its_reason_kept():
    text = ("intro\n\n<!-- not run: needs the real lab -->\n```sh\ntwinmesh bridge a=b\n```\n\n"
            "```python\nprint(1)\n```\n```sh {.copy}\ntwinmesh things   # all\n# a comment\n```\n")
    found = blocks(text)
    assert [(b.kind, b.not_run) for b in found] == [("sh", "needs the real lab"), ("python", None), ("sh", None)]
    assert sh_lines(found[2].body) == ["twinmesh things   # all"]
    assert found[0].line == 4


@pytest.mark.parametrize("command, at", [
    ("twinmesh up --speed max", 1),
    ("twinmesh --secure up lights", 2),
    ("twinmesh --listen tcp/0.0.0.0:7447 up", 3),
    ("twinmesh --connect tcp/h:7447 things", None),
    ("twinmesh upload", None),
])
def test_a_lab_is_started_by_up_after_any_global_options(command, at):
    assert up_at(command) == at


def test_a_comment_far_from_the_fence_marks_nothing():
    text = "<!-- not run: something -->\n\nprose\n\n```sh\ntwinmesh things\n```\n"
    assert [b.not_run for b in blocks(text)] == [None]


@pytest.mark.parametrize("line, expected", [
    ("twinmesh things", "twinmesh things"),
    ("twinmesh observe a b        # one JSON value per change", "twinmesh observe a b"),
    ("curl -d '{\"a\": \"#x\"}' http://h  # c", "curl -d '{\"a\": \"#x\"}' http://h"),
])
def test_comments_are_stripped_but_not_inside_quotes(line, expected):
    assert strip_comment(line) == expected
