"""Random draft 7 schemas, each satisfiable by construction, get valid values (issue 49).

Hypothesis draws a JSON value first and then a schema that value satisfies, from the keywords a TD
may use (type, bounds, multipleOf, lengths, pattern, enum/const, items, tuples, contains, uniqueItems,
properties, required, additionalProperties, patternProperties, propertyNames, dependencies,
min/maxProperties) wrapped in allOf, anyOf, oneOf (beside a branch the value breaks), not and
if/then/else. The value proves the schema satisfiable, so a refusal is the generator's fault; every
value given out is checked by jsonschema's Draft7Validator and by twinmesh's validator.
"""
from __future__ import annotations

import re
import string

from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from jsonschema import Draft7Validator
from schema_checks import why_invalid

from mesh.wot.schema_values import NoValue, SchemaValues

KEYS = st.text(string.ascii_lowercase, min_size=1, max_size=6)
VALUES = st.recursive(
    st.none() | st.booleans() | st.integers(-1000, 1000) | st.floats(-1e3, 1e3, allow_nan=False).map(lambda x: round(x, 2))
    | st.text(string.ascii_letters + string.digits + " -_", max_size=10),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(KEYS, inner, max_size=4),
    max_leaves=10,
)


def satisfies(value, schema) -> bool:
    return Draft7Validator(schema).is_valid(value)


def kind(v) -> str:
    if v is None:
        return "null"
    if isinstance(v, bool):
        return "boolean"
    if isinstance(v, int):
        return "integer"
    if isinstance(v, float):
        return "number"
    return {str: "string", list: "array", dict: "object"}[type(v)]


def subset(names: list[str]) -> st.SearchStrategy[list[str]]:
    return st.lists(st.booleans(), min_size=len(names), max_size=len(names)).map(
        lambda keep: [n for n, k in zip(names, keep) if k])


@st.composite
def described(draw, v, depth: int = 0):
    """A schema `v` satisfies, from the keywords of its type."""
    s: dict = {}
    t = kind(v)
    if draw(st.booleans()):
        s["type"] = t if t != "integer" or draw(st.booleans()) else "number"
    if t in ("integer", "number"):
        if draw(st.booleans()):
            s["minimum"] = v - draw(st.integers(0, 50))
        if draw(st.booleans()):
            s["exclusiveMaximum"] = v + draw(st.integers(1, 50))
        if t == "integer" and v and draw(st.booleans()):
            s["multipleOf"] = draw(st.sampled_from([d for d in (1, 2, 3, 5, 7, 10) if v % d == 0]))
    elif t == "string":
        if draw(st.booleans()):
            s["minLength"] = draw(st.integers(0, len(v)))
        if draw(st.booleans()):
            s["maxLength"] = len(v) + draw(st.integers(0, 5))
        if v and draw(st.booleans()):
            i = draw(st.integers(0, len(v) - 1))
            s["pattern"] = re.escape(v[i:i + draw(st.integers(1, 3))])
    elif t == "array" and depth < 3:
        if v and draw(st.booleans()):
            s["items"] = {"anyOf": [draw(described(x, depth + 1)) for x in v]}
        elif v and draw(st.booleans()):
            s["items"] = [draw(described(x, depth + 1)) for x in v]
            if draw(st.booleans()):
                s["additionalItems"] = False
        if v and draw(st.booleans()):
            s["contains"] = draw(described(draw(st.sampled_from(v)), depth + 1))
        if draw(st.booleans()):
            s["minItems"] = draw(st.integers(0, len(v)))
        if draw(st.booleans()):
            s["maxItems"] = len(v) + draw(st.integers(0, 3))
        if draw(st.booleans()) and satisfies(v, {"uniqueItems": True}):
            s["uniqueItems"] = True
    elif t == "object" and depth < 3:
        names = sorted(v)
        declared = draw(subset(names))
        if declared:
            s["properties"] = {k: draw(described(v[k], depth + 1)) for k in declared}
            s["required"] = draw(subset(declared))
        rest = [k for k in names if k not in declared]
        choice = draw(st.integers(0, 3))
        if choice == 1 and not rest:
            s["additionalProperties"] = False
        elif choice == 1:
            s["additionalProperties"] = {"anyOf": [draw(described(v[k], depth + 1)) for k in rest]}
        elif choice == 2 and rest:
            s["patternProperties"] = {f"^{re.escape(k)}$": draw(described(v[k], depth + 1)) for k in rest}
            s["additionalProperties"] = False
        elif choice == 3:
            s["propertyNames"] = {"maxLength": max([len(k) for k in names] or [0]) + draw(st.integers(0, 2))}
        if len(names) > 1 and draw(st.booleans()):
            s["dependencies"] = {names[0]: names[1:]}
        if draw(st.booleans()):
            s["minProperties"] = draw(st.integers(0, len(names)))
        if draw(st.booleans()):
            s["maxProperties"] = len(names) + draw(st.integers(0, 2))
    if draw(st.integers(0, 9)) == 0:
        s["enum"] = [v, draw(VALUES)]
    return s


@st.composite
def wrapped(draw, v, s):
    """`s` (which `v` satisfies) inside a combinator, with a second schema `v` may or may not satisfy."""
    other = draw(described(draw(VALUES)))
    fits = satisfies(v, other)
    how = draw(st.sampled_from(["plain", "allOf", "anyOf", "oneOf", "not", "if", "const"]))
    if how == "allOf" and fits:
        return {"allOf": [s, other]}
    if how == "anyOf":
        return {"anyOf": draw(st.permutations([s, other]))}
    if how == "oneOf" and not fits:
        return {"oneOf": draw(st.permutations([s, other]))}
    if how == "not" and not fits:
        return {**s, "not": other}
    if how == "if":
        return {"if": other, "then": s, "else": {}} if fits else {"if": other, "then": {}, "else": s}
    if how == "const":
        return {"const": v}
    return s


@st.composite
def satisfiable(draw):
    v = draw(VALUES)
    schema = draw(wrapped(v, draw(described(v))))
    assert satisfies(v, schema), (v, schema)
    return v, schema


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])
@given(satisfiable(), st.integers(0, 2**16))
def test_a_schema_some_value_satisfies_gets_valid_values(case, seed):
    witness, schema = case
    source = SchemaValues(seed)
    try:
        source.prepare(schema)
    except NoValue as e:
        raise AssertionError(f"refused a schema {witness!r} satisfies: {e}") from None
    for _ in range(3):
        value = source.value(schema)
        assert why_invalid(value, schema) is None, (value, why_invalid(value, schema))
