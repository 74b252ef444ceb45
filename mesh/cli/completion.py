"""Shell completion of Thing and affordance names, asked of the running lab.

click completes commands and options itself (`eval "$(_TWINMESH_COMPLETE=bash_source twinmesh)"`);
these callbacks add what only the lab knows. A lab that does not answer within a moment completes
nothing: a shell must never hang on Tab.
"""
from __future__ import annotations

from typing import Any

import click
from click.shell_completion import CompletionItem

from mesh.fabric.settings import DEFAULT_ENDPOINT, MeshSettings

TIMEOUT = 1.0  # s: the most a Tab may wait for the lab


def _settings(ctx: click.Context) -> MeshSettings:
    p = ctx.find_root().params
    return MeshSettings(prefix=p.get("prefix") or "wot", mode="client",
                        connect=tuple(p.get("connect") or ()) or (DEFAULT_ENDPOINT,), query_timeout=TIMEOUT)


def _ask(ctx: click.Context, question) -> list[str]:
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.session import one_shot_session
    from mesh.wot.problem import Problem

    settings = _settings(ctx)
    try:
        with one_shot_session(settings, True) as session:
            return list(question(MeshClient(session, settings)))
    except (Problem, Exception):  # noqa: BLE001 - completion offers nothing rather than a traceback
        return []


def things(ctx: click.Context, param: click.Parameter, incomplete: str) -> list[CompletionItem]:
    return [CompletionItem(n) for n in _ask(ctx, lambda c: c.things()) if n.startswith(incomplete)]


def _affordances(kind: str, only: Any = None):
    def complete(ctx: click.Context, param: click.Parameter, incomplete: str) -> list[CompletionItem]:
        thing = ctx.params.get("thing")
        if not thing:
            return []

        def names(c):
            td = c.td(thing)
            return [n for n, a in getattr(td, kind).items() if only is None or only(a)]
        return [CompletionItem(n) for n in _ask(ctx, names) if n.startswith(incomplete)]
    return complete


properties = _affordances("properties")
writable_properties = _affordances("properties", lambda p: not p.readOnly)
observable_properties = _affordances("properties", lambda p: bool(p.observable))
actions = _affordances("actions")
events = _affordances("events")
