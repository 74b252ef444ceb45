"""Values from a data schema alone, always valid: what a virtual Thing reads, answers and emits.

Values are built, not guessed: a schema is read as a conjunction of what must hold (its own keywords,
`allOf`, the chosen branch of `anyOf` / `oneOf`, `if`+`then` or `else`) and of what must not (`not`,
the other `oneOf` branches, a rejected `if`), and each JSON type is built from that conjunction:
bounds and `multipleOf` merged, strings from every `pattern` (rstr's regex generator) and `format`,
arrays with their tuple, `contains` and `uniqueItems`, objects with `required`, `dependencies`,
`patternProperties`, `additionalProperties` and `propertyNames`. What must not hold is excluded by
type where it can be, else broken on purpose (an object that still fits another `oneOf` branch gets
a property that branch refuses). Optional parts that cannot be built are left out. Every value is
then checked by the validator that checks inputs (`mesh.wot.validate`: draft 7, formats), so a
mistake here costs a retry, never an invalid value.

A schema is prepared once per process (`prepare`): a pool of valid values drawn from a generator
seeded by the schema itself, so the same TD gets the same pool in every process that serves it and
what passed at start cannot fail later. A live draw (seeded by the caller) that misses falls back to
the pool: an answer never waits for luck. A schema with no valid value is `NoValue`, naming the JSON
pointer and the keywords that contradict each other; an invalid schema is `NoValue` with the
validator's words. hypothesis-jsonschema was weighed as the runtime generator: its `not` and `oneOf`
are filters over broad strategies (20 values of `{"not": {"type": "null"}}` took seconds), its values
are test-shaped (surrogates, 1e16) and it would make hypothesis a runtime dependency; it stays the
test suite's second opinion (tests/test_schema_values_property.py).
"""
from __future__ import annotations

import copy
import datetime
import math
import random
import re
import string
import threading
import uuid
import zlib
from dataclasses import dataclass
from decimal import Decimal
from typing import Any

import fastjsonschema
import msgspec

from mesh.wot.problem import BadInput
from mesh.wot.validate import _compiled, _doubles_only

ATTEMPTS = 48  # whole values tried when a schema is prepared
POOL = 8  # distinct valid values kept per schema: the answer when a live draw misses
LIVE_TRIES = 3  # live draws tried before the pool answers
LOCAL_TRIES = 4  # tries of one sub-value before its parent gives up on it
MAX_DEPTH = 48
STEPS = 5000  # sub-values and strings built for one value at most (a 64-item array of triples takes 257)
PLAN_STEPS = 30000  # ... and for the whole preparation of a schema
FRUITLESS = 16  # values tried with none valid before a schema is given up
MAX_SIZE = 2000  # items, characters or properties a value may be asked to have at least
SPAN = 100  # how far an unbounded number ranges from its one bound (or from 0)
TYPES = ("string", "integer", "number", "boolean", "object", "array", "null")
COMBINATORS = ("allOf", "anyOf", "oneOf", "not", "if", "then", "else", "$ref", "definitions")


class NoValue(ValueError):
    """No valid value exists or could be built for a schema; the message says where and why."""


def is_valid(value: Any, schema: Any) -> bool:
    """`mesh.wot.validate.validate`'s verdict without its sentence: the same compiled pair (fastjsonschema
    for what it accepts, jsonschema deciding the rest), stopping at the first error. Most checks here
    are of schemas a value must not match: the refusals are the common case."""
    if schema is True or schema == {}:
        return True
    if schema is False:
        return False
    try:
        fast, validator = _compiled(msgspec.json.encode(schema))
    except BadInput:
        return False
    if fast is not None and _doubles_only(value):
        try:
            fast(value)
            return True
        except fastjsonschema.JsonSchemaException:
            pass
    return bool(validator.is_valid(value))


@dataclass(frozen=True)
class _Plan:
    pool: list[bytes]  # JSON of valid values: each answer is a fresh copy
    live: bool  # live draws are worth trying (most prepared draws were valid)


_plans: dict[bytes, _Plan | NoValue] = {}
_planning = threading.Lock()


def prepare(schema: Any, where: str = "") -> None:
    """Build the schema's pool now (NoValue naming `where` and the pointer inside when there is no value)."""
    _plan(schema, where)


def _plan(schema: Any, where: str) -> _Plan:
    key = msgspec.json.encode(schema)
    with _planning:
        plan = _plans.get(key)
        if plan is None:
            try:
                plan = _build_plan(schema, key)
            except NoValue as e:
                plan = e
            _plans[key] = plan
    if isinstance(plan, NoValue):
        raise NoValue(f"{where}{plan}" if where else str(plan).lstrip(": ")) from None
    return plan


