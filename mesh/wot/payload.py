"""JSON from outside: every byte string a client or a peer sends becomes a value or a BadInput, never a 5xx.

msgspec raises more than `DecodeError` on hostile input: `RecursionError` for arrays nested about a
thousand deep (on CPython 3.11; from 3.12 on it decodes them, and the validators after it would
recurse instead, so the depth is bounded here, the same on every Python), `UnicodeDecodeError` for
invalid UTF-8 inside a string, `ValidationError` for a number beyond a double. All of them mean the
same to a client: its payload is not usable JSON.
"""
from __future__ import annotations

from typing import Any

import msgspec

from mesh.wot.problem import BadInput

JSON_ERRORS = (msgspec.DecodeError, msgspec.ValidationError, RecursionError, UnicodeDecodeError)
MAX_DEPTH = 128  # arrays and objects inside each other: the deepest value an affordance of ours takes is a few


def _deeper_than(value: Any, limit: int) -> bool:
    """Whether `value` nests arrays/objects more than `limit` deep (iterative: no recursion to exhaust)."""
    stack = [(value, 1)]
    while stack:
        v, depth = stack.pop()
        if isinstance(v, (list, dict)):
            if depth > limit:
                return True
            stack.extend((x, depth + 1) for x in (v.values() if isinstance(v, dict) else v))
    return False


def decode_json(payload: bytes, what: str) -> Any:
    """The JSON value of `payload`, or BadInput saying what about `what` was wrong."""
    try:
        value = msgspec.json.decode(payload)
    except RecursionError:
        raise BadInput(f"{what} is nested too deeply to be read") from None
    except UnicodeDecodeError:
        raise BadInput(f"{what} is not valid UTF-8") from None
    except (msgspec.DecodeError, msgspec.ValidationError) as e:
        raise BadInput(f"{what} is not valid JSON ({e})") from None
    if payload.count(b"[") + payload.count(b"{") > MAX_DEPTH and _deeper_than(value, MAX_DEPTH):
        raise BadInput(f"{what} is nested too deeply to be read (more than {MAX_DEPTH} levels)")
    return value
