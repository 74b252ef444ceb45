"""Values from a data schema alone, always valid: what a virtual Thing reads, answers and emits.

A seeded walk over the schema (`random.Random`: the same seed gives the same values), and every value
checked against the schema by the same validator that checks inputs (`mesh.wot.validate`: draft 7,
formats included) before it is given out; a value that fails is drawn again, a schema nothing valid
can be drawn from (contradicting keywords) is `NoValue` naming where. Strings matching a `pattern`
come from rstr's regex generator; the rest is here because no library gives valid values seeded and
judged as validators judge them: a fractional `multipleOf` (0.1, 0.01) must pass jsonschema's own
float test (`0.3 / 0.1` is not an integer to it, `0.4 / 0.1` is), a `oneOf` value must match exactly
one branch, lengths and patterns hold together (`strict_multiple`). jsf (JSON Schema Faker) and hypothesis-jsonschema
were weighed: the first draws from a subset and does not check, the second is built for tests
(unseeded `example()`, no way to keep a value in bounds across calls).
"""
from __future__ import annotations

import datetime
import math
import random
import string
import uuid
from decimal import Decimal
from typing import Any

from mesh.wot.problem import BadInput
from mesh.wot.validate import validate

ATTEMPTS = 60
SPAN = 100  # how far an unbounded number ranges from its one bound (or from 0)


class NoValue(ValueError):
    """No valid value could be drawn for a schema; the message says where and why."""


def is_valid(value: Any, schema: dict[str, Any]) -> bool:
    try:
        validate(value, schema, path="value")
        return True
    except BadInput:
        return False


