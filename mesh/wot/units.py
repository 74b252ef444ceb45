"""Units of measure from one vocabulary: QUDT's unit IRIs, written `qudt:<NAME>` in a TD's `unit`.

The TD 1.1 context maps `unit` to `schema:unitCode` with IRI values, so a compact IRI whose prefix
the TD's `@context` declares (`TD_CONTEXT` does) expands to the unit's QUDT IRI, e.g. `qudt:DEG` ->
http://qudt.org/vocab/unit/DEG. `SYMBOLS` gives the short symbol people read in plots and tables.
"""
from __future__ import annotations

PREFIX = "qudt"
QUDT_UNITS = "http://qudt.org/vocab/unit/"

DEGREE = "qudt:DEG"
DEGREE_PER_SECOND = "qudt:DEG-PER-SEC"
MILLIMETRE = "qudt:MilliM"
MILLIMETRE_PER_MINUTE = "qudt:MilliM-PER-MIN"
METRE = "qudt:M"
SECOND = "qudt:SEC"
MILLISECOND = "qudt:MilliSEC"
PERCENT = "qudt:PERCENT"
LUX = "qudt:LUX"
KELVIN = "qudt:K"
CELSIUS = "qudt:DEG_C"
UNITLESS = "qudt:UNITLESS"  # a ratio or a normalised value (0..1 colour channels, probabilities, speed factors)
NUMBER = "qudt:NUM"         # a count

SYMBOLS = {DEGREE: "deg", DEGREE_PER_SECOND: "deg/s", MILLIMETRE: "mm", MILLIMETRE_PER_MINUTE: "mm/min",
           METRE: "m", SECOND: "s", MILLISECOND: "ms", PERCENT: "%", LUX: "lx", KELVIN: "K", CELSIUS: "°C", UNITLESS: "",
           NUMBER: ""}


def iri(unit: str) -> str:
    """The full IRI of a `qudt:` unit (other strings are returned as they are)."""
    return QUDT_UNITS + unit.removeprefix(f"{PREFIX}:") if unit.startswith(f"{PREFIX}:") else unit


def symbol(unit: str | None) -> str:
    """What people read: `qudt:MilliM` -> `mm`; a unit outside the vocabulary is shown as written."""
    return SYMBOLS.get(unit, unit) if unit else ""
