"""What every route needs from a request: the registry, the security, the base URL, the affordance.

Kept apart from `app.py` so that the route modules do not import the app factory that imports them.
"""
from __future__ import annotations

from typing import Any

from starlette.requests import Request

from mesh.http.credentials import Auth
from mesh.http.gateway import Registry
from mesh.wot.names import SLUG, unescaped
from mesh.wot.problem import NotFound
from mesh.wot.thing_description import NOSEC, AffordanceKind, Security, ThingDescription


def registry(request: Request) -> Registry:
    return request.app.state.registry


def security(request: Request) -> Security:
    auth: Auth | None = request.app.state.auth
    return auth.security() if auth else NOSEC


def base_url(request: Request) -> str:
    """`http://host:port` as the client reached us (so hrefs work from wherever the TD was fetched)."""
    return str(request.base_url).rstrip("/")


def thing_name(request: Request) -> str:
    thing = request.path_params["thing"]
    if not SLUG.match(thing):
        raise NotFound(f"no Thing {thing!r} on the mesh (Thing names are slugs)")
    return thing


async def thing_td(request: Request) -> tuple[str, ThingDescription]:
    """(name, mesh TD) of the Thing in the path: 404 unknown, 503 gone."""
    thing = thing_name(request)
    return thing, await registry(request).td(thing)


async def affordance(request: Request, kind: AffordanceKind) -> tuple[str, str, Any]:
    """(thing, name, affordance) for `/{thing}/{kind}/{name}...`: 404 when the TD has no such affordance."""
    thing, td = await thing_td(request)
    name = unescaped(request.path_params["name"])
    found = td.affordance(kind, name)
    if found is None:
        raise NotFound(td.no_such(thing, kind, name))
    return thing, name, found
