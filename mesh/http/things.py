"""Discovery and files: each Thing's TD, the TDD-style directory, `/.well-known/wot`, linked files.

| route | what |
|---|---|
| `GET /` | URLs of the Things' TDs (as node-wot's servient answers); for a browser (`Accept: text/html`) the control page |
| `GET /_ui/{file}` | the control page's script, style and `config.json` (`mesh/http/ui/`) |
| `GET /_lab/stream` | every change and event of the lab as one SSE stream, `event: <thing>/<kind>/<name>` (the page's) |
| `GET /.well-known/wot` | the directory's own TD (a WoT Discovery Thing Description Directory) |
| `GET /things?offset=&limit=` | all TDs, a TDD listing (`application/ld+json` array; `Link: rel=next` when paged) |
| `GET /things/{id}` | one TD by its (URL-encoded) `id` |
| `GET /events`, `/events/{type}` | directory notifications (SSE): `thing_created`, `_updated`, `_deleted`, `{id, title}` |
| `GET /{thing}` | the Thing's TD |
| `GET /{thing}/files/{name}` | a linked file, with the content type the device gave it |

TDs are `application/td+json` whatever the Accept header says (node-wot asks with `*/*`). TDs and
listings carry an `ETag` (a hash of the body); `If-None-Match` with it answers 304 without a body.
"""
from __future__ import annotations

import functools
import hashlib
import re
from importlib import resources

import msgspec
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from mesh.http.context import base_url, registry, security, thing_name
from mesh.http.gateway import DIRECTORY
from mesh.http.streams import EventStream
from mesh.http.tdrewrite import LD_JSON, TD_JSON, directory_td, http_td, served_id
from mesh.wot.names import NAME
from mesh.wot.problem import BadInput, NotFound, Problem
from mesh.wot.thing_description import JSON


async def _td_bytes(request: Request, thing: str) -> bytes:
    reg = registry(request)
    await reg.td(thing)
    base, sec = base_url(request), security(request)
    return reg.render(thing, base, lambda td, source: msgspec.json.encode(http_td(td, thing, base, sec, source)))


def _etagged(request: Request, body: bytes, media_type: str, headers: dict[str, str] | None = None) -> Response:
    """`body` with its ETag, or 304 when the client already has it (If-None-Match)."""
    tag = f'"{hashlib.sha256(body).hexdigest()[:32]}"'
    headers = {**(headers or {}), "ETag": tag}
    wanted = {t.strip().removeprefix("W/") for t in request.headers.get("if-none-match", "").split(",")}
    if tag in wanted or "*" in wanted:
        return Response(status_code=304, headers=headers)
    return Response(body, media_type=media_type, headers=headers)


async def thing_description(request: Request) -> Response:
    return _etagged(request, await _td_bytes(request, thing_name(request)), TD_JSON)


async def index(request: Request) -> Response:
    """A browser (asking for HTML) gets the control page; WoT clients the list of TD URLs."""
    if "text/html" in request.headers.get("accept", ""):
        return Response(_ui_file("index.html"), media_type="text/html; charset=utf-8",
                        headers={"Cache-Control": "no-cache"})
    base = base_url(request)
    return Response(msgspec.json.encode([f"{base}/{n}" for n in registry(request).names()]), media_type=JSON)


UI_FILES = {"index.html": "text/html; charset=utf-8", "app.js": "text/javascript; charset=utf-8",
            "forms.js": "text/javascript; charset=utf-8", "style.css": "text/css; charset=utf-8"}


@functools.cache
def _ui_file(name: str) -> bytes:
    return (resources.files(__package__) / "ui" / name).read_bytes()


async def ui_file(request: Request) -> Response:
    """The control page's script and style (`mesh/http/ui/`), and its settings (`config.json`:
    where the 3D view is, if one is served)."""
    name = request.path_params["name"]
    if name == "config.json":
        return Response(msgspec.json.encode({"view": request.app.state.view}), media_type=JSON)
    if name not in UI_FILES:
        raise NotFound(f"the control page has no file {name!r}")
    return Response(_ui_file(name), media_type=UI_FILES[name], headers={"Cache-Control": "no-cache"})


