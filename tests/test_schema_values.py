"""Virtual Things' values (issue 49): a valid value for every satisfiable draft 7 schema, built and
seeded; a schema with none is refused in one line naming its JSON pointer and the keywords at odds.

Each value is judged twice: by jsonschema's own Draft7Validator with its format checker (what node-wot's
ajv and any other consumer would apply) and by twinmesh's input validator.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from schema_checks import why_invalid

from mesh.wot.schema_values import NoValue, SchemaValues

DATA = Path(__file__).parent / "data"
HUE = json.loads((DATA / "td-corpus" / "plugfest-2021" / "philips-hue__lightTD1.td.jsonld").read_text())
HUE_OUTPUT = HUE["actions"]["setState"]["output"]  # items' optional `success`: a oneOf every object fits 9 of 10 branches of
HUE_SUCCESS = HUE_OUTPUT["items"]["properties"]["success"]


def values(schema, seed: int, n: int = 12) -> list:
    source = SchemaValues(seed)
    source.prepare(schema)
    return [source.value(schema) for _ in range(n)]


# one construct each (and their nesting): the keyword's name, a schema, what its values must show
KEYWORDS = {
    "oneOf-overlapping": ({"oneOf": [{"type": "integer"}, {"type": "number", "minimum": 0}]}, None),
    "oneOf-objects-every-one-fits": ({"type": "object", "required": ["success"], "properties": {"success": HUE_SUCCESS}},
                                     None),
    "anyOf": ({"anyOf": [{"type": "integer", "minimum": 10}, {"type": "string", "pattern": "^x-[0-9]+$"}]}, None),
    "allOf": ({"allOf": [{"type": "integer"}, {"minimum": 3}, {"maximum": 5}, {"not": {"const": 4}}]},
              lambda v: v in (3, 5)),
    "not": ({"not": {"type": "null"}}, lambda v: v is not None),
    "not-enum": ({"type": "string", "enum": ["a", "b", "c"], "not": {"enum": ["a", "b"]}}, lambda v: v == "c"),
    "if-then-else": ({"type": "object", "required": ["kind"], "properties": {"kind": {"enum": ["a", "b"]}},
                      "if": {"properties": {"kind": {"const": "a"}}},
                      "then": {"required": ["x"], "properties": {"x": {"type": "integer"}}},
                      "else": {"required": ["y"], "properties": {"y": {"type": "string"}}}}, None),
    "dependencies": ({"type": "object", "properties": {"a": {"type": "integer"}, "b": {"type": "string"}},
                      "required": ["a"], "dependencies": {"a": ["b"], "b": {"required": ["c"],
                                                                           "properties": {"c": {"const": 1}}}}},
                     lambda v: v.get("c") == 1 and "b" in v),
    "patternProperties": ({"type": "object", "patternProperties": {"^s_[a-z]+$": {"type": "string"}},
                           "additionalProperties": False, "minProperties": 2},
                          lambda v: len(v) >= 2 and all(k.startswith("s_") for k in v)),
    "propertyNames": ({"type": "object", "propertyNames": {"pattern": "^[a-z]{2,4}$"}, "minProperties": 2},
                      lambda v: len(v) >= 2),
    "additionalProperties": ({"type": "object", "properties": {"a": {"type": "integer"}}, "required": ["a"],
                              "additionalProperties": {"type": "string", "minLength": 2}, "minProperties": 3},
                             lambda v: len(v) >= 3),
    "additionalProperties-false": ({"type": "object", "properties": {"a": {"type": "integer"}},
                                    "additionalProperties": False}, lambda v: set(v) <= {"a"}),
    "contains": ({"type": "array", "items": {"anyOf": [{"type": "integer"}, {"type": "string"}]},
                  "contains": {"type": "integer", "minimum": 50}}, lambda v: any(isinstance(x, int) and x >= 50 for x in v)),
    "uniqueItems": ({"type": "array", "items": {"type": "integer", "minimum": 0, "maximum": 4}, "uniqueItems": True,
                     "minItems": 5}, lambda v: sorted(v) == [0, 1, 2, 3, 4]),
    "tuple-items": ({"type": "array", "items": [{"type": "string"}, {"type": "boolean"}], "additionalItems": False,
                     "minItems": 2}, lambda v: len(v) == 2),
    "enum-of-objects": ({"enum": [{"mode": "eco", "level": 1}, {"mode": "boost", "level": [2, 3]}]}, None),
    "const-object": ({"const": {"a": [1, {"b": None}]}}, lambda v: v == {"a": [1, {"b": None}]}),
    "multipleOf-fraction": ({"type": "number", "minimum": 0.5, "maximum": 1.5, "multipleOf": 0.01}, None),
    "multipleOf-two": ({"type": "integer", "multipleOf": 6, "allOf": [{"multipleOf": 4}], "minimum": 1, "maximum": 50},
                       lambda v: v in (12, 24, 36, 48)),
    "formats": ({"type": "object", "required": ["t", "d", "e", "ip", "ip6", "u", "h", "id"],
                 "properties": {"t": {"format": "date-time"}, "d": {"format": "date"}, "e": {"format": "email"},
                                "ip": {"format": "ipv4"}, "ip6": {"format": "ipv6"}, "u": {"format": "uri"},
                                "h": {"format": "hostname"}, "id": {"format": "uuid"}}}, None),
    "pattern-and-lengths": ({"type": "string", "pattern": "[0-9]{2}", "minLength": 6, "maxLength": 8}, None),
    "ref": ({"definitions": {"pct": {"type": "integer", "minimum": 0, "maximum": 100}},
             "type": "array", "minItems": 1, "items": {"$ref": "#/definitions/pct"}}, None),
    "nesting": ({"type": "array", "minItems": 2, "items": {
        "type": "object", "required": ["id", "reading"],
        "properties": {"id": {"type": "string", "format": "uuid"},
                       "reading": {"oneOf": [{"type": "number", "minimum": 0}, {"type": "null"},
                                             {"type": "object", "additionalProperties": False,
                                              "patternProperties": {"^[a-z]+$": {"type": "boolean"}}}]}},
        "if": {"required": ["tags"]}, "then": {"properties": {"tags": {"type": "array", "uniqueItems": True,
                                                                         "items": {"enum": ["x", "y", "z"]}}}},
        "not": {"required": ["forbidden"]}}}, lambda v: all("forbidden" not in x for x in v)),
}


@pytest.mark.parametrize("keyword", list(KEYWORDS))
def test_every_keyword_gets_valid_values_for_every_seed(keyword):
    schema, shows = KEYWORDS[keyword]
    for seed in range(6):
        for v in values(schema, seed):
            assert why_invalid(v, schema) is None, (keyword, seed, v, why_invalid(v, schema))
            assert shows is None or shows(v), (keyword, seed, v)


@pytest.mark.parametrize("seed", range(40))
def test_the_hue_lamps_set_state_answers_a_valid_output_for_every_seed(seed):
    """The issue's HTTP 500: the output was refused (NoValue) whenever an item drew its optional `success`."""
    for v in values(HUE_OUTPUT, seed, n=5):
        assert why_invalid(v, HUE_OUTPUT) is None, v


