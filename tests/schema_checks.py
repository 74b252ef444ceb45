"""The check every generated value must pass: jsonschema's draft 7 validator with formats, and ours."""
from __future__ import annotations

from jsonschema import Draft7Validator

from mesh.wot.problem import BadInput
from mesh.wot.validate import validate


def why_invalid(value, schema) -> str | None:
    """None when `value` is valid by `schema` for both validators, else the first one's reason."""
    errors = list(Draft7Validator(schema, format_checker=Draft7Validator.FORMAT_CHECKER).iter_errors(value))
    if errors:
        return errors[0].message
    try:
        validate(value, schema, path="value")
    except BadInput as e:
        return e.detail
    return None