class SchemaValues:
    """Valid values for data schemas (plain JSON dicts, as a TD writes them), from one seeded source."""

    def __init__(self, seed: int | None = None):
        self.rng = random.Random(seed)
        import rstr

        self._regex = rstr.Rstr(self.rng)

    # --- what a virtual Thing asks for ---------------------------------------------------------------
    def initial(self, schema: dict[str, Any], where: str = "value") -> Any:
        """The schema's own value where it gives one (`const`, `default`, first `enum`, first of
        `examples`) and that value is valid; else a drawn one."""
        for term in ("const", "default"):
            if term in schema and is_valid(schema[term], schema):
                return schema[term]
        for term in ("enum", "examples"):
            given = schema.get(term)
            if isinstance(given, list):
                for value in given:
                    if is_valid(value, schema):
                        return value
        return self.value(schema, where)

    def value(self, schema: dict[str, Any], where: str = "value") -> Any:
        """A drawn valid value (NoValue when none can be drawn)."""
        for _ in range(ATTEMPTS):
            try:
                candidate = self._draw(schema, depth=0)
            except _Impossible as e:
                raise NoValue(f"{where}: {e}") from None
            if is_valid(candidate, schema):
                return candidate
        raise NoValue(f"{where}: no valid value found in {ATTEMPTS} draws (do its keywords contradict each other?)")

    def drift(self, schema: dict[str, Any], value: Any) -> Any:
        """A nearby valid value for a numeric schema (a reading that lives), else `value` unchanged."""
        kind = _type_of(schema)
        if kind not in ("number", "integer") or "enum" in schema or "const" in schema or isinstance(value, bool) \
                or not isinstance(value, (int, float)):
            return value
        lo, hi = _bounds(schema, kind == "integer")
        step = schema.get("multipleOf") or (1 if kind == "integer" else max((hi - lo) / 50, 0.01))
        for _ in range(8):
            candidate = value + self.rng.choice((-1, 1)) * step * self.rng.randint(1, 2)
            if kind == "integer":
                candidate = int(round(candidate))
            else:
                m = schema.get("multipleOf")
                candidate = _multiple(candidate, m) if isinstance(m, (int, float)) else round(candidate, 6)
                if isinstance(m, (int, float)) and not strict_multiple(candidate, m):
                    continue
            if is_valid(candidate, schema):
                return candidate
        return value

    # --- drawing -----------------------------------------------------------------------------------------
    def _draw(self, schema: Any, depth: int) -> Any:
        if not isinstance(schema, dict):
            return None  # `true` / a missing schema: anything; null is something
        if depth > 24:
            raise _Impossible("nested deeper than 24 levels")
        if "const" in schema:
            return schema["const"]
        if isinstance(schema.get("enum"), list) and schema["enum"]:
            return self.rng.choice(schema["enum"])
        if isinstance(schema.get("allOf"), list):
            return self._draw(_merge(_without(schema, "allOf"), *schema["allOf"]), depth + 1)
        if isinstance(schema.get("oneOf"), list) and schema["oneOf"]:
            return self._one_of(schema, depth)
        if isinstance(schema.get("anyOf"), list) and schema["anyOf"]:
            return self._draw(_merge(_without(schema, "anyOf"), self.rng.choice(schema["anyOf"])), depth + 1)
        kind = _type_of(schema)
        if isinstance(kind, list):
            kind = self.rng.choice(kind) if kind else "null"
        draw = getattr(self, f"_{kind}", None)
        if draw is None:
            raise _Impossible(f"unknown type {kind!r}")
        return draw(schema, depth)

    def _one_of(self, schema: dict[str, Any], depth: int) -> Any:
        base = _without(schema, "oneOf")
        branches = list(schema["oneOf"])
        self.rng.shuffle(branches)
        for branch in branches:
            for _ in range(4):
                candidate = self._draw(_merge(base, branch), depth + 1)
                if sum(is_valid(candidate, b) for b in schema["oneOf"] if isinstance(b, dict)) == 1:
                    return candidate
        raise _Impossible("no value matches exactly one branch of its oneOf")

    def _null(self, schema: dict[str, Any], depth: int) -> None:
        return None

    def _boolean(self, schema: dict[str, Any], depth: int) -> bool:
        return self.rng.random() < 0.5

    def _integer(self, schema: dict[str, Any], depth: int) -> int:
        lo, hi = _bounds(schema, integer=True)
        m = schema.get("multipleOf")
        if isinstance(m, (int, float)) and m > 0:
            k_lo, k_hi = math.ceil(lo / m), math.floor(hi / m)
            if k_lo > k_hi:
                raise _Impossible(f"no multiple of {m} within {lo}..{hi}")
            for _ in range(20):
                v = self.rng.randint(k_lo, k_hi) * m
                if float(v).is_integer():
                    return int(v)
            raise _Impossible(f"no integer multiple of {m} within {lo}..{hi}")
        if lo > hi:
            raise _Impossible(f"its bounds leave no integer ({lo}..{hi})")
        return self.rng.randint(int(lo), int(hi))

    def _number(self, schema: dict[str, Any], depth: int) -> float | int:
        lo, hi = _bounds(schema, integer=False)
        if lo > hi:
            raise _Impossible(f"its bounds leave no number ({lo}..{hi})")
        m = schema.get("multipleOf")
        if isinstance(m, (int, float)) and m > 0:
            k_lo, k_hi = math.ceil(lo / m), math.floor(hi / m)
            if k_lo > k_hi:
                raise _Impossible(f"no multiple of {m} within {lo}..{hi}")
            for _ in range(40):  # the validator's float test fails some multiples (0.3 / 0.1): draw again
                v = _multiple(self.rng.randint(k_lo, k_hi) * m, m)
                if lo <= v <= hi and strict_multiple(v, m):
                    return v
            raise _Impossible(f"no multiple of {m} within {lo}..{hi} that validators accept")
        return round(self.rng.uniform(lo, hi), 3) if hi - lo > 0.01 else lo

    def _string(self, schema: dict[str, Any], depth: int) -> str:
        lo = int(schema.get("minLength", 0))
        hi = int(schema.get("maxLength", max(lo, 12)))
        if lo > hi:
            raise _Impossible(f"minLength {lo} above maxLength {hi}")
        if isinstance(schema.get("pattern"), str):
            for _ in range(20):
                try:
                    s = self._regex.xeger(schema["pattern"])
                except Exception as e:  # a pattern rstr cannot generate from (lookarounds, back-references)
                    raise _Impossible(f"cannot draw a string for the pattern {schema['pattern']!r} ({e})") from None
                if lo <= len(s) <= hi:
                    return s
            raise _Impossible(f"no string of {lo}..{hi} characters drawn for the pattern {schema['pattern']!r}")
        fmt = schema.get("format")
        if isinstance(fmt, str) and fmt in _FORMATS:
            return _FORMATS[fmt](self.rng)
        n = self.rng.randint(lo, min(hi, lo + 12))
        return "".join(self.rng.choice(string.ascii_lowercase) for _ in range(n))

    def _array(self, schema: dict[str, Any], depth: int) -> list[Any]:
        items: Any = schema.get("items")
        lo = int(schema.get("minItems", 0))
        hi = int(schema.get("maxItems", max(lo, 3)))
        if lo > hi:
            raise _Impossible(f"minItems {lo} above maxItems {hi}")
        if isinstance(items, list):  # a tuple
            n = min(max(len(items), lo), hi) if schema.get("additionalItems", True) is not False else len(items)
            extra = schema.get("additionalItems") if isinstance(schema.get("additionalItems"), dict) else {}
            return [self._draw(items[i] if i < len(items) else extra, depth + 1) for i in range(n)]
        n = self.rng.randint(lo, min(hi, lo + 3))
        out: list[Any] = []
        for _ in range(n * 5):
            if len(out) == n:
                break
            v = self._draw(items, depth + 1)
            if not schema.get("uniqueItems") or v not in out:
                out.append(v)
        return out

    def _object(self, schema: dict[str, Any], depth: int) -> dict[str, Any]:
        props: dict[str, Any] = schema["properties"] if isinstance(schema.get("properties"), dict) else {}
        required = [r for r in schema.get("required", []) if isinstance(r, str)]
        out = {}
        for name in required:
            out[name] = self._draw(props.get(name, {}), depth + 1)
        optional = [n for n in props if n not in out]
        wanted = int(schema.get("minProperties", 0))
        for name in optional:
            if len(out) < wanted or self.rng.random() < 0.5:
                out[name] = self._draw(props[name], depth + 1)
        return out


