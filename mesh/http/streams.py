"""Observation over HTTP, shared by properties and events: long-poll and Server-Sent Events.

Long-poll (node-wot's default): `HEAD` answers 200 at once (node-wot's handshake, 1 s timeout);
each `GET` blocks until the next change and returns it as the body. A GET never answers with an
old value: a client that re-polls at once would otherwise spin.

SSE: one stream per request, registered before the response headers go out (so a client that
saw the stream open sees every later change). Frames are `id: <ISO time>` + `data: <JSON>`; on
per-affordance streams the events are unnamed, the only kind node-wot (`EventSource.onmessage`)
delivers; on the Thing-level streams (observeallproperties / subscribeallevents, the W3C WoT
Profile's style) each carries `event: <affordance name>`, which is what tells them apart. A
comment every 15 s keeps proxies from timing the stream out.

Both end cleanly: on client disconnect (a task watches `http.disconnect`), when the Thing leaves
(a GET gets 503, a stream ends) and when the adapter shuts down (`Registry.begin_shutdown`).
"""
from __future__ import annotations

import asyncio
from contextlib import AbstractContextManager
from datetime import datetime, timezone
from typing import Awaitable, TypeVar

import anyio
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import Receive, Scope, Send

from mesh.http.gateway import Registry
from mesh.http.observers import Change, Feed
from mesh.wot.problem import Problem
from mesh.wot.thing_description import JSON

T = TypeVar("T")
KEEPALIVE = 15.0
RETRY_MS = 2000


async def _disconnected(receive: Receive) -> None:
    while (await receive())["type"] != "http.disconnect":
        pass


async def _unless_disconnected(request: Request, awaitable: Awaitable[T]) -> T | None:
    """The awaitable's result, or None as soon as the client goes away (the wait is cancelled)."""
    work = asyncio.ensure_future(awaitable)
    gone = asyncio.ensure_future(_disconnected(request.receive))
    try:
        await asyncio.wait({work, gone}, return_when=asyncio.FIRST_COMPLETED)
    finally:
        gone.cancel()
        if not work.done():
            work.cancel()
    return work.result() if work.done() and not work.cancelled() else None


async def long_poll(request: Request, registry: Registry, thing: str, kind: str, name: str) -> Response:
    """Call after checking the Thing and the affordance exist (`Registry.td`)."""
    if request.method == "HEAD":
        return Response(status_code=200, media_type=JSON)
    with registry.watch(thing, kind, [name]) as feed:
        change = await _unless_disconnected(request, feed.next())
    if change is None:  # nobody is listening any more
        return Response(status_code=204)
    return Response(change.payload, media_type=JSON, headers={"Cache-Control": "no-store"})


def frame(change: Change, named: bool) -> bytes:
    """One SSE event; multi-line JSON (pretty-printed by some device) becomes several data lines."""
    when = datetime.fromtimestamp(change.at, timezone.utc).isoformat(timespec="milliseconds")
    head = (f"event: {change.name}\n" if named else "") + f"id: {when.replace('+00:00', 'Z')}\n"
    data = b"".join(b"data: " + line + b"\n" for line in change.payload.splitlines() or [b"null"])
    return head.encode() + data + b"\n"


class EventStream(Response):
    """A `text/event-stream` response fed by a registry feed (see the module docstring)."""

    media_type = "text/event-stream"

    def __init__(self, watch: AbstractContextManager[Feed], named: bool, keepalive: float = KEEPALIVE):
        self.watch = watch
        self.named = named
        self.keepalive = keepalive
        self.status_code = 200
        self.background = None
        self.init_headers({"Cache-Control": "no-store", "X-Accel-Buffering": "no"})

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        with self.watch as feed:  # registered before the headers go out
            await send({"type": "http.response.start", "status": self.status_code, "headers": self.raw_headers})
            await send({"type": "http.response.body", "body": f"retry: {RETRY_MS}\n\n".encode(), "more_body": True})
            async with anyio.create_task_group() as tg:
                async def until_disconnected() -> None:
                    await _disconnected(receive)
                    tg.cancel_scope.cancel()

                tg.start_soon(until_disconnected)
                await self._pump(feed, send)
                tg.cancel_scope.cancel()
        try:
            await send({"type": "http.response.body", "body": b"", "more_body": False})
        except OSError:
            pass

    async def _pump(self, feed: Feed, send: Send) -> None:
        try:
            while True:
                with anyio.move_on_after(self.keepalive) as waited:
                    change = await feed.next()
                body = b": keep-alive\n\n" if waited.cancelled_caught else frame(change, self.named)
                await send({"type": "http.response.body", "body": body, "more_body": True})
        except Problem:  # the Thing left, or the adapter is shutting down: end the stream
            return
        except OSError:  # the client went away mid-write
            return