def _build_plan(schema: Any, key: bytes) -> _Plan:
    invalid = _invalid_schema(schema)
    if invalid:
        raise NoValue(invalid)
    build = _Builder(random.Random(zlib.crc32(key)))
    pool: list[bytes] = []
    hits = tries = 0
    reasons: dict[str, int] = {}
    steps = 0
    while tries < ATTEMPTS and len(pool) < POOL and steps < PLAN_STEPS and (pool or tries < FRUITLESS):
        tries += 1
        try:
            candidate = build.value(schema)
        except _Impossible as e:
            reasons[str(e)] = reasons.get(str(e), 0) + 1
            continue
        except Exception as e:  # a schema the builder does not foresee is refused with why, never a traceback
            reasons[f"cannot build a value ({type(e).__name__}: {e})"] = 1
            continue
        finally:
            steps += build.steps
        try:
            valid = is_valid(candidate, schema)
        except Exception as e:  # the validator itself fails on this schema: inputs to it cannot be checked either
            raise NoValue(f": the validator cannot check this schema ({type(e).__name__}: {e})") from None
        if valid:
            hits += 1
            encoded = msgspec.json.encode(candidate)
            if encoded not in pool:
                pool.append(encoded)
    if not pool:
        raise NoValue(_explain(schema, reasons, tries))
    return _Plan(pool, live=hits * 2 >= tries)


def _invalid_schema(schema: Any) -> str | None:
    from jsonschema import Draft7Validator, SchemaError

    try:
        Draft7Validator.check_schema(schema)
    except SchemaError as e:
        return f"{_pointer(e.path)}: not valid JSON Schema: {e.message}"
    return None


def _pointer(parts: Any) -> str:
    return "".join("/" + str(p).replace("~", "~0").replace("/", "~1") for p in parts)


class SchemaValues:
    """Valid values for data schemas (plain JSON dicts, as a TD writes them), from one seeded source."""

    def __init__(self, seed: int | None = None):
        self.rng = random.Random(seed)
        self._build = _Builder(self.rng)

    # --- what a virtual Thing asks for ---------------------------------------------------------------
    def prepare(self, schema: Any, where: str = "value") -> None:
        """Refuse now (NoValue) a schema no value can be given for; later calls cannot fail."""
        _plan(schema, where)

    def initial(self, schema: dict[str, Any], where: str = "value") -> Any:
        """The schema's own value where it gives one (`const`, `default`, first `enum`, first of
        `examples`) and that value is valid; else a built one."""
        _plan(schema, where)
        for term in ("const", "default"):
            if term in schema and is_valid(schema[term], schema):
                return copy.deepcopy(schema[term])
        for term in ("enum", "examples"):
            given = schema.get(term)
            if isinstance(given, list):
                for value in given:
                    if is_valid(value, schema):
                        return copy.deepcopy(value)
        return self.value(schema, where)

    def value(self, schema: Any, where: str = "value") -> Any:
        """A valid value: a live draw, else one of the schema's pool (NoValue only for a schema
        that has none, and then already at `prepare`)."""
        plan = _plan(schema, where)
        if plan.live:
            for _ in range(LIVE_TRIES):
                try:
                    candidate = self._build.value(schema)
                    if is_valid(candidate, schema):
                        return candidate
                except Exception:  # whatever a live draw runs into, the pool answers
                    continue
        return msgspec.json.decode(self.rng.choice(plan.pool))

    def drift(self, schema: dict[str, Any], value: Any) -> Any:
        """A nearby valid value for a numeric schema (a reading that lives), else `value` unchanged."""
        kind = schema.get("type")
        if kind not in ("number", "integer") or "enum" in schema or "const" in schema or isinstance(value, bool) \
                or not isinstance(value, (int, float)):
            return value
        lo, hi = _bounds([schema], kind == "integer")
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


class _Impossible(Exception):
    pass


class _GiveUp(_Impossible):
    """Not worth another try of the same part: too deep, or out of steps."""


