"""Action routes: invokeaction POST on `/{thing}/actions/{name}`.

Synchronous, as every form says: the POST answers when the action is over (a robot motion may take
minutes; it waits in a worker thread, not on the event loop). 200 with the output as JSON, or 204
when the action has no output. The input is validated against the TD before the mesh sees it; an
action without input takes an empty body (node-wot: `Content-Length: 0`, no content type) or
`null`.
"""
from __future__ import annotations

from starlette.requests import Request
from starlette.responses import Response
from starlette.routing import Route

from twinmesh.http.context import affordance, registry
from twinmesh.http.inputs import ABSENT, encode, read_input
from twinmesh.wot.problem import BadInput
from twinmesh.wot.td import JSON


async def invoke_action(request: Request) -> Response:
    thing, name, action = await affordance(request, "actions")
    value = await read_input(request, action.input, "input")
    if action.input is None:
        if value is not ABSENT and value is not None:
            raise BadInput(f"action {name!r} takes no input")
        payload = None
    elif value is ABSENT:
        raise BadInput(f"action {name!r} needs an input")
    else:
        payload = encode(value)
    out = await registry(request).invoke(thing, name, payload)
    return Response(out, media_type=JSON) if out else Response(status_code=204)


routes = [Route("/{thing}/actions/{name}", invoke_action, methods=["POST"])]
