"""Input validation against an affordance's data schema, before anything reaches a device.

Covers the JSON Schema keywords TDs use (type, const, enum, minimum/maximum, exclusive bounds,
lengths, pattern, items, properties/required). A violation raises `BadInput` naming the path, e.g.
`input.x: 250 is above the maximum 200`.
"""
from __future__ import annotations

import re
import sys
from typing import Any

from twinmesh.wot.problem import BadInput
from twinmesh.wot.td import DataSchema

def _double(v: Any) -> bool:
    """A JSON number a device can take: an int or float within the range of a double (a 400-digit
    integer is valid JSON, but no device computes with it)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= sys.float_info.max


_TYPES = {
    "boolean": lambda v: isinstance(v, bool),
    "integer": lambda v: _double(v) and (isinstance(v, int) or float(v).is_integer()),
    "number": _double,
    "string": lambda v: isinstance(v, str),
    "array": lambda v: isinstance(v, list),
    "object": lambda v: isinstance(v, dict),
    "null": lambda v: v is None,
}


def _show(v: Any) -> str:
    s = repr(v) if not isinstance(v, (dict, list)) else type(v).__name__
    return s if len(s) < 60 else s[:57] + "..."


def validate(value: Any, schema: DataSchema | None, path: str = "input") -> None:
    """Raise BadInput if `value` does not satisfy `schema` (None accepts anything)."""
    if schema is None:
        return
    t = schema.type
    if t is not None:
        check = _TYPES.get(t)
        if check is None:
            raise BadInput(f"{path}: the schema has an unknown type {t!r}")
        if not check(value):
            raise BadInput(f"{path}: expected {t}, got {_show(value)}")
    if schema.const is not _unset() and value != schema.const:
        raise BadInput(f"{path}: must be {schema.const!r}")
    if schema.enum is not None and value not in schema.enum:
        raise BadInput(f"{path}: {_show(value)} is not one of {schema.enum}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        _check_bounds(value, schema, path)
    if isinstance(value, str):
        if schema.minLength is not None and len(value) < schema.minLength:
            raise BadInput(f"{path}: shorter than {schema.minLength} characters")
        if schema.maxLength is not None and len(value) > schema.maxLength:
            raise BadInput(f"{path}: longer than {schema.maxLength} characters")
        if schema.pattern is not None and not re.search(schema.pattern, value):
            raise BadInput(f"{path}: {_show(value)} does not match the pattern {schema.pattern}")
    if isinstance(value, list):
        if schema.minItems is not None and len(value) < schema.minItems:
            raise BadInput(f"{path}: needs at least {schema.minItems} items, got {len(value)}")
        if schema.maxItems is not None and len(value) > schema.maxItems:
            raise BadInput(f"{path}: allows at most {schema.maxItems} items, got {len(value)}")
        if schema.items is not None:
            for i, item in enumerate(value):
                validate(item, schema.items, f"{path}[{i}]")
    if isinstance(value, dict):
        for name in schema.required or ():
            if name not in value:
                raise BadInput(f"{path}: missing required field {name!r}")
        for name, sub in (schema.properties or {}).items():
            if name in value:
                validate(value[name], sub, f"{path}.{name}")


def _check_bounds(value: float, schema: DataSchema, path: str) -> None:
    if schema.minimum is not None and value < schema.minimum:
        raise BadInput(f"{path}: {value} is below the minimum {_num(schema.minimum)}")
    if schema.maximum is not None and value > schema.maximum:
        raise BadInput(f"{path}: {value} is above the maximum {_num(schema.maximum)}")
    if schema.exclusiveMinimum is not None and value <= schema.exclusiveMinimum:
        raise BadInput(f"{path}: {value} must be above {_num(schema.exclusiveMinimum)}")
    if schema.exclusiveMaximum is not None and value >= schema.exclusiveMaximum:
        raise BadInput(f"{path}: {value} must be below {_num(schema.exclusiveMaximum)}")


def _num(x: float) -> str:
    return str(int(x)) if float(x).is_integer() else str(x)


def _unset():
    import msgspec

    return msgspec.UNSET