class _Builder:
    """Builds one value for a conjunction of schemas that must hold and schemas that must not."""

    def __init__(self, rng: random.Random):
        import rstr

        self.rng = rng
        self._regex = rstr.Rstr(rng)
        self.root: Any = None
        self.steps = 0

    def value(self, schema: Any) -> Any:
        self.root = schema
        self.steps = 0
        return self._value([schema], [], 0)

    def _value(self, alls: list[Any], nots: list[Any], depth: int) -> Any:
        self._step()
        if depth > MAX_DEPTH:
            raise _GiveUp(f"nested deeper than {MAX_DEPTH} levels (a $ref to itself that every value must follow?)")
        last: _Impossible | None = None
        for _ in range(LOCAL_TRIES):
            try:
                flat, excluded = self._flatten(alls, nots)
                candidate = self._typed(flat, excluded, depth)
            except _GiveUp:
                raise  # trying again would go as deep and cost as much
            except _Impossible as e:
                last = e
                continue
            if not excluded and _built_right(candidate, flat):
                return candidate
            if all(_locally_valid(candidate, s) for s in flat) and not any(_locally_valid(candidate, n)
                                                                          for n in excluded):
                return candidate
        raise last or _Impossible("no value satisfies both what it must and must not match")

    def _step(self) -> None:
        self.steps += 1
        if self.steps > STEPS:  # retries nest: without a bound, 4 tries a level over 48 levels
            raise _GiveUp(f"gave up after {STEPS} steps")

    # --- the conjunction ---------------------------------------------------------------------------------
    def _flatten(self, alls: list[Any], nots: list[Any]) -> tuple[list[dict[str, Any]], list[Any]]:
        """The plain schemas that must all hold (combinators resolved, one branch chosen each) and the
        schemas that must not."""
        flat: list[dict[str, Any]] = []
        excluded = list(nots)
        todo = list(alls)
        seen = 0
        while todo:
            seen += 1
            if seen > 256:
                raise _Impossible("too many subschemas")
            s = todo.pop(0)
            if s is True:
                continue
            if s is False:
                raise _Impossible("the schema false allows nothing")
            if not isinstance(s, dict):
                continue
            if "$ref" in s:
                todo.append(self._deref(s["$ref"]))
                continue  # draft 7: siblings of $ref are ignored
            flat.append({k: v for k, v in s.items() if k not in COMBINATORS})
            if isinstance(s.get("allOf"), list):
                todo.extend(s["allOf"])
            if "not" in s:
                excluded.append(s["not"])
            if "if" in s and ("then" in s or "else" in s):
                if self.rng.random() < 0.5:
                    todo += [s["if"], s.get("then", True)]
                else:
                    excluded.append(s["if"])
                    todo.append(s.get("else", True))
            if isinstance(s.get("anyOf"), list) and s["anyOf"]:
                todo.append(self.rng.choice(s["anyOf"]))
            if isinstance(s.get("oneOf"), list) and s["oneOf"]:
                i = self.rng.randrange(len(s["oneOf"]))
                todo.append(s["oneOf"][i])
                excluded.extend(b for j, b in enumerate(s["oneOf"]) if j != i)
        return flat, excluded

    def _deref(self, ref: Any) -> Any:
        if not isinstance(ref, str) or not ref.startswith("#"):
            raise _Impossible(f"cannot follow $ref {ref!r} (only refs inside the schema)")
        node = self.root
        for part in [p for p in ref[1:].split("/") if p]:
            part = part.replace("~1", "/").replace("~0", "~")
            if isinstance(node, dict) and part in node:
                node = node[part]
            elif isinstance(node, list) and part.isdigit() and int(part) < len(node):
                node = node[int(part)]
            else:
                raise _Impossible(f"$ref {ref!r} points nowhere")
        return node

    def _typed(self, flat: list[dict[str, Any]], nots: list[Any], depth: int) -> Any:
        for n in nots:
            if n is True or n == {}:
                raise _Impossible("not {} allows nothing")
        listed = next((s for s in flat if "const" in s or "enum" in s), None)
        if listed is not None:
            options = [listed["const"]] if "const" in listed else list(listed["enum"] or [])
            fits = [v for v in options if all(_locally_valid(v, s) for s in flat)
                    and not any(_locally_valid(v, n) for n in nots)]
            if not fits:
                raise _Impossible("none of its enum/const values satisfies its other keywords")
            return copy.deepcopy(self.rng.choice(fits))
        kinds = self._kinds(flat, nots)
        kind = self.rng.choice(kinds)
        if kind == "null":
            return None
        if kind == "boolean":
            return self.rng.random() < 0.5
        if kind in ("integer", "number"):
            return self._number(flat, kind == "integer")
        if kind == "string":
            return self._string(flat)
        if kind == "array":
            return self._array(flat, nots, depth)
        return self._object(flat, nots, depth)

    def _kinds(self, flat: list[dict[str, Any]], nots: list[Any]) -> list[str]:
        allowed = set(TYPES)
        for s in flat:
            if "type" in s:
                allowed &= _expand(s["type"])
        for n in nots:
            if not isinstance(n, dict):
                continue
            if "type" in n and not set(n) - {"type", "title", "description", "$comment"}:
                allowed -= _expand(n["type"])  # `not: {type: ...}` alone excludes its types outright
            elif not any(k in n for k in ("type", "enum", "const", *COMBINATORS)) and _hinted(n):
                allowed &= _expand(sorted(_hinted(n)))  # any other type matches it: only these can break it
        if not allowed:
            raise _Impossible("no JSON type is left by its type keywords")
        hinted = {kind for s in flat for kind in _hinted(s)} & allowed
        if hinted:
            return sorted(hinted)
        plain = [k for k in ("string", "integer", "number", "boolean", "object", "array", "null") if k in allowed]
        return plain[:3] if len(plain) > 3 else plain

    # --- scalars -------------------------------------------------------------------------------------------
    def _number(self, flat: list[dict[str, Any]], integer: bool) -> float | int:
        lo, hi = _bounds(flat, integer)
        multiples = [s["multipleOf"] for s in flat if _is_num(s.get("multipleOf")) and s["multipleOf"] > 0]
        if lo > hi:
            raise _Impossible(f"its bounds leave no {'integer' if integer else 'number'} ({lo}..{hi})")
        if multiples:
            m = max(multiples)
            k_lo, k_hi = math.ceil(lo / m), math.floor(hi / m)
            if k_lo > k_hi:
                raise _Impossible(f"no multiple of {m} within {lo}..{hi}")
            for _ in range(40):  # the validator's float test fails some multiples (0.3 / 0.1): draw again
                k = self.rng.randint(k_lo, k_hi) if self.rng.random() < 0.8 else self.rng.choice((k_lo, k_hi))
                v = _multiple(k * m, m)
                if integer and not float(v).is_integer():
                    continue
                v = int(v) if integer else v
                if lo <= v <= hi and all(strict_multiple(v, other) for other in multiples):
                    return v
            raise _Impossible(f"no multiple of {', '.join(map(str, multiples))} within {lo}..{hi} that validators accept")
        if integer:
            return self.rng.randint(int(lo), int(hi))
        if hi - lo <= 0.01:
            return lo
        v = self.rng.uniform(lo, hi)
        return round(v, 3) if lo <= round(v, 3) <= hi else v

    def _string(self, flat: list[dict[str, Any]]) -> str:
        lo = max([int(s["minLength"]) for s in flat if _is_num(s.get("minLength"))] or [0])
        hi = min([int(s["maxLength"]) for s in flat if _is_num(s.get("maxLength"))] or [10**6])
        if lo > MAX_SIZE:
            raise _Impossible(f"minLength {lo} above the {MAX_SIZE} characters a virtual Thing builds")
        if lo > hi:
            raise _Impossible(f"minLength {lo} above maxLength {hi}")
        patterns = [s["pattern"] for s in flat if isinstance(s.get("pattern"), str)]
        formats = [s["format"] for s in flat if isinstance(s.get("format"), str) and s["format"] in _FORMATS]
        for _ in range(8):
            self._step()
            if patterns:
                s = self._from_pattern(self.rng.choice(patterns), lo, hi)
            elif formats:
                s = _FORMATS[formats[0]](self.rng)
            else:
                n = self.rng.randint(lo, min(hi, lo + 12))
                s = "".join(self.rng.choice(string.ascii_lowercase) for _ in range(n))
            if lo <= len(s) <= hi and all(re.search(p, s) for p in patterns):
                return s
        length = f" of {lo}..{hi} characters" if hi < 10**6 else f" of {lo}+ characters" if lo else ""
        raise _Impossible(f"no string{length} matches {' and '.join(patterns) or formats[0]}")

    def _from_pattern(self, pattern: str, lo: int, hi: int) -> str:
        try:
            s = self._regex.xeger(pattern)
        except Exception as e:  # a pattern rstr cannot build from (lookarounds, back-references)
            raise _Impossible(f"cannot build a string for the pattern {pattern!r} ({e})") from None
        if len(s) < lo and not pattern.endswith("$"):  # an unanchored pattern may be padded
            s += "".join(self.rng.choice(string.ascii_lowercase) for _ in range(lo - len(s)))
        elif len(s) < lo and not pattern.startswith("^"):
            s = "".join(self.rng.choice(string.ascii_lowercase) for _ in range(lo - len(s))) + s
        return s

    # --- arrays ----------------------------------------------------------------------------------------
    def _array(self, flat: list[dict[str, Any]], nots: list[Any], depth: int) -> list[Any]:
        out, holder, lo, hi = self._items(flat, depth)
        for n in nots:  # what must not match, broken on purpose where it still does
            if isinstance(n, dict) and _locally_valid(out, n):
                self._break_array(out, n, flat, holder, lo, hi, depth)
        return out

    def _break_array(self, out: list[Any], n: dict[str, Any], flat: list[dict[str, Any]], holder: int, lo: int,
                     hi: int, depth: int) -> None:
        """Make `out` stop matching `n`: an item `n`'s `items` refuses, more items than its `maxItems`,
        fewer than its `minItems`, a repeated item against its `uniqueItems`."""
        unique = any(s.get("uniqueItems") is True for s in flat)
        moves: list[str] = []
        if isinstance(n.get("items"), dict) and n["items"] is not True and n["items"] != {}:
            moves.append("refuse")
        if _is_num(n.get("maxItems")) and n["maxItems"] < hi:
            moves.append("grow")
        if _is_num(n.get("minItems")) and n["minItems"] > lo:
            moves.append("shrink")
        if n.get("uniqueItems") is True and not unique and out:
            moves.append("repeat")
        if ("enum" in n or "const" in n) and len(out) < hi:  # one item more makes it another value
            moves.append("more")
        self.rng.shuffle(moves)
        for move in moves:
            try:
                if move == "refuse":
                    i = self.rng.randrange(len(out) + 1) if len(out) < hi else self.rng.randrange(len(out))
                    if i == holder:
                        continue
                    v = self._value([x for s in flat for x in _item_schemas(s, i)], [n["items"]], depth + 1)
                    out[i:i + 1] = [v]
                elif move == "grow":
                    while len(out) <= n["maxItems"] and len(out) < hi:
                        out.append(self._value([x for s in flat for x in _item_schemas(s, len(out))], [], depth + 1))
                elif move == "shrink":
                    if holder > 0:  # the item `contains` was built for goes first
                        out.insert(0, out.pop(holder))
                        holder = 0
                    del out[max(lo, holder + 1):]
                elif move == "more":
                    out.append(self._value([x for s in flat for x in _item_schemas(s, len(out))], [], depth + 1))
                elif move == "repeat" and len(out) < hi and holder != len(out):
                    out.append(copy.deepcopy(out[-1]))
            except _Impossible:
                continue
            if not _locally_valid(out, n):
                return

    def _items(self, flat: list[dict[str, Any]], depth: int) -> tuple[list[Any], int, int, int]:
        lo = max([int(s["minItems"]) for s in flat if _is_num(s.get("minItems"))] or [0])
        hi = min([int(s["maxItems"]) for s in flat if _is_num(s.get("maxItems"))] or [max(lo, 3) + 3])
        contains = [s["contains"] for s in flat if "contains" in s]
        unique = any(s.get("uniqueItems") is True for s in flat)
        for s in flat:
            if isinstance(s.get("items"), list) and s.get("additionalItems") is False:
                hi = min(hi, len(s["items"]))
        if contains:
            lo = max(lo, 1)
        if lo > hi:
            raise _Impossible(f"minItems {lo} above maxItems {hi}")
        if lo > MAX_SIZE:
            raise _Impossible(f"minItems {lo} above the {MAX_SIZE} items a virtual Thing builds")
        n = self.rng.randint(lo, min(hi, lo + 3))
        holder = self.rng.randrange(n) if contains and n else -1
        out: list[Any] = []
        for i in range(n):
            schemas = [schema for s in flat for schema in _item_schemas(s, i)] + (contains if i == holder else [])
            for attempt in range(4):
                try:  # after a repeat, the items so far are values it must not be
                    v = self._value(schemas, [{"enum": list(out)}] if attempt and out else [], depth + 1)
                except _Impossible:
                    if i >= lo and i != holder:
                        return out, holder, lo, hi
                    raise
                if not unique or all(_json(v) != _json(w) for w in out):
                    break
            else:
                if i >= lo and i != holder:
                    return out, holder, lo, hi
                raise _Impossible("cannot build enough unique items")
            out.append(v)
        return out, holder, lo, hi

    # --- objects ---------------------------------------------------------------------------------------
    def _object(self, flat: list[dict[str, Any]], nots: list[Any], depth: int) -> dict[str, Any]:
        pieces = list(flat)
        present: set[str] = set()
        for _ in range(8):  # dependencies may add names and schemas: until nothing changes
            shape = _Shape(pieces)
            for name in shape.required:
                if not shape.allowed(name):
                    raise _Impossible(f"the required property {name!r} is not allowed (additionalProperties, "
                                      f"propertyNames or a false schema)")
            present |= set(shape.required)
            present |= {n for n in shape.declared if shape.allowed(n) and self.rng.random() < 0.5}
            added = False
            for name in sorted(present):
                for d in shape.dependencies.get(name) or []:
                    if isinstance(d, list):
                        new = {x for x in d if isinstance(x, str)} - present
                        present |= new
                        added = added or bool(new)
                    elif isinstance(d, dict) and d not in pieces:
                        pieces.append(d)
                        added = True
            if not added:
                break
        shape = _Shape(pieces)
        if shape.min_props > MAX_SIZE:
            raise _Impossible(f"minProperties {shape.min_props} above the {MAX_SIZE} a virtual Thing builds")
        if len(shape.required) > shape.max_props:
            raise _Impossible(f"{len(shape.required)} required properties above maxProperties {shape.max_props}")
        optional = sorted(present - set(shape.required))
        self.rng.shuffle(optional)
        names = list(shape.required) + optional[:max(0, shape.max_props - len(shape.required))]
        out: dict[str, Any] = {}
        for name in names:
            if not shape.allowed(name):
                continue
            try:
                out[name] = self._value(shape.schemas(name), [], depth + 1)
            except _Impossible:
                if name in shape.required:
                    raise
        wanted = shape.min_props
        if not shape.declared and not shape.required and self.rng.random() < 0.5:
            wanted = max(wanted, min(shape.max_props, len(out) + self.rng.randint(1, 2)))  # a free-form object
        extra = 0
        while len(out) < wanted and extra < 4 * wanted + 8:
            extra += 1
            free = self._free_name(shape, out)
            if free is None:
                break
            try:
                out[free] = self._value(shape.schemas(free), [], depth + 1)
            except _Impossible:
                continue
        for name in list(out):  # the names a name added for minProperties depends on
            for d in shape.dependencies.get(name) or []:
                for other in d if isinstance(d, list) else []:
                    if isinstance(other, str) and other not in out and shape.allowed(other):
                        out[other] = self._value(shape.schemas(other), [], depth + 1)
        if len(out) < shape.min_props:
            raise _Impossible(f"cannot find {shape.min_props} properties it allows (minProperties)")
        for n in nots:  # what must not match, broken on purpose where it still does
            if isinstance(n, dict) and _locally_valid(out, n):
                self._break(out, n, shape, depth)
        return out

    def _free_name(self, shape: "_Shape", taken: dict[str, Any], avoid: Any = None) -> str | None:
        """A property name the object allows that it does not have yet (and `avoid` does not refuse)."""
        def fits(name: str) -> bool:
            return name not in taken and shape.allowed(name) and not (avoid and avoid(name))

        for name in shape.declared:
            if fits(name):
                return name
        for pattern in shape.patterns:
            try:
                name = self._regex.xeger(pattern)
            except Exception:
                continue
            if fits(name):
                return name
        for _ in range(4):
            if shape.names:
                try:
                    name = self._value([{"type": "string"}, *shape.names], [], 1)
                except _Impossible:
                    return None
            else:
                name = f"p{len(taken) + 1}{self.rng.choice(string.ascii_lowercase)}"
            if fits(name):
                return name
        return None

    def _break(self, out: dict[str, Any], n: dict[str, Any], shape: "_Shape", depth: int) -> None:
        """Make `out` stop matching `n` while it keeps to its own shape: leave out a name `n` requires,
        give a property a value `n` refuses, add a property or a name `n` does not allow."""
        moves: list[tuple[Any, ...]] = []
        for name in n.get("required") or []:
            if name in out and name not in shape.required:
                moves.append(("drop", name))
        for name, sub in (n.get("properties") or {}).items():
            if shape.allowed(name) and sub is not True and sub != {}:
                moves.append(("refuse", name, sub))
        for pattern, sub in (n.get("patternProperties") or {}).items():
            if sub is not True and sub != {}:
                moves.append(("pattern", pattern, sub))
        extra = n.get("additionalProperties", True)
        if extra is not True and extra != {}:
            moves.append(("extra", extra))
        if _is_num(n.get("maxProperties")):
            moves.append(("grow", n["maxProperties"]))
        if n.get("propertyNames", True) not in (True, {}):
            moves.append(("name", n["propertyNames"]))
        if "enum" in n or "const" in n:  # one property more makes it another value
            moves.append(("grow", len(out)))
        self.rng.shuffle(moves)
        for move in moves:
            try:
                self._move(out, n, shape, move, depth)
            except _Impossible:
                continue
            if not _locally_valid(out, n):
                return

    def _move(self, out: dict[str, Any], n: dict[str, Any], shape: "_Shape", move: tuple[Any, ...], depth: int) -> None:
        kind = move[0]
        if kind == "drop":
            if len(out) - 1 >= shape.min_props:
                del out[move[1]]
        elif kind == "refuse":
            out[move[1]] = self._value(shape.schemas(move[1]), [move[2]], depth + 1)
        elif kind == "pattern":
            name = self._regex.xeger(move[1])
            if name not in out and shape.allowed(name):
                out[name] = self._value(shape.schemas(name), [move[2]], depth + 1)
        elif kind == "extra":
            own = set(n.get("properties") or {})
            patterns = [p for p in n.get("patternProperties") or {} if isinstance(p, str)]
            free = self._free_name(shape, out, avoid=lambda x: x in own or any(_search(p, x) for p in patterns))
            if free is not None:
                out[free] = self._value(shape.schemas(free), [] if move[1] is False else [move[1]], depth + 1)
        elif kind == "grow":
            while len(out) <= move[1]:
                free = self._free_name(shape, out)
                if free is None:
                    return
                out[free] = self._value(shape.schemas(free), [], depth + 1)
        elif kind == "name":
            name = self._value([{"type": "string"}, *shape.names], [move[1]], depth + 1)
            if name not in out and shape.allowed(name):
                out[name] = self._value(shape.schemas(name), [], depth + 1)


