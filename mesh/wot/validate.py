"""Input validation against an affordance's data schema, before anything reaches a device.

A real JSON Schema implementation (jsonschema, draft 7, the dialect TD data schemas follow) with
its format checks, compiled once per schema; what changes is only how a violation reads: one
`BadInput` naming the path and the rule, e.g. `input.x: 250 is above the maximum 200`. Numbers
are JSON numbers a device can compute with: booleans are not numbers, and an integer beyond the
range of a double (valid JSON, 400 digits) is refused.

Valid values, the common case, are let through by fastjsonschema's generated code (about ten
times faster); jsonschema decides whenever that code refuses, and alone for schemas with a
`format` (the two libraries check formats differently) or values holding an integer too large.
jsonschema is loaded at the first schema compiled (an import a process that validates nothing, such as
`twinmesh tdgen`, need not pay).
"""
from __future__ import annotations

import queue
import sys
import threading
from functools import lru_cache
from typing import TYPE_CHECKING, Any

import fastjsonschema
import msgspec

from mesh.wot.problem import BadInput
from mesh.wot.thing_description import DataSchema, ThingDescription, keep_source_terms

if TYPE_CHECKING:
    from jsonschema import Draft7Validator
    from jsonschema.exceptions import ValidationError

Schema = DataSchema | dict[str, Any] | None


