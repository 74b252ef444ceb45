"""The Starlette app of the WoT HTTP adapter: routes by affordance kind, problems, auth, CORS.

The app does not own the Zenoh session: it is given a `Registry` (built on an open session) and
starts/stops it with its lifespan, so the server decides when the session opens and closes.
"""
from __future__ import annotations

from contextlib import asynccontextmanager
from typing import AsyncIterator

from starlette.applications import Starlette
from starlette.middleware import Middleware
from starlette.middleware.cors import CORSMiddleware
from starlette.types import ASGIApp

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
    """The app behind its hot path (`fast_reads`): what the adapter serves."""
    return FastReads(create_app(registry, auth, view), registry, auth)