class _Shape:
    """What a conjunction of schemas says about an object's properties."""

    def __init__(self, pieces: list[dict[str, Any]]):
        self.pieces = pieces
        self.required: list[str] = []
        self.declared: list[str] = []
        self.patterns: list[str] = []
        self.names: list[Any] = []
        self.dependencies: dict[str, list[Any]] = {}
        self.min_props = max([int(p["minProperties"]) for p in pieces if _is_num(p.get("minProperties"))] or [0])
        self.max_props = min([int(p["maxProperties"]) for p in pieces if _is_num(p.get("maxProperties"))] or [10**6])
        for p in pieces:
            for name in p.get("required") or []:
                if isinstance(name, str) and name not in self.required:
                    self.required.append(name)
            for name in p.get("properties") or {}:
                if name not in self.declared:
                    self.declared.append(name)
            self.patterns += [pat for pat in p.get("patternProperties") or {} if isinstance(pat, str)]
            if "propertyNames" in p:
                self.names.append(p["propertyNames"])
            for name, dep in (p.get("dependencies") or {}).items():
                self.dependencies.setdefault(name, []).append(dep)

    def schemas(self, name: str) -> list[Any]:
        """Every schema the property `name` must satisfy."""
        out: list[Any] = []
        for p in self.pieces:
            props = p.get("properties") or {}
            matched = [s for pat, s in (p.get("patternProperties") or {}).items() if _search(pat, name)]
            if name in props:
                out.append(props[name])
            out += matched
            if name not in props and not matched and "additionalProperties" in p:
                out.append(p["additionalProperties"])
        return out

    def allowed(self, name: str) -> bool:
        return all(s is not False for s in self.schemas(name)) and all(
            _locally_valid(name, names) for names in self.names)


