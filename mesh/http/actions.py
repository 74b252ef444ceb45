"""Action routes: invoke (synchronous or asynchronous), query, cancel, query all.

| route | op | answer |
|---|---|---|
| `POST /{thing}/actions/{a}` | invokeaction | when the action is over: 200 with the output, 204 without |
| `POST /{thing}/actions/{a}?async=true` (or `Prefer: respond-async`) | invokeaction | at once: 201 + `Location` |
| `GET /{thing}/actions/{a}/{id}` | queryaction | 200, the status (WoT Profile ActionStatus) |
| `DELETE /{thing}/actions/{a}/{id}` | cancelaction | 204 once it stopped; 202 if still stopping; 409 if it had ended |
| `GET /{thing}/actions` | queryallactions | 200, `{action: [status, ...]}` |

Synchronous invocation is the first form (node-wot's); a robot motion may take minutes and waits
in a worker thread, not on the event loop. Either way the input is validated against the TD before
the mesh sees it (400 up front, nothing starts); an action without input takes an empty body
(node-wot: `Content-Length: 0`, no content type) or `null`.
"""
from __future__ import annotations

import re

import msgspec
from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from mesh.http.context import affordance, base_url, registry, thing_td
from mesh.http.inputs import ABSENT, encode, read_input
from mesh.wot.invocation import ID, ActionStatus
from mesh.wot.problem import BadInput, NotFound
from mesh.wot.thing_description import JSON

_TRUE = ("", "true", "1", "yes")


def _wants_async(request: Request) -> bool:
    flag = request.query_params.get("async")
    if flag is not None and flag.lower() not in (*_TRUE, "false", "0", "no"):
        raise BadInput(f"async must be true or false, not {flag!r}")
    prefer = {p.strip().lower() for p in request.headers.get("prefer", "").split(",")}
    return (flag is not None and flag.lower() in _TRUE) or "respond-async" in prefer


def _located(request: Request, thing: str, status: ActionStatus) -> tuple[str, bytes]:
    href = f"{base_url(request)}/{thing}/actions/{status.action}/{status.id}"
    return href, msgspec.json.encode(msgspec.structs.replace(status, href=href))


async def invoke_action(request: Request) -> Response:
    thing, name, action = await affordance(request, "actions")
    asynchronous = _wants_async(request)
    value = await read_input(request, registry(request).schemas(thing).of(action.input, "actions", name, "input"),
                             "input")
    if action.input is None:
        if value is not ABSENT and value is not None:
            raise BadInput(f"action {name!r} takes no input")
        payload = None
    elif value is ABSENT:
        raise BadInput(f"action {name!r} needs an input")
    else:
        payload = encode(value)
    if asynchronous:
        status = await registry(request).invoke_async(thing, name, payload)
        href, body = _located(request, thing, status)
        return Response(body, status_code=201, media_type=JSON,
                        headers={"Location": href, "Preference-Applied": "respond-async"})
    out = await registry(request).invoke(thing, name, payload)
    return Response(out, media_type=JSON) if out else Response(status_code=204)


async def _invocation(request: Request) -> tuple[str, str, str]:
    thing, name, _ = await affordance(request, "actions")
    id = request.path_params["id"]
    if not re.fullmatch(ID, id):
        raise NotFound(f"{name!r} of {thing} has no invocation {id!r} (ids are 32 hex digits)")
    return thing, name, id


async def query_action(request: Request) -> Response:
    thing, name, id = await _invocation(request)
    _, body = _located(request, thing, await registry(request).query_action(thing, name, id))
    return Response(body, media_type=JSON)


async def cancel_action(request: Request) -> Response:
    thing, name, id = await _invocation(request)
    status = await registry(request).cancel_action(thing, name, id)
    if status.status == "cancelled":
        return Response(status_code=204)
    _, body = _located(request, thing, status)  # asked to stop, not stopped yet (or it finished meanwhile)
    return Response(body, status_code=202, media_type=JSON)


async def query_all_actions(request: Request) -> Response:
    thing, _ = await thing_td(request)
    found = await registry(request).query_all_actions(thing)
    body = {name: [msgspec.structs.replace(s, href=_located(request, thing, s)[0]) for s in statuses]
            for name, statuses in sorted(found.items())}
    return Response(msgspec.json.encode(body), media_type=JSON)


routes = [
    Route("/{thing}/actions", query_all_actions, methods=["GET"]),
    Route("/{thing}/actions/{name}", invoke_action, methods=["POST"]),
    Route("/{thing}/actions/{name}/{id}", query_action, methods=["GET"]),
    Route("/{thing}/actions/{name}/{id}", cancel_action, methods=["DELETE"]),
]