def _double(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and abs(v) <= sys.float_info.max


@lru_cache(maxsize=1)
def _draft7() -> tuple[Any, Any]:
    """Draft 7 with TD numbers (`_double`), and its format checker."""
    import jsonschema

    types = jsonschema.Draft7Validator.TYPE_CHECKER.redefine_many({
        "number": lambda _, v: _double(v),
        "integer": lambda _, v: _double(v) and (isinstance(v, int) or float(v).is_integer()),
    })
    return jsonschema.validators.extend(jsonschema.Draft7Validator, type_checker=types), \
        jsonschema.Draft7Validator.FORMAT_CHECKER


def validate(value: Any, schema: Schema, path: str = "input") -> None:
    """Raise BadInput if `value` does not satisfy `schema` (None accepts anything)."""
    if schema is None:
        return
    fast, validator = _compiled(msgspec.json.encode(schema))
    if fast is not None and _doubles_only(value):
        try:
            fast(value)
            return
        except fastjsonschema.JsonSchemaException:
            pass  # jsonschema says why (or, should they ever differ, decides)
    errors = list(validator.iter_errors(value))
    if errors:  # the most relevant one, not a branch inside oneOf/anyOf: that would mislead
        from jsonschema.exceptions import relevance

        raise BadInput(_sentence(max(errors, key=relevance), path))


def prepare(td: ThingDescription) -> None:
    """Compile the input schemas of the TD's actions on a background thread, so that an action's first
    call does not wait for it (in the adapter and again in the device: without it a lab's first
    `addObstacle` reached its device later than the next ones). Identical schemas compile once.
    For a Thing's first TD only: a robot's TD regenerated after each scene change has new bounds in its
    inputs, and compiling them at once competed with serving it."""
    inputs = [action.input for action in td.actions.values() if action.input is not None]
    if inputs:
        waiting = _compiler()
        for schema in inputs:
            waiting.put(msgspec.json.encode(schema))


_waiting: queue.SimpleQueue[bytes] | None = None
_starting = threading.Lock()


def _compiler() -> queue.SimpleQueue[bytes]:
    global _waiting
    with _starting:
        if _waiting is None:
            _waiting = queue.SimpleQueue()
            threading.Thread(target=_compile_all, args=(_waiting,), name="schema-compiler", daemon=True).start()
        return _waiting


def _compile_all(waiting: queue.SimpleQueue[bytes]) -> None:
    while True:
        try:
            _compiled(waiting.get())
        except BadInput:  # an invalid schema: its first call says so
            pass


@lru_cache(maxsize=4096)
def _compiled(schema_json: bytes) -> tuple[Any, Draft7Validator]:
    from jsonschema import SchemaError

    validator, formats = _draft7()
    schema = msgspec.json.decode(schema_json)
    try:
        validator.check_schema(schema)
    except SchemaError as e:
        raise BadInput(f"the affordance's schema is not valid JSON Schema: {e.message}") from None
    fast = None
    if b'"format"' not in schema_json:
        try:
            fast = fastjsonschema.compile(schema)
        except fastjsonschema.JsonSchemaDefinitionException:
            fast = None
    return fast, validator(schema, format_checker=formats)


def _doubles_only(value: Any) -> bool:
    """No integer beyond a double's range anywhere in `value` (fastjsonschema would take it)."""
    if isinstance(value, int) and not isinstance(value, bool):
        return abs(value) <= sys.float_info.max
    if isinstance(value, dict):
        return all(_doubles_only(v) for v in value.values())
    if isinstance(value, list):
        return all(_doubles_only(v) for v in value)
    return True


def _where(error: ValidationError, path: str) -> str:
    for part in error.absolute_path:
        path += f"[{part}]" if isinstance(part, int) else f".{part}"
    return path


def _show(v: Any) -> str:
    s = repr(v) if not isinstance(v, (dict, list)) else type(v).__name__
    return s if len(s) < 60 else s[:57] + "..."


def _num(x: Any) -> str:
    return str(int(x)) if isinstance(x, (int, float)) and float(x).is_integer() else str(x)


def _sentence(e: ValidationError, path: str) -> str:
    """The violation as a person reads it; the keyword decides the words."""
    where, v, rule = _where(e, path), e.instance, e.validator_value
    match e.validator:
        case "type":
            types = rule if isinstance(rule, str) else " or ".join(rule)
            return f"{where}: expected {types}, got {_show(v)}"
        case "const":
            return f"{where}: must be {rule!r}"
        case "enum":
            return f"{where}: {_show(v)} is not one of {rule}"
        case "minimum":
            return f"{where}: {v} is below the minimum {_num(rule)}"
        case "maximum":
            return f"{where}: {v} is above the maximum {_num(rule)}"
        case "exclusiveMinimum":
            return f"{where}: {v} must be above {_num(rule)}"
        case "exclusiveMaximum":
            return f"{where}: {v} must be below {_num(rule)}"
        case "multipleOf":
            return f"{where}: {v} is not a multiple of {_num(rule)}"
        case "minLength":
            return f"{where}: shorter than {rule} characters"
        case "maxLength":
            return f"{where}: longer than {rule} characters"
        case "pattern":
            return f"{where}: {_show(v)} does not match the pattern {rule}"
        case "format":
            return f"{where}: {_show(v)} is not a valid {rule}"
        case "minItems":
            return f"{where}: needs at least {rule} items, got {len(v)}"
        case "maxItems":
            return f"{where}: allows at most {rule} items, got {len(v)}"
        case "uniqueItems":
            return f"{where}: items must be unique"
        case "required":
            missing = next((n for n in rule if n not in v), rule[0])
            return f"{where}: missing required field {missing!r}"
        case "additionalProperties":
            extra = sorted(k for k in v if k not in (e.schema.get("properties") or {}))
            return f"{where}: unexpected field{'s' if len(extra) > 1 else ''} {', '.join(map(repr, extra))}"
        case "minProperties" | "maxProperties":
            return f"{where}: {e.message}"
        case "oneOf" | "anyOf":
            names = [_branch_name(b, i) for i, b in enumerate(rule)]
            options = f"either {names[0]} or {names[1]}" if len(names) == 2 else "one of: " + ", ".join(names)
            if not e.context:
                return f"{where}: {_show(v)} fits more than one of the allowed schemas ({e.validator}); give {options}"
            aimed = _aimed_branch(e)
            if aimed is not None:
                return _sentence(aimed, path)
            return f"{where}: {_show(v)} fits none of the allowed schemas ({e.validator}); give {options}"
        case "not":
            return f"{where}: {_show(v)} matches a schema it must not match"
        case _:
            return f"{where}: {e.message}"


def _branch_name(schema: Any, index: int) -> str:
    """A oneOf/anyOf branch as people know it: its title, else what it requires, else its number."""
    if isinstance(schema, dict):
        if schema.get("title"):
            required = schema.get("required")
            return f"{schema['title']} ({', '.join(required)})" if required else str(schema["title"])
        if schema.get("required"):
            return "an object with " + ", ".join(schema["required"])
    return f"schema {index + 1}"


def _aimed_branch(e: ValidationError) -> ValidationError | None:
    """The error of the one branch the value was meant for: the only branch whose required fields it
    has (and whose type it has); None when that is not one branch."""
    by_branch: dict[Any, list[ValidationError]] = {}
    for sub in e.context or []:
        by_branch.setdefault(sub.schema_path[0], []).append(sub)
    aimed = [errors for errors in by_branch.values()
             if not any(sub.validator in ("required", "type") and not sub.path for sub in errors)]
    return min(aimed[0], key=lambda sub: len(sub.path)) if len(aimed) == 1 else None


class SourceSchemas:
    """A Thing's data schemas as its own TD document states them: the model's schema (`DataSchema`) with
    every keyword the document holds beyond it (`patternProperties`, `not`, `if`/`then`/`else`,
    `definitions` a `$ref` points into, ...), so that a value is checked against the whole schema, never
    a part of it (less, which lets through what the TD forbids, or more: `additionalProperties: false`
    without the `patternProperties` beside it refuses every value). Each is merged once, when asked."""

    def __init__(self, source: dict[str, Any] | None):
        self.source = source if isinstance(source, dict) else None
        self._merged: dict[tuple[str, str, str], Schema] = {}

    def of(self, schema: Schema, kind: str, name: str, part: str = "") -> Schema:
        """`schema` (the model's, of affordance `kind`/`name`, `part` "input", "output", "data" or "" for
        a property itself) with what the document says beyond it (the model's itself where it says nothing
        more: its compiled validator is shared)."""
        if self.source is None or schema is None or isinstance(schema, dict):
            return schema
        key = (kind, name, part)
        if key not in self._merged:
            affordances = self.source.get(kind)
            raw = affordances.get(name) if isinstance(affordances, dict) else None
            if part and isinstance(raw, dict):
                raw = raw.get(part)
            model = msgspec.to_builtins(schema)
            if isinstance(raw, dict):  # forms are the server's, not the schema's
                merged = keep_source_terms({k: v for k, v in raw.items() if k != "forms"}, model)
                self._merged[key] = merged if merged != model else schema
            else:
                self._merged[key] = schema
        return self._merged[key]