_SURE = {  # keywords each kind of value is built to satisfy outright (the whole value is checked at the end)
    "scalar": {"type", "minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "multipleOf", "minLength",
               "maxLength", "pattern"},
    "array": {"type", "items", "minItems", "maxItems"},
}
_VOCABULARY = {"type", "enum", "const", "multipleOf", "maximum", "exclusiveMaximum", "minimum", "exclusiveMinimum",
               "maxLength", "minLength", "pattern", "format", "items", "additionalItems", "maxItems", "minItems",
               "uniqueItems", "contains", "maxProperties", "minProperties", "required", "properties",
               "patternProperties", "additionalProperties", "dependencies", "propertyNames"}


def _built_right(value: Any, flat: list[dict[str, Any]]) -> bool:
    """The value needs no check of its own here: the builder satisfies every keyword it was given
    (a number within merged bounds, a list of items each checked in turn); it saves a validation per
    item of a 64-item array."""
    if isinstance(value, dict):
        return False
    sure = _SURE["array"] if isinstance(value, list) else _SURE["scalar"]
    return all(not isinstance(s.get("items"), list) and _VOCABULARY.intersection(s) <= sure for s in flat)


def _item_schemas(s: dict[str, Any], i: int) -> list[Any]:
    items = s.get("items")
    if isinstance(items, list):
        if i < len(items):
            return [items[i]]
        return [s["additionalItems"]] if "additionalItems" in s else []
    return [items] if items is not None else []


