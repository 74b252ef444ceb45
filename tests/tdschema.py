"""Validate Thing Descriptions (and Thing Models) against the official TD 1.1 JSON schemas, formats checked.

The schema alone is loose (NOTES.md): it does not check that security names exist in
securityDefinitions, so that is checked here too.
"""
from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path

import jsonschema

DATA = Path(__file__).resolve().parent / "data"  # copies, with their sources in data/SOURCES.md
TD_SCHEMA = DATA / "wot" / "td-1.1-json-schema-validation.json"
TM_SCHEMA = DATA / "wot" / "tm-1.1-json-schema-validation.json"
REFERENCE_TDS = DATA / "reference-tds"


@lru_cache(maxsize=2)
def _validator(path: Path = TD_SCHEMA) -> jsonschema.protocols.Validator:
    schema = json.loads(path.read_text())
    cls = jsonschema.validators.validator_for(schema)
    return cls(schema, format_checker=cls.FORMAT_CHECKER)


def td_errors(td: dict) -> list[str]:
    """All problems of a TD: schema violations (formats included) and dangling security names."""
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in _validator().iter_errors(td)]
    security = td.get("security", [])
    for name in [security] if isinstance(security, str) else security:
        if name not in td.get("securityDefinitions", {}):
            errors.append(f"security: {name!r} is not in securityDefinitions")
    return errors


def assert_valid_td(td: dict) -> None:
    errors = td_errors(td)
    assert not errors, "TD invalid:\n" + "\n".join(errors)


def assert_valid_tm(tm: dict) -> None:
    """A Thing Model (TD 1.1 §10) against the official TM schema, formats checked."""
    errors = [f"{'/'.join(map(str, e.absolute_path))}: {e.message}" for e in _validator(TM_SCHEMA).iter_errors(tm)]
    assert not errors, "TM invalid:\n" + "\n".join(errors)
