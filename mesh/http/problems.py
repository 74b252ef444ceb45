"""The one place where errors become HTTP responses: RFC 9457 `application/problem+json`.

Routes raise `mesh.wot.problem.Problem`s (the same ones that cross the mesh, so a device's 422 comes out
as a 422); Starlette's own 404/405 and unexpected exceptions are mapped here too, so every error a
client sees has the same shape. Problems that need response headers (`Allow` on 405,
`WWW-Authenticate` on 401, `Retry-After` on 503) carry them in a `headers` attribute.
"""
from __future__ import annotations

import logging
from typing import Mapping

import msgspec
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import Response

from mesh.wot.problem import NotAllowed, NotFound, Problem, Unavailable

log = logging.getLogger(__name__)

PROBLEM_JSON = "application/problem+json"


class TooLarge(Problem):
    status, slug, title = 413, "too-large", "Request body too large"


class UnsupportedMediaType(Problem):
    status, slug, title = 415, "unsupported-media-type", "Unsupported media type"


def with_headers(problem: Problem, headers: Mapping[str, str]) -> Problem:
    """Attach response headers to a problem (kept off the JSON body)."""
    problem.headers = dict(headers)  # type: ignore[attr-defined]
    return problem


def method_not_allowed(detail: str, allow: list[str]) -> Problem:
    """405 with the `Allow` header HTTP requires."""
    return with_headers(NotAllowed(detail), {"Allow": ", ".join(allow)})


def unavailable(detail: str, retry_after: int | None = None) -> Problem:
    p = Unavailable(detail)
    return with_headers(p, {"Retry-After": str(retry_after)}) if retry_after else p


def problem_response(problem: Problem, instance: str | None = None) -> Response:
    """The response for a problem; `instance` (the request path) says where it happened."""
    details = problem.details()
    if details.instance is None and instance:
        details.instance = instance
    headers = dict(getattr(problem, "headers", None) or {})
    return Response(msgspec.json.encode(details), status_code=problem.status, headers=headers,
                    media_type=PROBLEM_JSON)


async def _on_problem(request: Request, exc: Exception) -> Response:
    assert isinstance(exc, Problem)
    return problem_response(exc, request.url.path)


async def _on_http_exception(request: Request, exc: Exception) -> Response:
    """Starlette's routing errors (no such path, wrong method) as problems."""
    assert isinstance(exc, HTTPException)
    if exc.status_code == 404:
        problem: Problem = NotFound(f"nothing at {request.url.path}")
    elif exc.status_code == 405:
        problem = NotAllowed(f"{request.method} is not allowed on {request.url.path}")
    else:
        problem = Problem(exc.detail or "", status=exc.status_code, slug=f"http-{exc.status_code}",
                          title=exc.detail or "HTTP error")
    if exc.headers:
        with_headers(problem, exc.headers)
    return problem_response(problem, request.url.path)


async def _on_error(request: Request, exc: Exception) -> Response:
    """A bug in the adapter still answers in the documented shape (and is logged with its traceback)."""
    log.error("%s %s failed", request.method, request.url.path, exc_info=exc)
    return problem_response(Problem(f"{type(exc).__name__}: {exc}"), request.url.path)


def exception_handlers() -> dict:
    """For `Starlette(exception_handlers=...)`."""
    return {Problem: _on_problem, HTTPException: _on_http_exception, Exception: _on_error}
