"""`twinmesh bridge`: take in every remote Thing's TD first (one that cannot be had starts none), then
serve each on the mesh, each on its own session, until stopped."""
from __future__ import annotations

import logging
import threading
from contextlib import ExitStack
from dataclasses import dataclass
from typing import Any

from mesh.bridge.bridged import BridgedThing
from mesh.bridge.intake import IntakeError, take_in
from mesh.bridge.remote import RemoteThing
from mesh.fabric.keys import check_slug
from mesh.fabric.settings import MeshSettings
from mesh.http.http_client import HttpClient

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class Remote:
    """What to bridge: the name on the mesh, the TD's URL, and how to talk to it."""

    name: str
    url: str


@dataclass(frozen=True)
class Access:
    """Credentials and certificate checks for the remote Things (one set for all of them)."""

    auth: str | None = None     # basic:USER:PASS or bearer:TOKEN, sent with the TD fetch and every interaction
    verify: bool | str = True   # True, a CA file, or False (--insecure)
    timeout: float = 10.0

    def client(self) -> HttpClient:
        return HttpClient(self.auth, timeout=self.timeout, verify=self.verify, longpoll=True)


def parse_remote(spec: str) -> Remote:
    """`NAME=URL` (ValueError naming the problem otherwise)."""
    name, sep, url = spec.partition("=")
    if not sep or not url:
        raise ValueError(f"{spec!r} is not NAME=URL")
    check_slug(name)
    if url.split(":", 1)[0].lower() not in ("http", "https"):
        raise ValueError(f"{name}: {url!r} is not an http(s) URL")
    return Remote(name, url)


def take_in_all(remotes: list[Remote], client: HttpClient) -> list[tuple[Remote, RemoteThing, dict[str, Any]]]:
    """Every remote Thing's TD, or IntakeError for the first that cannot be had."""
    names = [r.name for r in remotes]
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise IntakeError(f"{', '.join(twice)}: the same name given twice")
    found = []
    for remote in remotes:
        td = take_in(remote.url, client)
        found.append((remote, RemoteThing(td, client, remote.url), td))
    return found


def on_mesh(session, settings: MeshSettings, name: str) -> bool:
    """Whether a Thing `name` is alive on the mesh already."""
    replies = session.liveliness().get(settings.keys.alive(name), timeout=2.0)
    return any(r.ok is not None for r in replies)


def serve(settings: MeshSettings, stop: threading.Event, found: list[tuple[Remote, RemoteThing, dict[str, Any]]],
          poll: float = 1.0, ready: Any = None) -> None:
    """Serve the taken-in Things until `stop`; `ready()` is called once all are on the mesh."""
    from mesh.fabric.session import open_session

    with ExitStack() as stack:
        for remote, thing, td in found:
            session = stack.enter_context(open_session(settings, thing=remote.name))
            if on_mesh(session, settings, remote.name):
                raise IntakeError(f"{remote.name}: a Thing of that name is already on the mesh; bridge "
                                  f"{remote.url} under another NAME")
            stack.enter_context(BridgedThing(session, remote.name, thing, td, settings.keys, poll=poll))
            log.info("bridged %s (%s) from %s", remote.name, thing.title, remote.url)
        if ready is not None:
            ready()
        stop.wait()
