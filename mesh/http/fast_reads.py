"""The hot path: a read of a fresh cached property answered before routing.

A WoT client polling a property asks `GET /{thing}/properties/{name}` again and again; when the
registry holds a fresh published value (`Registry.cached`: the same rule as `Registry.read`), the
answer is those bytes. This pure ASGI layer sends them without Starlette's routing, middleware
stack and Response objects, which cost more than the rest of the request. Anything else (a query
string, a browser's `Origin`, credentials that do not match, a value not cached) goes the full way,
so behaviour is the same; only the time differs (tests/bench/bench_http_load.py).
"""
from __future__ import annotations

from starlette.types import ASGIApp, Receive, Scope, Send

from mesh.http.credentials import Auth
from mesh.http.gateway import Registry
from mesh.wot.names import unescaped

_HEADERS = [(b"content-type", b"application/json"), (b"vary", b"Origin")]


class FastReads:
    def __init__(self, app: ASGIApp, registry: Registry, auth: Auth | None):
        self.app, self.registry, self.auth = app, registry, auth

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and scope["method"] == "GET" and not scope["query_string"]:
            parts = scope["path"].split("/")
            if len(parts) == 4 and parts[2] == "properties" and self._plain(scope):
                payload = self.registry.cached(parts[1], unescaped(parts[3]))
                if payload is not None:
                    await send({"type": "http.response.start", "status": 200,
                                "headers": [*_HEADERS, (b"content-length", str(len(payload)).encode())]})
                    await send({"type": "http.response.body", "body": payload})
                    return
        await self.app(scope, receive, send)

    def _plain(self, scope: Scope) -> bool:
        """No browser origin (CORS headers are the middleware's), and the credentials, if any are needed."""
        authorization = None
        for key, value in scope["headers"]:
            if key == b"origin":
                return False
            if key == b"authorization":
                authorization = value.decode("latin-1")
        return self.auth is None or self.auth.accepts(authorization)