def _locally_valid(value: Any, schema: Any) -> bool:
    """`is_valid`, for a part of a schema: a `$ref` it cannot resolve alone is left to the whole schema's check."""
    if isinstance(schema, dict) and b'"$ref"' in msgspec.json.encode(schema):
        return True
    try:
        return is_valid(value, schema)
    except Exception:
        return True


def _search(pattern: str, name: str) -> bool:
    try:
        return re.search(pattern, name) is not None
    except re.error:
        return False


def _json(v: Any) -> bytes:
    return msgspec.json.encode(v, order="deterministic")


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _expand(kinds: Any) -> set[str]:
    out = {kinds} if isinstance(kinds, str) else {k for k in kinds if isinstance(k, str)} if isinstance(
        kinds, list) else set(TYPES)
    if "number" in out:
        out.add("integer")
    return out


def _hinted(s: dict[str, Any]) -> set[str]:
    """The types a schema's keywords are about, when it names none."""
    out = set()
    if any(k in s for k in ("properties", "required", "patternProperties", "additionalProperties", "minProperties",
                            "maxProperties", "dependencies", "propertyNames")):
        out.add("object")
    if any(k in s for k in ("items", "minItems", "maxItems", "contains", "uniqueItems", "additionalItems")):
        out.add("array")
    if any(k in s for k in ("minimum", "maximum", "exclusiveMinimum", "exclusiveMaximum", "multipleOf")):
        out.add("number")
    if any(k in s for k in ("minLength", "maxLength", "pattern", "format")):
        out.add("string")
    return out


