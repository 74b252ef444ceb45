"""A mesh TD rewritten for HTTP: forms for this adapter, the SPEC §5 invariants, the directory's TD.

The mesh TD (Zenoh-neutral forms) is the single source of truth; this module only derives the
HTTP view of it, so it never drifts from what the device serves. Form layout, per affordance:

- property: `[read/write]` on `/{thing}/properties/{p}`, then (observable) long-poll on
  `.../{p}/observable` and SSE on `.../{p}/sse`, long-poll first because node-wot takes the first
  form whose `op` matches and its SSE client cannot send credentials (see `auth.py`);
- action: `invokeaction` POST on `/{thing}/actions/{a}` (synchronous), then POST on `...?async=true`
  (201 + `Location` of `/{thing}/actions/{a}/{id}`), `queryaction` GET and `cancelaction` DELETE there;
- event: long-poll on `/{thing}/events/{e}`, then SSE on `.../{e}/sse`;
- Thing level: `readallproperties`/`readmultipleproperties` (`?names=a,b`) GET and, with a writable
  property, `writeallproperties`/`writemultipleproperties` PUT on `/{thing}/properties`; the W3C-profile style
  `observeallproperties` / `subscribeallevents` SSE streams (named events) on `/{thing}/properties`
  and `/{thing}/events` (asked for with `Accept: text/event-stream`); `queryallactions` GET on `/{thing}/actions`.
"""
from __future__ import annotations

import re
from typing import Any
from urllib.parse import urljoin

import msgspec

from mesh.wot import units
from mesh.wot.names import escaped
from mesh.wot.thing_description import (
    INVOCATION_ID,
    JSON,
    NOSEC,
    TD_CONTEXT,
    ActionAffordance,
    DataSchema,
    EventAffordance,
    Form,
    Link,
    PropertyAffordance,
    Security,
    ThingDescription,
    keep_terms,
    property_ops,
    thing_id,
)

TD_JSON = "application/td+json"
LD_JSON = "application/ld+json"
DISCOVERY_CONTEXT = "https://www.w3.org/2022/wot/discovery"
_ABSOLUTE = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")



def http_td(td: ThingDescription, thing: str, base: str, security: Security = NOSEC,
            source: dict[str, Any] | None = None) -> dict[str, Any]:
    """The TD of `thing` as this adapter serves it at `{base}/{thing}` (a JSON-ready dict); the terms
    of `source` (the TD as the Thing serves it) that the model does not hold are kept."""
    td = with_types(td)
    url = f"{base}/{thing}"
    props = {n: _property(p, f"{url}/properties/{escaped(n)}") for n, p in td.properties.items()}
    actions = {n: _action(a, f"{url}/actions/{escaped(n)}") for n, a in td.actions.items()}
    events = {n: _event(e, f"{url}/events/{escaped(n)}") for n, e in td.events.items()}
    forms = [Form(href=f"{url}/properties", op=["readallproperties", "readmultipleproperties"], contentType=JSON)
             ] if props else []
    if any(not p.readOnly for p in td.properties.values()):
        forms.append(Form(href=f"{url}/properties", op=["writeallproperties", "writemultipleproperties"],
                          contentType=JSON))
    if any(p.observable for p in td.properties.values()):
        forms.append(Form(href=f"{url}/properties", op=["observeallproperties", "unobserveallproperties"],
                          subprotocol="sse", contentType=JSON))
    if actions:
        forms.append(Form(href=f"{url}/actions", op="queryallactions", method="GET", contentType=JSON))
    if events:
        forms.append(Form(href=f"{url}/events", op=["subscribeallevents", "unsubscribeallevents"],
                          subprotocol="sse", contentType=JSON))
    links = [_link(link, url, thing) for link in td.links if link.rel != "self"]
    links.insert(0, Link(href=url, rel="self", type=TD_JSON))
    out = msgspec.structs.replace(
        td, title=td.title or thing, id=served_id(td, thing),
        context=_context(td.context), base=None, properties=props, actions=actions, events=events,
        forms=forms, links=links, securityDefinitions=dict(security[0]), security=list(security[1]))
    return keep_terms(source, msgspec.to_builtins(out)) if source else msgspec.to_builtins(out)


def served_id(td: ThingDescription, thing: str) -> str:
    """The Thing's own id when it is an absolute URI (node-wot checks), else a stable URN."""
    return td.id if td.id and _ABSOLUTE.match(td.id) else thing_id(thing)


