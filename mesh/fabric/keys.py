"""Key expressions: the one contract every peer on the mesh speaks (SPEC §2).

Everything that builds or parses a key goes through here, so the layout lives in one place.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from mesh.wot.names import NAME, SLUG, escaped, unescaped

DEFAULT_PREFIX = "wot"

Kind = Literal["properties", "actions", "events", "files"]
KINDS: tuple[Kind, ...] = ("properties", "actions", "events", "files")


def check_slug(thing: str) -> str:
    """A Thing name must be a slug so that it is one key chunk and one URL segment."""
    if not SLUG.match(thing):
        raise ValueError(f"thing name {thing!r} is not a slug ([a-z0-9-]+, no leading/trailing dash)")
    return thing


def check_name(name: str) -> str:
    """Affordance and file names become one key chunk: no '/', '*', '$', '?', '#'."""
    if not NAME.match(name):
        raise ValueError(f"affordance name {name!r} cannot be a key expression chunk")
    return name


@dataclass(frozen=True)
class Keys:
    """Key expressions under one prefix (default `wot`)."""

    prefix: str = DEFAULT_PREFIX

    def alive(self, thing: str) -> str:
        return f"{self.prefix}/{thing}"

    def all_alive(self) -> str:
        return f"{self.prefix}/*"

    def twin(self, thing: str) -> str:
        """The liveliness token of a Thing whose TD links a twin (a robot): the tdgen service follows
        these alone, so a mesh of thousands of other devices costs it nothing."""
        return f"{self.prefix}/{thing}/twin"

    def all_twins(self) -> str:
        return f"{self.prefix}/*/twin"

    def td(self, thing: str) -> str:
        return f"{self.prefix}/{thing}/td"

    def affordance(self, thing: str, kind: Kind, name: str) -> str:
        return f"{self.prefix}/{thing}/{kind}/{escaped(name)}"

    def property(self, thing: str, name: str) -> str:
        return self.affordance(thing, "properties", name)

    def action(self, thing: str, name: str) -> str:
        return self.affordance(thing, "actions", name)

    def event(self, thing: str, name: str) -> str:
        return self.affordance(thing, "events", name)

    def file(self, thing: str, name: str) -> str:
        return self.affordance(thing, "files", name)

    def everything(self) -> str:
        return f"{self.prefix}/**"

    def parse(self, key: str) -> "ParsedKey | None":
        """Split a key into (thing, kind, name); None when it is not one of ours."""
        parts = str(key).split("/")
        pre = self.prefix.split("/")
        if parts[: len(pre)] != pre:
            return None
        rest = parts[len(pre):]
        if len(rest) == 1 and SLUG.match(rest[0]):
            return ParsedKey(rest[0], "alive", "")
        if len(rest) == 2 and rest[1] in ("td", "twin"):
            return ParsedKey(rest[0], rest[1], "")
        if len(rest) == 3 and rest[1] in KINDS:
            return ParsedKey(rest[0], rest[1], unescaped(rest[2]))
        return None


@dataclass(frozen=True)
class ParsedKey:
    thing: str
    kind: str  # "alive" | "td" | "twin" | one of KINDS
    name: str
