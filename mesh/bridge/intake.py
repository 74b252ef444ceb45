"""Taking in a TD written by someone else (a real device's, a published one): from a file or an
http(s) URL, checked to be a TD and not a Thing Model, its relative hrefs made absolute. One line
naming the source and the first problem when it cannot be used; the bridge and the virtual Things
share it."""
from __future__ import annotations

import json
from functools import lru_cache
from pathlib import Path
from typing import Any
from urllib.parse import urljoin

import msgspec

from mesh.wot.problem import UNREACHABLE, Problem
from mesh.wot.thing_description import decode_td

TD_SCHEMA = "td-1.1-json-schema-validation.json"  # W3C's, shipped (mesh/wot/schemas/SOURCE.md)


class IntakeError(ValueError):
    """A TD that cannot be taken in; the message names the source and the first problem.

    `unreachable`: the source did not answer (no connection, or no answer in time), as opposed to
    answering something unusable: a command exits with UNREACHABLE for the first, 2 for the second."""

    def __init__(self, message: str, unreachable: bool = False):
        super().__init__(message)
        self.unreachable = unreachable


def is_url(source: str) -> bool:
    return source.split(":", 1)[0].lower() in ("http", "https")


def fetch_document(source: str, client: Any | None = None) -> dict[str, Any]:
    """The JSON object at `source`: a file, or an http(s) URL fetched with `client`
    (`mesh.http.http_client.HttpClient`: its credentials and certificate checks)."""
    if is_url(source):
        if client is None:
            raise IntakeError(f"{source}: a URL needs an HTTP client")
        try:
            doc = client.fetch_td(source)
        except Problem as p:
            raise IntakeError(f"{source}: {_fetch_problem(p)}", unreachable=p.reason == UNREACHABLE) from None
    else:
        try:
            doc = json.loads(Path(source).read_text(encoding="utf-8"))
        except OSError as e:
            raise IntakeError(f"{source}: cannot be read ({e.strerror or e})") from None
        except (json.JSONDecodeError, UnicodeDecodeError) as e:
            raise IntakeError(f"{source}: not JSON ({e})") from None
    if not isinstance(doc, dict):
        raise IntakeError(f"{source}: a TD is a JSON object, not {type(doc).__name__}")
    return doc


def _fetch_problem(p: Problem) -> str:
    if p.reason == "tls-untrusted":
        return (f"{p.detail}: give the CA that signed it with --ca FILE (or, knowing what it means, "
                "--insecure)")
    if p.status in (401, 403):
        return (f"the Thing refused the credentials (HTTP {p.status}): give them with --auth "
                "basic:USER:PASS or bearer:TOKEN")
    return str(p)


def is_thing_model(doc: dict[str, Any]) -> bool:
    kinds = doc.get("@type", [])
    return "tm:ThingModel" in ([kinds] if isinstance(kinds, str) else kinds if isinstance(kinds, list) else [])


def check_td(doc: dict[str, Any], source: str) -> dict[str, Any]:
    """`doc` if it is a TD this mesh can serve (IntakeError naming the first problem otherwise)."""
    if is_thing_model(doc):
        raise IntakeError(f"{source}: this is a Thing Model (@type tm:ThingModel), not a Thing Description: "
                          "make a TD of it first (fill in its placeholders and give it forms)")
    problem = first_problem(doc)
    if problem is not None:
        raise IntakeError(f"{source}: not a valid Thing Description: {problem}")
    try:
        decode_td(doc)
    except msgspec.ValidationError as e:
        raise IntakeError(f"{source}: not a Thing Description twinmesh can serve: {e}") from None
    return doc


@lru_cache(maxsize=1)
def _td_schema() -> Any:
    import jsonschema

    schema = json.loads((Path(__file__).parent.parent / "wot" / "schemas" / TD_SCHEMA).read_text())
    return jsonschema.Draft7Validator(schema)


def first_problem(doc: dict[str, Any]) -> str | None:
    """The first way `doc` breaks the W3C TD 1.1 JSON Schema, as `at <JSON pointer>: <what> (rule <keyword>)`."""
    from jsonschema.exceptions import best_match

    error = best_match(_td_schema().iter_errors(doc))
    if error is None:
        return None
    pointer = "".join(f"/{str(p).replace('~', '~0').replace('/', '~1')}" for p in error.absolute_path) or "/"
    message = error.message if len(error.message) <= 200 else error.message[:200] + "..."
    return f"at {pointer}: {message} (rule {error.validator})"


def absolute_hrefs(doc: dict[str, Any], url: str | None) -> dict[str, Any]:
    """A copy of `doc` whose forms' hrefs are absolute: resolved against the TD's `base`, else the URL it
    came from (WoT TD 1.1 §6.3.1)."""
    base = doc.get("base") or url
    if not base:
        return doc

    def fix(forms: Any) -> Any:
        if not isinstance(forms, list):
            return forms
        return [{**f, "href": urljoin(base, f["href"])} if isinstance(f, dict) and isinstance(f.get("href"), str)
                else f for f in forms]

    out = dict(doc)
    out["forms"] = fix(doc.get("forms"))
    if out["forms"] is None:
        del out["forms"]
    for kind in ("properties", "actions", "events"):
        if isinstance(doc.get(kind), dict):
            out[kind] = {name: {**a, "forms": fix(a.get("forms"))} if isinstance(a, dict) else a
                         for name, a in doc[kind].items()}
    return out


def take_in(source: str, client: Any | None = None) -> dict[str, Any]:
    """The TD at `source` (file or URL), checked, with absolute hrefs."""
    doc = check_td(fetch_document(source, client), source)
    return absolute_hrefs(doc, source if is_url(source) else None)
