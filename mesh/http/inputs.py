"""Request bodies: size-limited, JSON, validated against the affordance's schema before the mesh sees them.

Chunked bodies (node-wot sends `Transfer-Encoding: chunked`) are read as a stream and counted as
they arrive; a body over the limit is refused with 413 as soon as it is known to be too large (at
once from `Content-Length`, else at the chunk that crosses the limit), never buffered whole.
"""
from __future__ import annotations

from typing import Any

import msgspec
from starlette.requests import Request

from mesh.http.problems import TooLarge, UnsupportedMediaType
from mesh.wot.payload import decode_json
from mesh.wot.validate import Schema, validate

MAX_BODY = 1 << 20  # 1 MiB: the largest input any affordance of ours needs is a few hundred bytes

ABSENT = object()  # no body at all, distinct from a JSON null


def _is_json(content_type: str) -> bool:
    media = content_type.split(";", 1)[0].strip().lower()
    return media in ("application/json", "text/json") or media.endswith("+json")


async def read_body(request: Request, limit: int = MAX_BODY) -> bytes:
    declared = request.headers.get("content-length")
    if declared is not None and declared.isdigit() and int(declared) > limit:
        raise TooLarge(f"the body has {int(declared)} bytes; the limit is {limit}")
    chunks, size = [], 0
    async for chunk in request.stream():
        size += len(chunk)
        if size > limit:
            raise TooLarge(f"the body is over the limit of {limit} bytes")
        chunks.append(chunk)
    return b"".join(chunks)


async def read_input(request: Request, schema: Schema, path: str) -> Any:
    """The validated JSON value of the body, or ABSENT when the body is empty."""
    body = await read_body(request)
    if not body.strip():  # nothing to decode: whatever the content type says (curl -d '' sends a form type)
        return ABSENT
    content_type = request.headers.get("content-type")
    if content_type and not _is_json(content_type):
        raise UnsupportedMediaType(f"send application/json, not {content_type}")
    value = decode_json(body, f"{path}: the body")
    validate(value, schema, path)
    return value


def encode(value: Any) -> bytes:
    """The payload sent on the mesh: re-encoded, so only what was validated travels."""
    return msgspec.json.encode(value)