class _Impossible(Exception):
    pass


def strict_multiple(v: float, m: float) -> bool:
    """`v` is a multiple of `m` as jsonschema and node-wot's ajv judge it: `v / m` an exact integer in
    floating point (17.7 is no multiple of 0.1 to them: 17.7 / 0.1 = 176.99999999999997). The
    adapter's own input check is more lenient; values given out must pass the strict test."""
    q = v / m
    return math.isfinite(q) and q == int(q)


def _type_of(schema: dict[str, Any]) -> Any:
    if "type" in schema:
        return schema["type"]
    if "properties" in schema or "required" in schema:
        return "object"
    if "items" in schema:
        return "array"
    if any(k in schema for k in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "multipleOf")):
        return "number"
    if any(k in schema for k in ("minLength", "maxLength", "pattern", "format")):
        return "string"
    return "null"


def _bounds(schema: dict[str, Any], integer: bool) -> tuple[float, float]:
    lo: Any = schema.get("minimum")
    hi: Any = schema.get("maximum")
    xlo, xhi = schema.get("exclusiveMinimum"), schema.get("exclusiveMaximum")
    tiny = 1 if integer else 1e-6
    if isinstance(xlo, (int, float)) and not isinstance(xlo, bool):
        lo = xlo + tiny if lo is None else max(lo, xlo + tiny)
    if isinstance(xhi, (int, float)) and not isinstance(xhi, bool):
        hi = xhi - tiny if hi is None else min(hi, xhi - tiny)
    if lo is None and hi is None:
        lo, hi = 0, SPAN
    elif lo is None:
        lo = hi - SPAN
    elif hi is None:
        hi = lo + SPAN
    if integer:
        lo, hi = math.ceil(lo), math.floor(hi)
    return lo, hi


def _multiple(v: float, m: float) -> float | int:
    """`v` as the nearest multiple of `m`, written with `m`'s decimals (0.30000000000000004 -> 0.3)."""
    places = max(0, -Decimal(str(m)).as_tuple().exponent)  # type: ignore[operator]
    k = round(v / m)
    out = round(float(Decimal(k) * Decimal(str(m))), places)
    return int(out) if float(m).is_integer() else out


def _merge(*schemas: Any) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for s in schemas:
        if not isinstance(s, dict):
            continue
        for k, v in s.items():
            if k == "properties" and isinstance(v, dict):
                out["properties"] = {**out.get("properties", {}), **v}
            elif k == "required" and isinstance(v, list):
                out["required"] = sorted({*out.get("required", []), *v})
            else:
                out[k] = v
    return out


def _without(schema: dict[str, Any], key: str) -> dict[str, Any]:
    return {k: v for k, v in schema.items() if k != key}


def _date_time(rng: random.Random) -> str:
    moment = datetime.datetime(2024, 1, 1, tzinfo=datetime.timezone.utc) + datetime.timedelta(
        seconds=rng.randint(0, 3 * 365 * 86400))
    return moment.isoformat().replace("+00:00", "Z")


_FORMATS = {
    "date-time": _date_time,
    "date": lambda rng: _date_time(rng)[:10],
    "time": lambda rng: _date_time(rng)[11:],
    "email": lambda rng: f"user{rng.randint(1, 999)}@example.org",
    "idn-email": lambda rng: f"user{rng.randint(1, 999)}@example.org",
    "hostname": lambda rng: f"device-{rng.randint(1, 999)}.example.org",
    "idn-hostname": lambda rng: f"device-{rng.randint(1, 999)}.example.org",
    "ipv4": lambda rng: ".".join(str(rng.randint(1, 254)) for _ in range(4)),
    "ipv6": lambda rng: ":".join(f"{rng.randint(0, 0xffff):x}" for _ in range(8)),
    "uri": lambda rng: f"https://example.org/things/{rng.randint(1, 9999)}",
    "iri": lambda rng: f"https://example.org/things/{rng.randint(1, 9999)}",
    "uri-reference": lambda rng: f"/things/{rng.randint(1, 9999)}",
    "iri-reference": lambda rng: f"/things/{rng.randint(1, 9999)}",
    "uri-template": lambda rng: "https://example.org/things/{id}",
    "uuid": lambda rng: str(uuid.UUID(int=rng.getrandbits(128), version=4)),
    "json-pointer": lambda rng: f"/properties/p{rng.randint(1, 99)}",
    "relative-json-pointer": lambda rng: f"{rng.randint(0, 3)}/p",
    "regex": lambda rng: "^[a-z]+$",
}