def strict_multiple(v: float, m: float) -> bool:
    """`v` is a multiple of `m` as jsonschema and node-wot's ajv judge it: `v / m` an exact integer in
    floating point (17.7 is no multiple of 0.1 to them: 17.7 / 0.1 = 176.99999999999997). The
    adapter's own input check is more lenient; values given out must pass the strict test."""
    q = v / m
    return math.isfinite(q) and q == int(q)


def _bounds(flat: list[dict[str, Any]], integer: bool) -> tuple[float, float]:
    tiny = 1 if integer else 1e-6
    los = [s["minimum"] for s in flat if _is_num(s.get("minimum"))]
    los += [s["exclusiveMinimum"] + tiny for s in flat if _is_num(s.get("exclusiveMinimum"))]
    his = [s["maximum"] for s in flat if _is_num(s.get("maximum"))]
    his += [s["exclusiveMaximum"] - tiny for s in flat if _is_num(s.get("exclusiveMaximum"))]
    lo: Any = max(los) if los else None
    hi: Any = min(his) if his else None
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


# --- why there is no value ------------------------------------------------------------------------------
def _explain(schema: Any, reasons: dict[str, int], tries: int) -> str:
    """One line: the JSON pointer and the keywords that contradict each other, where a walk over the
    parts every value must satisfy finds them; else what the builder ran into."""
    found = _contradiction(schema, "")
    if found:
        return found
    common = max(reasons, key=lambda r: reasons[r]) if reasons else "every value built broke the schema"
    return f": no valid value found in {tries} tries ({common})"


