"""The one-shot Zenoh consumer every lab command uses; Problems become CLI exits (see `exits`)."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager

import click

from twinmesh.cli.exits import problem_exit
from twinmesh.fabric.client import MeshClient
from twinmesh.fabric.settings import MeshSettings
from twinmesh.wot.problem import Problem


@contextmanager
def mesh_client(settings: MeshSettings) -> Iterator[MeshClient]:
    """A client-mode session for one command (unless `--mode` was given); no lab, a Thing gone or a
    refusal ends the command with its message and exit code."""
    from twinmesh.fabric.session import one_shot_session

    try:
        with one_shot_session(settings, mode_given()) as session:
            yield MeshClient(session, settings)
    except Problem as p:
        raise problem_exit(p) from None


def mode_given() -> bool:
    return click.get_current_context().find_root().params.get("mode") is not None