def test_a_oneof_every_object_fits_still_gets_a_success_that_fits_one_branch():
    """An object with one branch's property fits all ten branches (all optional): a value that fits one
    exactly must give the other branches' properties values they refuse."""
    schema = KEYWORDS["oneOf-objects-every-one-fits"][0]
    seen = {json.dumps(v, sort_keys=True) for seed in range(3) for v in values(schema, seed, n=4)}
    assert len(seen) > 3, "the same value every time"


@pytest.mark.parametrize("schema", [{"not": {"type": "null"}},
                                    KEYWORDS["if-then-else"][0], KEYWORDS["patternProperties"][0],
                                    KEYWORDS["propertyNames"][0]],
                         ids=["not-null", "if-then-else", "patternProperties", "propertyNames"])
def test_the_issues_refused_schemas_are_served(schema):
    for v in values(schema, 0):
        assert why_invalid(v, schema) is None


def test_the_same_seed_gives_the_same_values_and_another_seed_others():
    schema = KEYWORDS["nesting"][0]
    assert values(schema, 5) == values(schema, 5)
    assert values(schema, 5) != values(schema, 6)


def test_a_schema_is_prepared_alike_in_every_process():
    """What passed `twinmesh up --thing` in the CLI's process must pass in the one that serves it: a
    schema's pool comes from the schema alone."""
    code = ("import json,sys; from mesh.wot import schema_values as s; schema=json.loads(sys.argv[1]); "
            "print(json.dumps([json.loads(v) for v in s._plan(schema, '').pool]))")
    pools = [subprocess.run([sys.executable, "-c", code, json.dumps(HUE_OUTPUT)], capture_output=True, text=True,
                            check=True).stdout for _ in range(2)]
    assert pools[0] == pools[1] and json.loads(pools[0])