def _property(p: PropertyAffordance, href: str) -> PropertyAffordance:
    forms = [Form(href=href, op=property_ops(p), contentType=JSON)]
    if p.observable:
        observe = ["observeproperty", "unobserveproperty"]
        forms += [Form(href=f"{href}/observable", op=observe, subprotocol="longpoll", contentType=JSON),
                  Form(href=f"{href}/sse", op=observe, subprotocol="sse", contentType=JSON)]
    return msgspec.structs.replace(p, forms=forms)


def _action(a: ActionAffordance, href: str) -> ActionAffordance:
    """Synchronous first (node-wot takes the first `invokeaction` form: the POST answers when the action
    is over, hence `synchronous: true` as SPEC §5 says), then the opt-in asynchronous one (201 +
    Location of a status resource) and that resource's query and cancel."""
    status = f"{href}/{{id}}"
    synchronous = True if a.synchronous is None else a.synchronous  # a Thing that says otherwise is kept
    return msgspec.structs.replace(
        a, synchronous=synchronous, uriVariables={**(a.uriVariables or {}), "id": INVOCATION_ID},
        forms=[Form(href=href, op="invokeaction", contentType=JSON),
               Form(href=f"{href}?async=true", op="invokeaction", contentType=JSON,
                    response={"contentType": JSON, "htv:statusCodeValue": 201,
                              "description": "The invocation's status (WoT Profile ActionStatus); Location names it"}),
               Form(href=status, op="queryaction", method="GET", contentType=JSON),
               Form(href=status, op="cancelaction", method="DELETE")])


def _event(e: EventAffordance, href: str) -> EventAffordance:
    sub = ["subscribeevent", "unsubscribeevent"]
    return msgspec.structs.replace(
        e, forms=[Form(href=href, op=sub, subprotocol="longpoll", contentType=JSON),
               Form(href=f"{href}/sse", op=sub, subprotocol="sse", contentType=JSON)])


def with_types(td: ThingDescription) -> ThingDescription:
    """The TD with `type` on every data schema: what the adapter both validates inputs against and
    advertises, so a device's untyped schema cannot let through what the served TD forbids."""
    return msgspec.structs.replace(
        td, properties={n: typed(p) for n, p in td.properties.items()},
        actions={n: msgspec.structs.replace(a, input=typed(a.input) if a.input else None,
                                            output=typed(a.output) if a.output else None)
                 for n, a in td.actions.items()},
        events={n: msgspec.structs.replace(e, data=typed(e.data) if e.data else None) for n, e in td.events.items()})


def typed(schema: DataSchema) -> Any:
    """`type` on every data schema (SPEC §5): inferred where the schema makes it unambiguous."""
    t = schema.type
    branches = [typed(b) for b in schema.oneOf] if schema.oneOf else schema.oneOf
    if t is None:
        if branches and len({b.type for b in branches if isinstance(b.type, str)} | {None}) == 2 \
                and all(b.type for b in branches):
            t = branches[0].type  # every branch of the oneOf has the same type
        elif schema.properties is not None or schema.required:
            t = "object"
        elif schema.items is not None or schema.minItems is not None or schema.maxItems is not None:
            t = "array"
        else:
            t = _type_of_values([*([schema.const] if schema.const is not msgspec.UNSET else []),
                                 *(schema.enum or [])])
    items = ([typed(i) for i in schema.items] if isinstance(schema.items, list)
             else typed(schema.items) if schema.items is not None else None)
    properties = {k: typed(v) for k, v in schema.properties.items()} if schema.properties else schema.properties
    return msgspec.structs.replace(schema, type=t, items=items, properties=properties, oneOf=branches)


def _type_of_values(values: list[Any]) -> str | None:
    kinds = {"boolean" if isinstance(v, bool) else "integer" if isinstance(v, int) else
             "number" if isinstance(v, float) else "string" if isinstance(v, str) else
             "null" if v is None else "array" if isinstance(v, list) else "object" for v in values}
    if kinds == {"integer", "number"}:
        return "number"
    return kinds.pop() if len(kinds) == 1 else None


def _context(context: str | list[Any]) -> list[Any]:
    """The two TD context URIs first (node-wot's stale schema needs 1.0 before 1.1), then the rest."""
    extra = [c for c in ([context] if isinstance(context, str) else context) if c not in TD_CONTEXT[:2]]
    return [*TD_CONTEXT[:2], *(extra or TD_CONTEXT[2:])]