def _contradiction(s: Any, at: str) -> str | None:
    if s is False:
        return f"{at}: the schema false allows nothing"
    if not isinstance(s, dict):
        return None
    where = at
    local = _local_contradiction(s)
    if local:
        return f"{where}: {local}"
    for i, sub in enumerate(s.get("allOf") or []):
        found = _contradiction(sub, f"{at}/allOf/{i}")
        if found:
            return found
    for key in ("anyOf", "oneOf"):
        branches = s.get(key)
        if isinstance(branches, list) and branches:
            found_all = [_contradiction(b, f"{at}/{key}/{i}") for i, b in enumerate(branches)]
            if all(found_all):
                return f"{where}: every {key} branch is impossible ({'; '.join(str(f) for f in found_all)})"
    props = s.get("properties") or {}
    for name in s.get("required") or []:
        if name in props:
            found = _contradiction(props[name], f"{at}/properties/{_pointer([name])[1:]}")
            if found:
                return found
    items = s.get("items")
    min_items = s.get("minItems", 0)
    if isinstance(items, dict) and _is_num(min_items) and min_items > 0:
        return _contradiction(items, f"{at}/items")
    if isinstance(items, list):
        for i, sub in enumerate(items[:int(min_items) if _is_num(min_items) else 0]):
            found = _contradiction(sub, f"{at}/items/{i}")
            if found:
                return found
    if "contains" in s:
        return _contradiction(s["contains"], f"{at}/contains")
    return None


def _local_contradiction(s: dict[str, Any]) -> str | None:
    """Keywords of one schema object that no value satisfies together."""
    kinds = _expand(s["type"]) if "type" in s else set(TYPES)
    if "type" in s and not kinds:
        return "type [] allows nothing"
    n = s.get("not")
    if n is True or n == {}:
        return f"not {msgspec.json.encode(n).decode()} allows nothing"
    if isinstance(n, dict) and "type" in n and not set(n) - {"type", "title", "description"} and kinds <= _expand(n["type"]):
        return f"type {_show(s.get('type', 'any'))} and not type {_show(n['type'])}"
    numeric = bool(kinds & {"number", "integer"})
    lo_key = next((k for k in ("minimum", "exclusiveMinimum") if _is_num(s.get(k))), None)
    hi_key = next((k for k in ("maximum", "exclusiveMaximum") if _is_num(s.get(k))), None)
    if numeric and kinds <= {"number", "integer"} and lo_key and hi_key:
        lo, hi = s[lo_key], s[hi_key]
        if lo > hi or (lo == hi and (lo_key != "minimum" or hi_key != "maximum")):
            return f"{lo_key} {_num(lo)} {'>' if lo > hi else '='} {hi_key} {_num(hi)}"
        if kinds == {"integer"}:
            i_lo, i_hi = _bounds([s], True)
            if i_lo > i_hi:
                return f"no integer between {lo_key} {_num(lo)} and {hi_key} {_num(hi)}"
        m = s.get("multipleOf")
        if isinstance(m, (int, float)) and m > 0 and math.ceil(lo / m) > math.floor(hi / m):
            return f"no multiple of {_num(m)} between {lo_key} {_num(lo)} and {hi_key} {_num(hi)}"
    for lo_key, hi_key, kind in (("minLength", "maxLength", "string"), ("minItems", "maxItems", "array"),
                                 ("minProperties", "maxProperties", "object")):
        if kinds <= {kind} and _is_num(s.get(lo_key)) and _is_num(s.get(hi_key)) and s[lo_key] > s[hi_key]:
            return f"{lo_key} {s[lo_key]} > {hi_key} {s[hi_key]}"
    if kinds <= {"object"}:
        required = [r for r in s.get("required") or [] if isinstance(r, str)]
        if _is_num(s.get("maxProperties")) and len(required) > s["maxProperties"]:
            return f"required names {len(required)} properties > maxProperties {s['maxProperties']}"
        props = s.get("properties") or {}
        for name in required:
            if props.get(name) is False:
                return f"required {name!r} and properties/{name}: false"
            if name not in props and s.get("additionalProperties") is False and not any(
                    _search(p, name) for p in s.get("patternProperties") or {}):
                return f"required {name!r} and additionalProperties false (not in properties)"
    if "const" in s or "enum" in s:
        options = [s["const"]] if "const" in s else s["enum"] if isinstance(s["enum"], list) else []
        rest = {k: v for k, v in s.items() if k != ("const" if "const" in s else "enum")}
        if not options:
            return "enum [] allows nothing"
        if not any(_locally_valid(v, rest) for v in options):
            term = f"const {_show(s['const'])}" if "const" in s else f"enum {_show(options)}"
            others = ", ".join(f"{k} {_show(v)}" for k, v in rest.items() if k in _VALIDATION)
            return f"{term} and {others or 'its other keywords'}: no value listed satisfies the others"
    return None


_VALIDATION = ("type", "enum", "const", "multipleOf", "maximum", "exclusiveMaximum", "minimum", "exclusiveMinimum",
               "maxLength", "minLength", "pattern", "format", "maxItems", "minItems", "uniqueItems", "maxProperties",
               "minProperties", "required")


def _show(v: Any) -> str:
    text = msgspec.json.encode(v).decode()
    return text if len(text) < 60 else text[:57] + "..."


def _num(x: Any) -> str:
    return str(int(x)) if _is_num(x) and float(x).is_integer() else str(x)


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
    "duration": lambda rng: f"PT{rng.randint(1, 59)}S",
}
