"""Problems: errors that cross the mesh as `{type,title,status,detail}` and map 1:1 to HTTP.

Raise a `Problem` (or a subclass) anywhere; the Thing runtime turns it into an error reply, the
consumer turns an error reply back into the same `Problem`, and the HTTP adapter maps it to an
`application/problem+json` response in exactly one place.
"""
from __future__ import annotations

import msgspec

PROBLEM_BASE = "https://twinmesh.dev/problems/"
UNREACHABLE = "unreachable"  # the `reason` of a 503/504 whose server never answered (no connection, no answer in time)


class ProblemDetails(msgspec.Struct, omit_defaults=True):
    """The wire form (RFC 9457 members we use)."""

    type: str
    title: str
    status: int
    detail: str = ""
    instance: str | None = None
    reason: str | None = None  # machine-readable refusal reason, e.g. "outside-workspace"
    extra: dict | None = None


class Problem(Exception):
    """An error a client should see, with the HTTP status it maps to."""

    status = 500
    slug = "internal-error"
    title = "Internal error"

    def __init__(self, detail: str = "", *, reason: str | None = None, extra: dict | None = None,
                 status: int | None = None, slug: str | None = None, title: str | None = None):
        super().__init__(detail or self.title)
        self.detail = detail
        self.reason = reason
        self.extra = extra
        if status is not None:
            self.status = status
        if slug is not None:
            self.slug = slug
        if title is not None:
            self.title = title

    def details(self) -> ProblemDetails:
        return ProblemDetails(type=PROBLEM_BASE + self.slug, title=self.title, status=self.status,
                              detail=self.detail, reason=self.reason, extra=self.extra)

    def to_json(self) -> bytes:
        return msgspec.json.encode(self.details())

    @classmethod
    def from_json(cls, data: bytes) -> "Problem":
        """Rebuild the problem a peer replied with; unreadable replies become a 502."""
        try:
            d = msgspec.json.decode(data, type=ProblemDetails)
        except msgspec.DecodeError:
            return BadGateway(f"peer replied with an unreadable error: {data[:200]!r}")
        slug = d.type.removeprefix(PROBLEM_BASE)
        cls_ = _BY_STATUS.get(d.status, Problem)
        return cls_(d.detail, reason=d.reason, extra=d.extra, status=d.status, slug=slug, title=d.title)

    def __str__(self) -> str:
        return f"{self.title}: {self.detail}" if self.detail else self.title


class BadInput(Problem):
    status, slug, title = 400, "bad-input", "Invalid input"


class Unauthorized(Problem):
    status, slug, title = 401, "unauthorized", "Unauthorized"


class NotFound(Problem):
    status, slug, title = 404, "not-found", "Not found"


class NotAllowed(Problem):
    status, slug, title = 405, "method-not-allowed", "Operation not allowed"


class Conflict(Problem):
    """The request is fine but the resource's state does not allow it (an action that has already ended)."""

    status, slug, title = 409, "conflict", "Conflict with the current state"


class Refused(Problem):
    """The input is well-formed but the device cannot do it (unreachable, empty warehouse...)."""

    status, slug, title = 422, "refused", "Request refused by the device"


class Unavailable(Problem):
    status, slug, title = 503, "unavailable", "Thing unavailable"


class TimedOut(Problem):
    status, slug, title = 504, "timeout", "Thing did not answer in time"


class BadGateway(Problem):
    status, slug, title = 502, "bad-gateway", "Bad reply from the mesh"


_BY_STATUS: dict[int, type[Problem]] = {
    c.status: c for c in (BadInput, Unauthorized, NotFound, NotAllowed, Conflict, Refused, Unavailable, TimedOut, BadGateway)
}
