"""Event routes: subscribeevent as long-poll and as SSE, and subscribeallevents.

| route | op |
|---|---|
| `HEAD, GET /{thing}/events/{name}` | subscribeevent, long-poll (GET blocks until the next event) |
| `GET /{thing}/events/{name}/sse` | subscribeevent, SSE (unnamed events) |
| `GET /{thing}/events` (`Accept: text/event-stream`) | subscribeallevents, SSE (`event: <name>`) |
"""
from __future__ import annotations

from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from mesh.http.context import affordance, registry, thing_td
from mesh.http.streams import EventStream, long_poll


async def subscribe_long_poll(request: Request) -> Response:
    thing, name, _ = await affordance(request, "events")
    return await long_poll(request, registry(request), thing, "events", name)


async def subscribe_sse(request: Request) -> Response:
    thing, name, _ = await affordance(request, "events")
    return EventStream(registry(request).watch(thing, "events", [name]), named=False)


async def subscribe_all(request: Request) -> Response:
    thing, td = await thing_td(request)
    return EventStream(registry(request).watch(thing, "events", list(td.events)), named=True)


routes = [
    Route("/{thing}/events", subscribe_all, methods=["GET"]),
    Route("/{thing}/events/{name}", subscribe_long_poll, methods=["GET"]),
    Route("/{thing}/events/{name}/sse", subscribe_sse, methods=["GET"]),
]
