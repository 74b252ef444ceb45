"""The Starlette app of the WoT HTTP adapter: routes by affordance kind, problems, auth, CORS.

The app does not own the Zenoh session: it is given a `Registry` (built on an open session) and
starts/stops it with its lifespan, so the server decides when the session opens and closes.
"""
from __future__ import annotations

import re
from contextlib import asynccontextmanager
from typing import AsyncIterator
from urllib.parse import unquote

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.cors import CORSMiddleware
from starlette.types import ASGIApp, Receive, Scope, Send

from mesh.http import actions, events, properties, things
from mesh.http.auth import AuthMiddleware
from mesh.http.credentials import Auth
from mesh.http.fast_reads import FastReads
from mesh.http.gateway import Registry
from mesh.http.problems import exception_handlers


def create_app(registry: Registry, auth: Auth | None = None, view: str | None = None) -> Starlette:
    """Discovery routes first (`/things` must not be taken for a Thing named `things`)."""

    @asynccontextmanager
    async def lifespan(app: Starlette) -> AsyncIterator[None]:
        await registry.start()
        try:
            yield
        finally:
            registry.begin_shutdown()
            await registry.close()

    # CORS outermost: browsers' preflights carry no credentials and must not meet a 401
    middleware = [Middleware(CORSMiddleware, allow_origins=["*"], allow_methods=["*"], allow_headers=["*"],
                             expose_headers=["Location", "Link", "Retry-After", "WWW-Authenticate"])]
    if auth is not None:
        middleware.append(Middleware(AuthMiddleware, auth=auth))
    app = Starlette(routes=[*things.routes_top, *properties.routes, *actions.routes, *events.routes,
                            *things.routes_thing],
                    middleware=middleware, exception_handlers=exception_handlers(), lifespan=lifespan)
    app.state.registry = registry
    app.state.auth = auth
    app.state.view = view  # the URL of the live 3D view, when one is served
    return app


def create_asgi(registry: Registry, auth: Auth | None = None, view: str | None = None) -> ASGIApp:
    """The app behind its hot path (`fast_reads`) and the escaped names' paths: what the adapter serves."""
    return EscapedSlashes(FastReads(create_app(registry, auth, view), registry, auth))


class EscapedSlashes:
    """`/{thing}/properties/a%2Fb` routes to the affordance `a/b`: the server decodes the path before
    routing (`a/b` would be two segments), so where the raw path escapes a `/` (or a `%`), the path is
    decoded again from it keeping those two escaped; `mesh.http.context` and the hot path unescape the
    name. A path without `%` is left as the server gave it."""

    def __init__(self, app: ASGIApp):
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        raw = scope.get("raw_path")
        if scope["type"] in ("http", "websocket") and raw and b"%" in raw:
            path = raw.split(b"?", 1)[0].decode("latin-1")
            kept = re.sub(r"%(2[fF]|25)", lambda m: "\x00" + m.group(1).upper(), path)
            scope = {**scope, "path": unquote(kept).replace("\x00", "%")}
        await self.app(scope, receive, send)
