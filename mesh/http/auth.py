"""Optional HTTP security: one `bearer` token or one `basic` user/password for the whole adapter.

What is protected: every affordance (properties, actions, events, both long-poll and SSE) and the
linked files. What stays public: discovery, i.e. the TDs (`/{thing}`, `/things`, `/things/{id}`,
`/.well-known/wot`, `/`), because a WoT client fetches a TD before it knows which credentials to
use (node-wot looks credentials up by the TD's `id`) and the TDs are what declare the scheme; and
the control page's own files (`/_ui/...`), which ask for the credentials and then send them.

SSE and auth: node-wot 0.9.2's SSE client (the `eventsource` package) sends no Authorization
header, so with auth on, node-wot can only observe over long-poll; that is why the long-poll form
comes first in every TD (node-wot picks the first matching form). The SSE endpoints are NOT
exempted: an exemption would leak every value to anyone. Clients that can set headers (browsers'
fetch-based SSE, curl, httpx) use SSE with credentials as usual.
"""
from __future__ import annotations

from starlette.types import ASGIApp, Receive, Scope, Send

from mesh.http.credentials import Auth
from mesh.http.problems import problem_response, with_headers
from mesh.wot.problem import Unauthorized


def is_public(path: str) -> bool:
    """Discovery paths: the TDs and the directory, and the control page (see the module docstring)."""
    segments = [s for s in path.split("/") if s]
    return len(segments) <= 1 or segments[0] in ("things", ".well-known", "events", "_ui")


class AuthMiddleware:
    """Pure ASGI middleware: 401 problem+json with `WWW-Authenticate` unless the credentials match.

    Runs inside the CORS middleware, so browsers' preflight requests (which carry no credentials)
    are answered before they get here.
    """

    def __init__(self, app: ASGIApp, auth: Auth):
        self.app = app
        self.auth = auth

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or is_public(scope["path"]):
            await self.app(scope, receive, send)
            return
        header = next((v.decode("latin-1") for k, v in scope["headers"] if k == b"authorization"), None)
        if self.auth.accepts(header):
            await self.app(scope, receive, send)
            return
        detail = "credentials required" if header is None else "wrong credentials"
        challenge = self.auth.challenge()
        if any(k == b"x-requested-with" for k, _ in scope["headers"]):
            # a script asks (the control page): a `Basic` challenge would make the browser open its own
            # login dialog over the page's form, so the scheme is named so that no browser knows it
            challenge = "X-Page-" + challenge
        problem = with_headers(Unauthorized(f"{detail} ({self.auth.scheme}, see the TD's securityDefinitions)"),
                               {"WWW-Authenticate": challenge})
        await problem_response(problem, scope["path"])(scope, receive, send)