def _link(link: Link, url: str, thing: str) -> Link:
    """Relative hrefs (e.g. `files/workspace.stl`) and `zenoh:` ones become adapter URLs."""
    href = link.href
    if href.startswith("zenoh:"):
        _, sep, name = href.partition(f"/{thing}/files/")
        href = f"{url}/files/{name}" if sep else href
    elif not _ABSOLUTE.match(href):
        href = urljoin(f"{url}/", href)
    return msgspec.structs.replace(link, href=href)


def directory_td(base: str, prefix: str) -> dict[str, Any]:
    """The adapter's own TD at `/.well-known/wot`: a Thing Description Directory (WoT Discovery TM).

    Read-only subset of the TDD Thing Model: the `things` listing, `retrieveThing` and the
    notifications (`thing_created`, `thing_updated`, `thing_deleted`, SSE). Discovery is public, so
    it is `nosec` even when the Things' affordances need credentials.
    """
    no_query = {"description": "Invalid query arguments", "contentType": "application/problem+json",
                "htv:statusCodeValue": 400}
    not_found = {"description": "TD with the given id not found", "contentType": "application/problem+json",
                 "htv:statusCodeValue": 404}
    return {
        "@context": [*TD_CONTEXT[:2], DISCOVERY_CONTEXT, *TD_CONTEXT[2:]],
        "@type": "ThingDirectory",
        "id": f"urn:twinmesh:directory:{prefix}",
        "title": "twinmesh Thing Description Directory",
        "description": "The Things alive on the twinmesh mesh, as WoT HTTP Things (read-only directory).",
        "version": {"instance": "1.0.0", "model": "1.0.0"},
        "securityDefinitions": NOSEC[0], "security": NOSEC[1],
        "links": [{"rel": "self", "href": f"{base}/.well-known/wot", "type": TD_JSON}],
        "properties": {
            "things": {
                "description": "Retrieve all Thing Descriptions",
                "type": "array", "items": {"type": "object"}, "readOnly": True, "observable": False,
                "uriVariables": {
                    "offset": {"title": "Number of TDs to skip before the page", "type": "integer", "unit": units.NUMBER,
                               "minimum": 0, "default": 0},
                    "limit": {"title": "Number of TDs in a page", "type": "integer", "minimum": 1,
                              "unit": units.NUMBER},
                    "format": {"title": "Payload format", "type": "string", "enum": ["array"], "default": "array"},
                },
                "forms": [{"href": f"{base}/things{{?offset,limit,format}}", "op": "readproperty",
                           "htv:methodName": "GET", "contentType": LD_JSON,
                           "response": {"description": "Success response", "contentType": LD_JSON,
                                        "htv:statusCodeValue": 200},
                           "additionalResponses": [no_query]}],
            },
        },
        "forms": [{"href": f"{base}/events", "op": ["subscribeallevents", "unsubscribeallevents"],
                   "subprotocol": "sse", "contentType": JSON}],
        "events": {name: {
            "description": what, "data": {"type": "object", "required": ["id", "title"], "properties": {
                "id": {"type": "string", "format": "iri-reference", "description": "The Thing's TD id"},
                "title": {"type": "string", "description": "The Thing's name on the adapter"}}},
            "forms": [{"href": f"{base}/events/{name}", "op": ["subscribeevent", "unsubscribeevent"],
                       "subprotocol": "sse", "contentType": JSON}]}
            for name, what in (("thing_created", "A Thing joined the mesh and its TD is served"),
                               ("thing_updated", "A Thing's TD changed (a robot's regenerated workspace)"),
                               ("thing_deleted", "A Thing left the mesh"))},
        "actions": {
            "retrieveThing": {
                "description": "Retrieve a Thing Description",
                "uriVariables": {"id": {"@type": "ThingID", "title": "Thing Description ID", "type": "string",
                                        "format": "iri-reference"}},
                "output": {"description": "The schema is implied by the content type", "type": "object"},
                "safe": True, "idempotent": True, "synchronous": True,
                "forms": [{"href": f"{base}/things/{{id}}", "op": "invokeaction", "htv:methodName": "GET",
                           "response": {"description": "Success response", "contentType": TD_JSON,
                                        "htv:statusCodeValue": 200},
                           "additionalResponses": [not_found]}],
            },
        },
    }
