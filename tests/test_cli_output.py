"""What the CLI prints, in the small: `check` says its verdict once, `things` lists names sorted, and a
consumer's wait that gets nothing says why instead of raising a bare `queue.Empty` (issue 46).

No lab here: `check` reads a points.csv written by the test, `things` runs on a small fake client."""
from __future__ import annotations

import queue
from contextlib import contextmanager

import numpy as np
import pytest
from click.testing import CliRunner

from devices.cli.main import main
from mesh.wot.consumed import Inbox, NothingArrived
from mesh.wot.problem import Problem


@pytest.fixture(scope="module")
def td_dir(tmp_path_factory):
    """A TD directory as `check` reads it: points.csv of a 400 mm cube of points, those within 80 mm of its
    centre colliding (an obstacle inside the hull), enough for the hull and the neighbour share."""
    out = tmp_path_factory.mktemp("check")
    rng = np.random.default_rng(1)
    points = rng.uniform(0, 400, size=(3000, 3))
    colliding = np.linalg.norm(points - 200, axis=1) < 80
    rows = [f"{x:.3f},{y:.3f},{z:.3f},{int(c)},0" for (x, y, z), c in zip(points, colliding)]
    (out / "points.csv").write_text("x,y,z,collision,j1\n" + "\n".join(rows) + "\n")
    return out


def _check(td_dir, *xyz: float):
    return CliRunner().invoke(main, ["check", str(td_dir), *(str(v) for v in xyz)])


@pytest.mark.parametrize("xyz, code, verdict", [
    ((80, 80, 80), 0, "OK: inside the workspace"),
    ((-5000, 0, 0), 1, "REFUSED: outside the workspace hull by"),
    ((200, 200, 200), 1, "REFUSED: collision probability"),
])
def test_check_prints_its_verdict_once_on_one_line(td_dir, xyz, code, verdict):
    result = _check(td_dir, *xyz)
    assert result.exit_code == code, result.output
    assert result.stderr == ""
    lines = result.stdout.splitlines()
    assert len(lines) == 1 and lines[0].startswith(verdict), lines
    assert f"(target {xyz[0]:g}, {xyz[1]:g}, {xyz[2]:g} mm)" in lines[0]
    assert "workspace" in lines[0] or "collision" in lines[0]


class _FakeClient:
    """Liveliness answers arrive in whatever order the routers forward them."""

    names = ["tdgen", "light-right", "conveyor-belt-2", "light-left", "conveyor-belt-1"]

    def iter_things(self, timeout: float = 2.0):
        yield from self.names

    def things(self, timeout: float = 2.0):
        return sorted(self.iter_things(timeout))


@pytest.fixture
def fake_mesh(monkeypatch):
    from mesh.cli import commands

    @contextmanager
    def fake(settings):
        yield _FakeClient()

    monkeypatch.setattr(commands, "mesh_client", fake)


def test_things_lists_names_sorted(fake_mesh):
    result = CliRunner().invoke(main, ["things"])
    assert result.exit_code == 0, result.output
    assert result.stdout.split() == sorted(_FakeClient.names)


def test_things_unsorted_prints_names_as_they_arrive(fake_mesh):
    result = CliRunner().invoke(main, ["things", "--unsorted"])
    assert result.stdout.split() == _FakeClient.names
    assert CliRunner().invoke(main, ["things", "--sort"]).stdout.split() == sorted(_FakeClient.names)


def test_an_inbox_that_gets_nothing_says_why():
    with pytest.raises(NothingArrived) as caught:
        Inbox().get(timeout=0.05)
    problem = caught.value
    assert isinstance(problem, Problem) and problem.status == 504
    assert "no change or event arrived within 0.05 s" in str(problem)
    assert "read it first" in str(problem)
    assert isinstance(problem, queue.Empty)  # code that caught queue.Empty keeps working


def test_an_inbox_gives_values_and_raises_what_a_broken_stream_reported():
    inbox = Inbox()
    inbox(True)
    inbox(Problem("stream broken"))
    assert inbox.get(timeout=1) is True
    with pytest.raises(Problem, match="stream broken"):
        inbox.get(timeout=1)