async def well_known(request: Request) -> Response:
    body = directory_td(base_url(request), registry(request).keys.prefix)
    return _etagged(request, msgspec.json.encode(body), TD_JSON)


def _page_arg(request: Request, name: str, minimum: int) -> int | None:
    raw = request.query_params.get(name)
    if raw is None:
        return None
    if not re.fullmatch(r"[0-9]{1,9}", raw) or int(raw) < minimum:  # str.isdigit() takes '²', int() does not
        raise BadInput(f"{name} must be an integer >= {minimum}, not {raw!r}")
    return int(raw)


async def listing(request: Request) -> Response:
    """All TDs, in name order; `offset`/`limit` page it (the TDD API's uriVariables)."""
    if request.query_params.get("format", "array") != "array":
        raise BadInput("format: only 'array' is supported")
    offset = _page_arg(request, "offset", 0) or 0
    limit = _page_arg(request, "limit", 1)
    names = registry(request).names()
    page = names[offset:] if limit is None else names[offset:offset + limit]
    tds = []
    for name in page:
        try:
            tds.append(await _td_bytes(request, name))
        except Problem:  # it left while we listed: leave it out
            continue
    headers = {}
    if limit is not None and offset + limit < len(names):
        headers["Link"] = f'</things?offset={offset + limit}&limit={limit}>; rel="next"'
    return _etagged(request, b"[" + b",".join(tds) + b"]", LD_JSON, headers)


async def by_id(request: Request) -> Response:
    """The TDD's retrieveThing; a Thing that was listed and left answers 503, like its own URL."""
    wanted = request.path_params["id"]
    for name, td in registry(request).known_tds().items():
        if served_id(td, name) == wanted:
            return _etagged(request, await _td_bytes(request, name), TD_JSON)
    raise NotFound(f"no TD with id {wanted!r}")


DIRECTORY_EVENTS = ("thing_created", "thing_updated", "thing_deleted")


async def directory_events(request: Request) -> Response:
    """The TDD notifications (WoT Discovery): a Thing joined, its TD changed (a robot's regenerated
    workspace), or it left; one named SSE event each, `{id, title}` as data."""
    kind = request.path_params.get("type")
    if kind is not None and kind not in DIRECTORY_EVENTS:
        raise NotFound(f"no directory event {kind!r} (there are {', '.join(DIRECTORY_EVENTS)})")
    names = [kind] if kind else list(DIRECTORY_EVENTS)
    return EventStream(registry(request).observers.watch(DIRECTORY, "events", names), named=True)


async def lab_stream(request: Request) -> Response:
    """Every property change and event of every Thing, and the directory's notifications, as one SSE
    stream (`event: <thing>/<kind>/<name>`): the control page's live updates. Needs the credentials."""
    return EventStream(registry(request).observers.watch_everything(), named=True)


async def linked_file(request: Request) -> Response:
    thing = thing_name(request)
    name = request.path_params["name"]
    if not NAME.match(name):  # never a wildcard or reserved character into a key expression
        raise NotFound(f"{thing} has no file {name!r} (file names are letters, digits, '_', '.', '-')")
    reply = await registry(request).file(thing, name)
    return Response(reply.payload, media_type=reply.encoding or "application/octet-stream")


routes_top = [
    Route("/", index, methods=["GET"]),
    Route("/.well-known/wot", well_known, methods=["GET"]),
    Route("/_ui/{name}", ui_file, methods=["GET"]),
    Route("/_lab/stream", lab_stream, methods=["GET"]),
    Route("/things", listing, methods=["GET"]),
    Route("/things/{id:path}", by_id, methods=["GET"]),
    Route("/events", directory_events, methods=["GET"]),
    Route("/events/{type}", directory_events, methods=["GET"]),
]
routes_thing = [
    Route("/{thing}", thing_description, methods=["GET"]),
    Route("/{thing}/files/{name}", linked_file, methods=["GET"]),
]
