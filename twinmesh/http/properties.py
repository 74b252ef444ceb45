"""Property routes: readproperty GET, writeproperty PUT, readallproperties, observeproperty (long-poll, SSE).

| route | op |
|---|---|
| `GET /{thing}/properties` | readallproperties (object by name) |
| same, `Accept: text/event-stream` | observeallproperties (SSE, `event: <name>`) |
| `GET /{thing}/properties/{name}` | readproperty (200 JSON) |
| `PUT /{thing}/properties/{name}` | writeproperty (204), validated before the mesh sees it |
| `HEAD, GET /{thing}/properties/{name}/observable` | observeproperty, long-poll |
| `GET /{thing}/properties/{name}/sse` | observeproperty, SSE (unnamed events) |
"""
from __future__ import annotations

import asyncio

import msgspec
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from twinmesh.http.context import affordance, registry, thing_td
from twinmesh.http.inputs import ABSENT, encode, read_input
from twinmesh.http.problems import method_not_allowed
from twinmesh.http.streams import EventStream, long_poll
from twinmesh.wot.problem import BadInput, NotFound
from twinmesh.wot.td import JSON, PropertyAffordance


def wants_event_stream(request: Request) -> bool:
    return "text/event-stream" in request.headers.get("accept", "")


async def read_property(request: Request) -> Response:
    thing, name, prop = await affordance(request, "properties")
    if prop.writeOnly:
        raise method_not_allowed(f"property {name!r} of {thing} is write-only", ["PUT"])
    return Response(await registry(request).read(thing, name), media_type=JSON)


async def write_property(request: Request) -> Response:
    thing, name, prop = await affordance(request, "properties")
    if prop.readOnly:
        raise method_not_allowed(f"property {name!r} of {thing} is read-only", ["GET", "HEAD"])
    value = await read_input(request, prop, name)
    if value is ABSENT:
        raise BadInput(f"{name}: a value is required")
    await registry(request).write(thing, name, encode(value))
    return Response(status_code=204)


async def one_property(request: Request) -> Response:
    """One route for both methods, so that a 405 lists them all in `Allow`."""
    return await (write_property if request.method == "PUT" else read_property)(request)


async def all_properties(request: Request) -> Response:
    thing, td = await thing_td(request)
    reg = registry(request)
    if wants_event_stream(request):
        names = [n for n, p in td.properties.items() if p.observable]
        return EventStream(reg.watch(thing, "properties", names), named=True)
    names = [n for n, p in td.properties.items() if not p.writeOnly]
    values = await asyncio.gather(*(reg.read(thing, n) for n in names))
    body = b",".join(msgspec.json.encode(n) + b":" + (v or b"null") for n, v in zip(names, values))
    return Response(b"{" + body + b"}", media_type=JSON)


async def _observable(request: Request) -> tuple[str, str, PropertyAffordance]:
    thing, name, prop = await affordance(request, "properties")
    if not prop.observable:
        raise NotFound(f"property {name!r} of {thing} is not observable")
    return thing, name, prop


async def observe_long_poll(request: Request) -> Response:
    thing, name, _ = await _observable(request)
    return await long_poll(request, registry(request), thing, "properties", name)


async def observe_sse(request: Request) -> Response:
    thing, name, _ = await _observable(request)
    return EventStream(registry(request).watch(thing, "properties", [name]), named=False)


routes = [
    Route("/{thing}/properties", all_properties, methods=["GET"]),
    Route("/{thing}/properties/{name}", one_property, methods=["GET", "PUT"]),
    Route("/{thing}/properties/{name}/observable", observe_long_poll, methods=["GET"]),
    Route("/{thing}/properties/{name}/sse", observe_sse, methods=["GET"]),
]
