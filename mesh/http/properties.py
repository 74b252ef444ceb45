"""Property routes: readproperty GET, writeproperty PUT, readallproperties, observeproperty (long-poll, SSE).

| route | op |
|---|---|
| `GET /{thing}/properties` | readallproperties (object by name) |
| `GET /{thing}/properties?names=a,b` | readmultipleproperties (those, by name) |
| `PUT /{thing}/properties` | writemultipleproperties / writeallproperties (object by name, 204): every value is validated
  first, and written in order; if a device refuses one, those written before get their old values back |
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

from mesh.http.context import affordance, registry, thing_td
from mesh.http.inputs import ABSENT, encode, read_input
from mesh.http.problems import method_not_allowed
from mesh.http.streams import EventStream, long_poll
from mesh.wot.problem import BadInput, NotFound
from mesh.wot.thing_description import JSON, DataSchema, PropertyAffordance
from mesh.wot.validate import validate


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
    value = await read_input(request, registry(request).schemas(thing).of(prop, "properties", name), name)
    if value is ABSENT:
        raise BadInput(f"{name}: a value is required")
    await registry(request).write(thing, name, encode(value))
    return Response(status_code=204)


async def one_property(request: Request) -> Response:
    """One route for both methods, so that a 405 lists them all in `Allow`."""
    return await (write_property if request.method == "PUT" else read_property)(request)


async def all_properties(request: Request) -> Response:
    if request.method == "PUT":
        return await write_properties(request)
    thing, td = await thing_td(request)
    reg = registry(request)
    if wants_event_stream(request):
        names = [n for n, p in td.properties.items() if p.observable]
        return EventStream(reg.watch(thing, "properties", names), named=True)
    readable = [n for n, p in td.properties.items() if not p.writeOnly]
    names = _named(request, thing, td.properties, readable) or readable
    values = await asyncio.gather(*(reg.read(thing, n) for n in names))
    body = b",".join(msgspec.json.encode(n) + b":" + (v or b"null") for n, v in zip(names, values))
    return Response(b"{" + body + b"}", media_type=JSON)


def _named(request: Request, thing: str, props: dict[str, PropertyAffordance], readable: list[str]) -> list[str]:
    """readmultipleproperties: the names of `?names=a,b` (none: all), each one the Thing reads."""
    raw = request.query_params.get("names")
    if raw is None:
        return []
    names = list(dict.fromkeys(n for n in raw.split(",") if n))
    unknown = [n for n in names if n not in props]
    if unknown or not names:
        raise BadInput(f"names: {thing} has no property {', '.join(map(repr, unknown)) or '(none given)'} "
                       f"(it has {', '.join(props)})")
    unreadable = [n for n in names if n not in readable]
    if unreadable:
        raise BadInput(f"names: {', '.join(map(repr, unreadable))} of {thing} cannot be read (write-only)")
    return names


async def write_properties(request: Request) -> Response:
    """writemultipleproperties / writeallproperties: all or nothing."""
    thing, td = await thing_td(request)
    value = await read_input(request, DataSchema(type="object"), "properties")
    if value is ABSENT or not value:
        raise BadInput("properties: an object of property names and their new values is required")
    unknown = [n for n in value if n not in td.properties]
    if unknown:
        raise BadInput(f"properties: {thing} has no property {', '.join(map(repr, unknown))} "
                       f"(it has {', '.join(td.properties)})")
    read_only = [n for n in value if td.properties[n].readOnly]
    if read_only:
        raise BadInput(f"properties: {', '.join(map(repr, read_only))} of {thing} cannot be written (read-only)")
    for name, v in value.items():  # every value checked before any is written
        validate(v, registry(request).schemas(thing).of(td.properties[name], "properties", name), name)
    reg = registry(request)
    before = {n: await reg.read(thing, n) for n in value if not td.properties[n].writeOnly}
    written: list[str] = []
    try:
        for name, v in value.items():
            await reg.write(thing, name, encode(v))
            written.append(name)
    except Exception:
        for name in reversed(written):  # put back what was written before the refusal
            if name in before:
                try:
                    await reg.write(thing, name, before[name])
                except Exception:  # noqa: BLE001 - the refusal is what the client must hear
                    pass
        raise
    return Response(status_code=204)


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
    Route("/{thing}/properties", all_properties, methods=["GET", "PUT"]),
    Route("/{thing}/properties/{name}", one_property, methods=["GET", "PUT"]),
    Route("/{thing}/properties/{name}/observable", observe_long_poll, methods=["GET"]),
    Route("/{thing}/properties/{name}/sse", observe_sse, methods=["GET"]),
]