# a schema no value satisfies, and the line that must say so (JSON pointer, keywords)
UNSATISFIABLE = [
    ({"type": "integer", "minimum": 5, "maximum": 3}, ": minimum 5 > maximum 3"),
    ({"type": "object", "required": ["a"], "properties": {"a": {"type": "number", "exclusiveMinimum": 2,
                                                                  "exclusiveMaximum": 2}}},
     "/properties/a: exclusiveMinimum 2 = exclusiveMaximum 2"),
    ({"type": "integer", "minimum": 1.2, "maximum": 1.8}, ": no integer between minimum 1.2 and maximum 1.8"),
    ({"type": "string", "minLength": 4, "maxLength": 2}, ": minLength 4 > maxLength 2"),
    ({"type": "array", "minItems": 1, "items": {"type": "string", "enum": ["a"], "minLength": 3}},
     '/items: enum ["a"] and type "string", minLength 3: no value listed satisfies the others'),
    ({"type": "object", "required": ["x"], "properties": {"y": {}}, "additionalProperties": False},
     ": required 'x' and additionalProperties false (not in properties)"),
    ({"type": "string", "not": {"type": "string"}}, ': type "string" and not type "string"'),
    ({"not": {}}, ": not {} allows nothing"),
    ({"anyOf": [{"type": "integer", "minimum": 3, "maximum": 1}, {"type": "string", "maxLength": 1, "minLength": 2}]},
     ": every anyOf branch is impossible (/anyOf/0: minimum 3 > maximum 1; /anyOf/1: minLength 2 > maxLength 1)"),
    ({"allOf": [{"type": "string"}, {"type": "integer"}]}, ": no valid value found"),
]


@pytest.mark.parametrize("schema, says", UNSATISFIABLE, ids=[s for _, s in UNSATISFIABLE])
def test_an_unsatisfiable_schema_is_refused_in_one_line_naming_the_pointer_and_keywords(schema, says):
    with pytest.raises(NoValue) as refused:
        SchemaValues(0).prepare(schema, "t (td.json): /actions/a/output")
    line = str(refused.value)
    assert line.startswith("t (td.json): /actions/a/output") and says in line and "\n" not in line, line


def test_an_invalid_schema_is_refused_with_the_validators_words():
    with pytest.raises(NoValue) as refused:
        SchemaValues(0).prepare({"type": "object", "properties": {"a": {"type": "strin"}}}, "t: /properties/p")
    assert str(refused.value).startswith("t: /properties/p/properties/a/type: not valid JSON Schema: 'strin'")


def test_a_refused_schema_stays_refused_and_a_served_one_never_fails():
    source = SchemaValues(1)
    for _ in range(2):
        with pytest.raises(NoValue):
            source.value({"type": "integer", "minimum": 5, "maximum": 3})
    for _ in range(200):
        assert why_invalid(source.value(HUE_OUTPUT), HUE_OUTPUT) is None


def _corpus() -> list[tuple[str, object]]:
    from devices.things.virtual import schemas_of

    files = [p for folder in ("td-corpus", "reference-tds/real-lab", "tds") for p in sorted((DATA / folder).rglob("*"))
             if p.suffix in (".json", ".jsonld") and "refused" not in p.parts]
    return [(f"{p.relative_to(DATA)}#/{'/'.join(where)}", schema)
            for p in files for schema, where in schemas_of(json.loads(p.read_text()))]


def test_every_schema_of_the_published_corpus_gets_valid_values():
    """Every property, action output and event data of every TD under tests/data (published TDs, the
    real lab's, the TD Playground's examples, one TD per construct)."""
    corpus = _corpus()
    assert len(corpus) > 300
    wrong = []
    for seed in (0, 1):
        source = SchemaValues(seed)
        for where, schema in corpus:
            for v in (source.value(schema, where) for _ in range(3)):
                why = why_invalid(v, schema)
                if why:
                    wrong.append(f"{where}: {json.dumps(v)[:80]}: {why}")
    assert wrong == [], "\n".join(wrong)
