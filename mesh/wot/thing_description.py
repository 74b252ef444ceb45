"""The Thing Description model: TD 1.1 as msgspec Structs.

TDs travel as JSON; decoding into these Structs is what checks their shape, and the same model
feeds input validation (`mesh.wot.validate`) and the HTTP adapter's form rewriting. Every term
of the TD 1.1 information model is a field, with the JSON Schema keywords a data schema may carry;
terms beyond it (extension vocabularies, other JSON Schema keywords) are carried by `keep_terms`
from the document a Thing serves into what the adapter serves.
"""
from __future__ import annotations

from typing import Any, Literal

import msgspec

from mesh.wot.names import escaped
from mesh.wot.units import PREFIX, QUDT_UNITS

TD_CONTEXT: list[Any] = [
    "https://www.w3.org/2019/wot/td/v1",
    "https://www.w3.org/2022/wot/td/v1.1",
    {"@language": "en", PREFIX: QUDT_UNITS},  # units: mesh.wot.units
]
Security = tuple[dict[str, dict[str, Any]], list[str]]  # (securityDefinitions, security) of a TD
NOSEC: Security = ({"nosec_sc": {"scheme": "nosec"}}, ["nosec_sc"])
JSON = "application/json"

AffordanceKind = Literal["properties", "actions", "events"]


class DataSchema(msgspec.Struct, omit_defaults=True, rename={"at_type": "@type", "schema_ref": "$ref"}):
    type: str | list[str] | None = None
    title: str | None = None
    titles: dict[str, str] | None = None
    description: str | None = None
    descriptions: dict[str, str] | None = None
    at_type: str | list[str] | None = None
    unit: str | None = None
    const: Any = msgspec.UNSET
    default: Any = msgspec.UNSET
    enum: list[Any] | None = None
    oneOf: "list[DataSchema] | None" = None
    anyOf: "list[DataSchema] | None" = None
    allOf: "list[DataSchema] | None" = None
    format: str | None = None
    minimum: float | None = None
    maximum: float | None = None
    exclusiveMinimum: float | None = None
    exclusiveMaximum: float | None = None
    multipleOf: float | None = None
    minLength: int | None = None
    maxLength: int | None = None
    pattern: str | None = None
    contentEncoding: str | None = None
    contentMediaType: str | None = None
    minItems: int | None = None
    maxItems: int | None = None
    uniqueItems: bool | None = None
    items: "DataSchema | list[DataSchema] | None" = None
    properties: "dict[str, DataSchema] | None" = None
    required: list[str] | None = None
    additionalProperties: "bool | DataSchema | None" = None
    minProperties: int | None = None
    maxProperties: int | None = None
    readOnly: bool | None = None
    writeOnly: bool | None = None
    schema_ref: str | None = None


class Form(msgspec.Struct, omit_defaults=True, rename={"method": "htv:methodName"}):
    href: str
    op: str | list[str] | None = None
    contentType: str | None = None
    contentCoding: str | None = None
    subprotocol: str | None = None
    method: str | None = None
    response: dict[str, Any] | None = None
    additionalResponses: list[dict[str, Any]] | None = None
    security: str | list[str] | None = None
    scopes: str | list[str] | None = None

    def ops(self) -> list[str]:
        return [self.op] if isinstance(self.op, str) else list(self.op or [])


class PropertyAffordance(DataSchema, omit_defaults=True):
    observable: bool | None = None
    uriVariables: dict[str, DataSchema] | None = None
    forms: list[Form] = []


class InteractionAffordance(msgspec.Struct, omit_defaults=True, rename={"at_type": "@type"}):
    """What actions and events share (TD 1.1 §5.3.1.4; a property has the same through DataSchema)."""

    title: str | None = None
    titles: dict[str, str] | None = None
    description: str | None = None
    descriptions: dict[str, str] | None = None
    at_type: str | list[str] | None = None
    uriVariables: dict[str, DataSchema] | None = None


class ActionAffordance(InteractionAffordance):
    input: DataSchema | None = None
    output: DataSchema | None = None
    safe: bool | None = None
    idempotent: bool | None = None
    synchronous: bool | None = None
    forms: list[Form] = []


class EventAffordance(InteractionAffordance):
    subscription: DataSchema | None = None
    data: DataSchema | None = None
    dataResponse: DataSchema | None = None
    cancellation: DataSchema | None = None
    forms: list[Form] = []


class Link(msgspec.Struct, omit_defaults=True):
    href: str
    rel: str | None = None
    type: str | None = None
    anchor: str | None = None
    sizes: str | None = None
    hreflang: str | list[str] | None = None


class ThingDescription(msgspec.Struct, omit_defaults=True,
                       rename={"context": "@context", "at_type": "@type"}):
    title: str
    context: str | list[Any] = msgspec.field(default_factory=lambda: list(TD_CONTEXT))
    at_type: str | list[str] | None = None
    id: str | None = None
    titles: dict[str, str] | None = None
    description: str | None = None
    descriptions: dict[str, str] | None = None
    version: dict[str, Any] | None = None
    created: str | None = None
    modified: str | None = None
    support: str | None = None
    base: str | None = None
    profile: str | list[str] | None = None
    schemaDefinitions: dict[str, DataSchema] | None = None
    uriVariables: dict[str, DataSchema] | None = None
    security: str | list[str] = msgspec.field(default_factory=lambda: list(NOSEC[1]))
    securityDefinitions: dict[str, dict[str, Any]] = msgspec.field(default_factory=lambda: dict(NOSEC[0]))
    properties: dict[str, PropertyAffordance] = {}
    actions: dict[str, ActionAffordance] = {}
    events: dict[str, EventAffordance] = {}
    links: list[Link] = []
    forms: list[Form] = []

    def affordance(self, kind: AffordanceKind, name: str):
        """The named affordance of a kind, or None."""
        return getattr(self, kind).get(name)

    def no_such(self, thing: str, kind: AffordanceKind, name: str) -> str:
        """The sentence for a missing affordance: what was asked, and what the Thing has instead."""
        singular = {"properties": "property", "actions": "action", "events": "event"}[kind]
        have = sorted(getattr(self, kind))
        return (f"{thing} has no {singular} {name!r}; its {kind}: {', '.join(have)}" if have
                else f"{thing} has no {singular} {name!r}; it has no {kind}")

    def to_json(self) -> bytes:
        return msgspec.json.encode(self)

    def to_dict(self) -> dict[str, Any]:
        return msgspec.to_builtins(self)


