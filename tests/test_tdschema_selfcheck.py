"""The validator really rejects what the official schema and our extra checks reject."""
from tdschema import td_errors


def _td(**over):
    td = {
        "@context": ["https://www.w3.org/2019/wot/td/v1", "https://www.w3.org/2022/wot/td/v1.1"],
        "id": "urn:uuid:0804d572-cce8-422a-bb7c-4412fcd56f06",
        "title": "t",
        "security": ["nosec_sc"],
        "securityDefinitions": {"nosec_sc": {"scheme": "nosec"}},
        "properties": {"p": {"type": "number", "forms": [{"href": "http://127.0.0.1/p"}]}},
    }
    td.update(over)
    return td


def test_minimal_td_is_valid():
    assert td_errors(_td()) == []


def test_relative_id_is_rejected_by_format_check():
    assert td_errors(_td(id="not a uri"))


def test_dangling_security_name_is_rejected():
    assert any("securityDefinitions" in e for e in td_errors(_td(security=["basic_sc"])))
