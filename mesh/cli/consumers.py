"""The one-shot consumers lab commands use (Zenoh, or WoT HTTP with `--via`); Problems become CLI exits
(see `exits`)."""
from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING

import click

from mesh import consumer
from mesh.cli.exits import problem_exit
from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.settings import MeshSettings
from mesh.wot.problem import Problem

if TYPE_CHECKING:
    from mesh.wot.consumed import Consumer


@contextmanager
def mesh_client(settings: MeshSettings) -> Iterator[MeshClient]:
    """A client-mode session for one command (unless `--mode` was given); no lab, a Thing gone or a
    refusal ends the command with its message and exit code."""
    from mesh.fabric.session import one_shot_session

    try:
        with one_shot_session(settings, mode_given()) as session:
            yield MeshClient(session, settings)
    except Problem as p:
        raise problem_exit(p) from None


def mode_given() -> bool:
    return click.get_current_context().find_root().params.get("mode") is not None


@contextmanager
def consumer_for(settings: MeshSettings, via: str | None = None, auth: str | None = None) -> Iterator[Consumer]:
    """A `mesh.Consumer` whose `thing(name)` is the Thing at `{via}/{name}` (WoT HTTP, with `auth`:
    bearer:TOKEN or basic:USER:PASS), or without `via` the Thing of that name on the mesh."""
    if via:
        try:
            made = consumer(auth=auth, base=via)
        except ValueError as e:
            raise click.BadParameter(str(e), param_hint="--auth") from None
        try:
            with made:
                yield made
        except Problem as p:
            raise problem_exit(p) from None
        return
    with mesh_client(settings) as client:
        with consumer(session=client.session, settings=settings) as made:
            yield made
