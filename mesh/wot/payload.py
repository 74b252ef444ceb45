"""JSON from outside: every byte string a client or a peer sends becomes a value or a BadInput, never a 5xx.

msgspec raises more than `DecodeError` on hostile input: `RecursionError` for arrays nested about a
thousand deep, `UnicodeDecodeError` for invalid UTF-8 inside a string, `ValidationError` for a
number beyond a double. All of them mean the same to a client: its payload is not usable JSON.
"""
from __future__ import annotations

from typing import Any

import msgspec

from mesh.wot.problem import BadInput

JSON_ERRORS = (msgspec.DecodeError, msgspec.ValidationError, RecursionError, UnicodeDecodeError)


def decode_json(payload: bytes, what: str) -> Any:
    """The JSON value of `payload`, or BadInput saying what about `what` was wrong."""
    try:
        return msgspec.json.decode(payload)
    except RecursionError:
        raise BadInput(f"{what} is nested too deeply to be read") from None
    except UnicodeDecodeError:
        raise BadInput(f"{what} is not valid UTF-8") from None
    except (msgspec.DecodeError, msgspec.ValidationError) as e:
        raise BadInput(f"{what} is not valid JSON ({e})") from None
