"""Values are checked against the whole schema a TD states, also the keywords the TD model does not hold
(`patternProperties`, `not`, `definitions` behind a `$ref`, ...): never a part of it, in the adapter and
in the device alike."""
from __future__ import annotations

import pytest
from fake_registry import FakeRegistry
from starlette.testclient import TestClient

from mesh.http.app import create_app
from mesh.wot.problem import BadInput
from mesh.wot.thing_description import decode_td
from mesh.wot.validate import SourceSchemas, validate

PATTERNED = {"type": "object", "patternProperties": {"^s_[a-z]+$": {"type": "string"}},
             "additionalProperties": False, "minProperties": 1}
REFERRED = {"definitions": {"pct": {"type": "integer", "minimum": 0, "maximum": 100}}, "type": "array",
            "items": {"$ref": "#/definitions/pct"}}
NOT_NULL = {"not": {"type": "null"}}


def _td() -> dict:
    return {"@context": "https://www.w3.org/2022/wot/td/v1.1", "title": "kw", "securityDefinitions":
            {"nosec_sc": {"scheme": "nosec"}}, "security": ["nosec_sc"],
            "properties": {"tags": {**PATTERNED, "forms": [{"href": "x"}]}},
            "actions": {"set": {"input": REFERRED, "forms": [{"href": "y"}]},
                        "put": {"input": NOT_NULL, "forms": [{"href": "z"}]}}}


def test_the_model_alone_refuses_valid_values_and_lets_forbidden_ones_through():
    """Why the document's schema is needed: the model has no patternProperties, no definitions, no not."""
    td = decode_td(_td())
    with pytest.raises(BadInput):
        validate({"s_a": "x"}, td.properties["tags"], "tags")  # additionalProperties false, alone
    validate(None, td.actions["put"].input, "input")  # `not` lost: null passes


def test_the_documents_schema_takes_valid_values_and_refuses_the_others():
    raw = _td()
    td, schemas = decode_td(raw), SourceSchemas(raw)
    validate({"s_a": "x", "s_b": "y"}, schemas.of(td.properties["tags"], "properties", "tags"), "tags")
    with pytest.raises(BadInput):
        validate({"other": "x"}, schemas.of(td.properties["tags"], "properties", "tags"), "tags")
    validate([0, 50, 100], schemas.of(td.actions["set"].input, "actions", "set", "input"))
    with pytest.raises(BadInput):
        validate([101], schemas.of(td.actions["set"].input, "actions", "set", "input"))
    with pytest.raises(BadInput):
        validate(None, schemas.of(td.actions["put"].input, "actions", "put", "input"))
    assert schemas.of(None, "actions", "x", "input") is None


def test_the_adapter_takes_a_write_and_an_input_the_whole_schema_allows():
    reg = FakeRegistry()
    reg.add(_td(), values={"tags": {"s_a": "x"}}, actions={"set": lambda v: None, "put": lambda v: None})
    with TestClient(create_app(reg)) as client:
        assert client.put("/kw/properties/tags", json={"s_b": "y"}).status_code == 204
        assert client.put("/kw/properties/tags", json={"b": "y"}).status_code == 400
        assert client.post("/kw/actions/set", json=[1, 2]).status_code in (200, 204)
        refused = client.post("/kw/actions/set", json=[101])
        assert refused.status_code == 400 and refused.headers["content-type"].startswith("application/problem+json")
        assert client.post("/kw/actions/put", json=None).status_code == 400