def decode_td(data: bytes | str | dict) -> ThingDescription:
    """Parse a TD from JSON text or a dict; raises msgspec.ValidationError on a bad shape."""
    if isinstance(data, dict):
        return msgspec.convert(data, ThingDescription)
    return msgspec.json.decode(data, type=ThingDescription)


def thing_id(thing: str) -> str:
    """A stable absolute URI for a Thing of the mesh (node-wot checks `id` is a URI)."""
    return f"urn:twinmesh:thing:{thing}"


PROPERTY_OPS = {"read": "readproperty", "write": "writeproperty", "observe": "observeproperty"}


def property_ops(p: PropertyAffordance) -> list[str]:
    """The operations a property allows, from readOnly/writeOnly/observable."""
    ops = []
    if not p.writeOnly:
        ops.append("readproperty")
    if not p.readOnly:
        ops.append("writeproperty")
    return ops


INVOCATION_ID = DataSchema(
    type="string", pattern="^[0-9a-f]{32}$",
    description="An asynchronous invocation's id, from its status (the second invokeaction form answers with it)")


def zenoh_forms(td: ThingDescription, prefix: str, thing: str) -> ThingDescription:
    """The TD as served on Zenoh: every form's href is the affordance's key expression."""
    def href(kind: str, name: str) -> str:
        return f"zenoh:{prefix}/{thing}/{kind}/{escaped(name)}"

    props = {
        n: msgspec.structs.replace(p, forms=[Form(href=href("properties", n), op=property_ops(p), contentType=JSON)]
                                   + ([Form(href=href("properties", n), op=["observeproperty", "unobserveproperty"],
                                            contentType=JSON)] if p.observable else []))
        for n, p in td.properties.items()
    }
    actions = {n: msgspec.structs.replace(a, uriVariables={**(a.uriVariables or {}), "id": INVOCATION_ID}, forms=[
        Form(href=href("actions", n), op="invokeaction", contentType=JSON),
        Form(href=href("actions", n) + "?async", op="invokeaction", contentType=JSON),
        Form(href=href("actions", n) + "?id={id}", op="queryaction", contentType=JSON),
        Form(href=href("actions", n) + "?id={id};cancel", op="cancelaction", contentType=JSON)])
               for n, a in td.actions.items()}
    events = {n: msgspec.structs.replace(e, forms=[Form(href=href("events", n),
                                                         op=["subscribeevent", "unsubscribeevent"], contentType=JSON)])
              for n, e in td.events.items()}
    forms = [Form(href=href("actions", "*") + "?calls", op="queryallactions", contentType=JSON)] if actions else []
    return msgspec.structs.replace(td, title=td.title or thing, id=td.id or thing_id(thing),
                                   properties=props, actions=actions, events=events, forms=forms)


REWRITTEN_TERMS = frozenset({"forms", "links", "base", "security", "securityDefinitions", "@context", "id", "title"})
AFFORDANCE_KINDS = ("properties", "actions", "events")


def keep_terms(source: Any, served: Any) -> Any:
    """`served` with every term of `source` that it lacks put back, at every depth: what a Thing
    said beyond this model (an extension vocabulary's terms, JSON Schema keywords TD 1.1 does not
    name) reaches its readers unchanged. Only where the server writes them are terms left as served:
    the Thing's own `REWRITTEN_TERMS` and each affordance's `forms`. Everywhere else, a term named
    `id`, `title` or `links` (a property called `id`, links inside an affordance) is the Thing's and
    kept; lists (`oneOf`, tuple `items`, `enum`) are kept element by element."""
    if not (isinstance(source, dict) and isinstance(served, dict)):
        return served
    out = dict(served)
    for key, value in source.items():
        if key in REWRITTEN_TERMS:
            continue
        if key in AFFORDANCE_KINDS and isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = {name: _keep_affordance(a, out[key][name]) if name in out[key] else a
                        for name, a in value.items()} | {n: a for n, a in out[key].items() if n not in value}
        else:
            out[key] = keep_source_terms(value, out[key]) if key in out else value
    return out


def _keep_affordance(source: Any, served: Any) -> Any:
    if not (isinstance(source, dict) and isinstance(served, dict)):
        return served
    out = dict(served)
    for key, value in source.items():
        if key != "forms":
            out[key] = keep_source_terms(value, out[key]) if key in out else value
    return out


def keep_source_terms(source: Any, served: Any) -> Any:
    """Every term of `source` at every depth, with what `served` says where both have a term."""
    if isinstance(source, dict) and isinstance(served, dict):
        return {**served, **{k: keep_source_terms(v, served[k]) if k in served else v for k, v in source.items()}}
    if isinstance(source, list) and isinstance(served, list) and len(source) == len(served):
        return [keep_source_terms(a, b) for a, b in zip(source, served)]
    if type(source) is not type(served) and isinstance(source, (int, float)) and not isinstance(source, bool) \
            and source == served:
        return source  # the Thing's 120, not the model's 120.0
    return served
