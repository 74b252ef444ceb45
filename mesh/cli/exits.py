"""Exit codes, one meaning each, for every command (the README lists them):

0  done (a check: the target is accepted)
1  refused or not found: the lab answered no (a refused move or input, no such Thing or affordance,
   a Thing not on the mesh)
2  usage: a bad option or argument, an input file that cannot be read or used (click's own code)
3  no lab reachable, or the Thing did not answer in time: worth retrying
"""
from __future__ import annotations

import click

from mesh.wot.problem import Problem

OK, REFUSED, USAGE, UNREACHABLE = 0, 1, 2, 3


class CommandFailed(click.ClickException):
    """A one-line message on stderr and the exit code that says what kind of failure it was."""

    def __init__(self, message: str, exit_code: int = REFUSED):
        super().__init__(message)
        self.exit_code = exit_code  # type: ignore[misc]  # click reads it from the instance


def problem_exit(p: Problem, message: str | None = None) -> CommandFailed:
    """What the CLI does with a Problem from the lab: no lab, no answer in time or a broken reply (5xx)
    is 3; a Thing that is not on the mesh, like any 4xx, is 1."""
    unreachable = p.status >= 500 and p.reason != "not-on-mesh"
    return CommandFailed(message or str(p), UNREACHABLE if unreachable else REFUSED)


def usage_exit(message: str) -> CommandFailed:
    return CommandFailed(message, USAGE)
