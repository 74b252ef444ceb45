"""How mesh messages look in a Rerun recording: (thing, affordance, JSON value) -> archetype logs.

Pure functions, no RecordingStream: the recorder (`mesh.recorder.logger`) sets the timelines and logs the
`Entry`s these return. The rules, per property value: the value's JSON type picks the archetype
(a value that does not fit its schema is still recorded as what it is); the TD's data schema,
where known, says what the type alone cannot: that an array or object is a colour and in which
scale (`maximum`), the schemas of an object's fields, the unit in a series' name.

- boolean -> `Scalars` 0/1; number, integer -> `Scalars`; all at `things/<thing>/properties/<p>`,
  drawn as steps (a property holds its value until the next change);
- a colour (an array of 3-4 numbers or an object with r, g, b, when the name or the schema's
  title/@type says colour) -> an `Image` swatch filled with that colour at the property's path, plus
  one `Scalars` per channel (`.../<p>/r`, `/g`, `/b`) in the Thing's own scale;
- an object of numbers and booleans only (a position, a location) -> one `Scalars` entity at the
  property's path with one series per field, named with its unit (one chunk per change, not one per
  field: the live view's browser takes in chunks, not rows, at a cost each);
- any other object -> the same rules per field, one entity per field (`.../<p>/<field>`);
- an array of numbers -> one `Scalars` entity with one series per element;
- a string -> a `TextLog` line at the property's path; anything else -> a `TextLog` line of JSON.

Events go to `things/<thing>/events` and joins/leaves to `mesh/log`, both as `TextLog`; a Thing's
TD is a markdown `TextDocument` at `things/<thing>/td`.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import msgspec
import rerun as rr

from mesh.wot import units
from mesh.wot.thing_description import DataSchema, ThingDescription

MESH_LOG = "mesh/log"
SWATCH_PIXELS = 8  # the swatch is a tiny image: the 2D view fills it with the colour
CHANNEL_COLORS = {"r": (230, 40, 40), "g": (40, 180, 40), "b": (40, 90, 230), "a": (128, 128, 128)}
_CHANNEL_ALIASES = {"r": "r", "red": "r", "g": "g", "green": "g", "b": "b", "blue": "b", "a": "a", "alpha": "a"}


@dataclass(frozen=True)
class Entry:
    """One `rec.log(path, archetype, static=static)` call."""

    path: str
    archetype: Any
    static: bool = False


# --- entity paths --------------------------------------------------------------------------------
def entity_path(*parts: str) -> str:
    """Join path parts, escaping what Rerun would read as separators or syntax."""
    return "/".join(rr.escape_entity_path_part(str(p)) for p in parts)


def property_path(thing: str, prop: str) -> str:
    return entity_path("things", thing, "properties", prop)


def events_path(thing: str) -> str:
    return entity_path("things", thing, "events")


def td_path(thing: str) -> str:
    return entity_path("things", thing, "td")


# --- mesh messages -------------------------------------------------------------------------------
def presence_entries(thing: str, joined: bool) -> list[Entry]:
    text = f"{thing} joined" if joined else f"{thing} left"
    return [Entry(MESH_LOG, rr.TextLog(text, level="INFO" if joined else "WARN"))]


def notice_entries(text: str, level: str = "WARN") -> list[Entry]:
    """A line about the recorder itself (a TD it could not fetch, messages it dropped)."""
    return [Entry(MESH_LOG, rr.TextLog(text, level=level))]


def event_entries(thing: str, event: str, data: Any) -> list[Entry]:
    text = event if data is None else f"{event}: {_json(data)}"
    return [Entry(events_path(thing), rr.TextLog(text, level="INFO"))]


def action_entries(thing: str, action: str, call: Any) -> list[Entry]:
    """One text-log line per finished action call (published by the Thing runtime)."""
    call = call if isinstance(call, dict) else {}
    args = "" if call.get("input") is None else _json(call["input"])
    if call.get("error"):
        text, level = f"{action}({args}) refused {call.get('status')}: {call['error']}", "WARN"
    else:
        result = "" if call.get("output") is None else f" -> {_json(call['output'])}"
        text, level = f"{action}({args}){result} in {call.get('seconds', 0):.2f} s", "INFO"
    return [Entry(entity_path("things", thing, "actions"), rr.TextLog(text, level=level))]


def td_entries(thing: str, td: ThingDescription) -> list[Entry]:
    return [Entry(td_path(thing), rr.TextDocument(td_markdown(thing, td), media_type=rr.MediaType.MARKDOWN))]


def td_markdown(thing: str, td: ThingDescription) -> str:
    """A readable TD: title, description, affordances with their types, then the full JSON."""
    lines = [f"# {td.title or thing}", ""]
    if td.description:
        lines += [td.description, ""]
    for kind, affordances in (("Properties", td.properties), ("Actions", td.actions), ("Events", td.events)):
        if affordances:
            lines.append(f"## {kind}")
            for name, a in affordances.items():
                lines.append(f"- `{name}`{_affordance_note(a)}")
            lines.append("")
    body = msgspec.json.format(td.to_json(), indent=2).decode()
    lines += ["## TD", "", "```json", body, "```"]
    return "\n".join(lines)


def _affordance_note(a: Any) -> str:
    schema = a if isinstance(a, DataSchema) else getattr(a, "data", None)
    kind = ""
    if schema is not None and schema.type:
        unit = units.symbol(schema.unit)
        kind = f" ({schema.type}{', ' + unit if unit else ''})"
    title = f" — {a.title}" if getattr(a, "title", None) else ""
    return kind + title


# --- property values -----------------------------------------------------------------------------
def property_entries(thing: str, prop: str, value: Any, schema: DataSchema | None = None) -> list[Entry]:
    """The logs for one value of a property (see the module docstring for the rules)."""
    return value_entries(property_path(thing, prop), prop, value, schema)


def value_entries(path: str, name: str, value: Any, schema: DataSchema | None) -> list[Entry]:
    kind = _json_type(value)
    if kind == "null":
        return []  # no value: nothing to draw
    if kind in ("array", "object") and _is_colour(name, schema):
        colour = _colour(value, schema)
        if colour is not None:
            return _colour_entries(path, colour)
    if kind == "boolean":
        return _scalar_entries(path, [1.0 if value else 0.0], [_series_name(name, schema)])
    if kind == "number":
        return _scalar_entries(path, [float(value)], [_series_name(name, schema)])
    if kind == "object":
        fields = (schema.properties or {}) if schema is not None else {}
        if value and all(_is_number(v) or isinstance(v, bool) for v in value.values()):
            return _scalar_entries(path, [float(v) for v in value.values()],
                                   [_series_name(str(f), fields.get(f)) for f in value])
        out: list[Entry] = []
        for field, v in value.items():
            out += value_entries(f"{path}/{rr.escape_entity_path_part(str(field))}", str(field), v, fields.get(field))
        return out
    if kind == "array" and value and all(_is_number(v) or isinstance(v, bool) for v in value):
        return _scalar_entries(path, [float(v) for v in value], [f"{name}[{i}]" for i in range(len(value))])
    if kind == "string":
        return [Entry(path, rr.TextLog(value, level="INFO"))]
    return [Entry(path, rr.TextLog(_json(value), level="INFO"))]


def _series_name(name: str, schema: DataSchema | None) -> str:
    unit = units.symbol(schema.unit) if schema is not None else ""
    return f"{name} ({unit})" if unit else name


def _scalar_entries(path: str, values: list[float], names: list[str], color: tuple[int, int, int] | None = None
                    ) -> list[Entry]:
    style = rr.SeriesLines(names=names, interpolation_mode="StepAfter",
                           colors=None if color is None else [color])
    return [Entry(path, style, static=True), Entry(path, rr.Scalars(values))]


def _colour_entries(path: str, colour: "Colour") -> list[Entry]:
    n = SWATCH_PIXELS
    pixels = bytes(colour.rgb8) * (n * n)
    out = [Entry(path, rr.Image(bytes=pixels, width=n, height=n, color_model="RGB", datatype="u8"))]
    for channel, v in colour.channels.items():
        out += _scalar_entries(f"{path}/{channel}", [v], [channel], CHANNEL_COLORS[channel])
    return out


@dataclass(frozen=True)
class Colour:
    channels: dict[str, float]  # r, g, b (and a) in the Thing's own scale
    scale: float  # the channels' full value: 1.0 or 255.0

    @property
    def rgb8(self) -> tuple[int, int, int]:
        r, g, b = (round(min(max(self.channels[c] / self.scale, 0.0), 1.0) * 255) for c in "rgb")
        return r, g, b


def _colour(value: Any, schema: DataSchema | None) -> Colour | None:
    """The colour in `value` (a list [r,g,b(,a)] or an object with r/g/b fields), or None."""
    if isinstance(value, list):
        if len(value) not in (3, 4) or not all(_is_number(v) for v in value):
            return None
        channels = dict(zip("rgba", (float(v) for v in value)))
        items = schema.items if schema is not None else None
        maxima = ([i.maximum for i in items] if isinstance(items, list)  # a tuple schema: one per channel
                  else [items.maximum] if items is not None else [])
    elif isinstance(value, dict):
        channels = {_CHANNEL_ALIASES[k.lower()]: float(v) for k, v in value.items()
                    if k.lower() in _CHANNEL_ALIASES and _is_number(v)}
        if not {"r", "g", "b"} <= channels.keys():
            return None
        fields = (schema.properties or {}) if schema is not None else {}
        maxima = [s.maximum for s in fields.values()]
    else:
        return None
    known = [m for m in maxima if m is not None]
    if known:
        scale = max(known)
    else:  # no schema: 0..1 if every channel fits, else 0..255
        scale = 1.0 if all(0.0 <= v <= 1.0 for v in channels.values()) else 255.0
    return Colour(channels, float(scale) or 1.0)


def light_colour(value: Any) -> tuple[float, float, float] | None:
    """A light's colour as sRGB 0..1 (a list or an r/g/b object, in 0..1 or 0..255), or None."""
    colour = _colour(value, None)
    if colour is None:
        return None
    r, g, b = (min(max(colour.channels[c] / colour.scale, 0.0), 1.0) for c in "rgb")
    return r, g, b


def _is_colour(name: str, schema: DataSchema | None) -> bool:
    hints = [name]
    if schema is not None:
        hints += [schema.title or "", schema.format or ""]
        hints += schema.at_type if isinstance(schema.at_type, list) else [schema.at_type or ""]
    return any("color" in h.lower() or "colour" in h.lower() for h in hints)


def _json_type(value: Any) -> str:
    if isinstance(value, bool):
        return "boolean"
    if _is_number(value):
        return "number"
    if isinstance(value, str):
        return "string"
    if isinstance(value, list):
        return "array"
    if isinstance(value, dict):
        return "object"
    return "null"


def _is_number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _json(value: Any) -> str:
    return msgspec.json.encode(value).decode()
