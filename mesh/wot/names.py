"""Affordance names as one key chunk and one URL path segment: any name a TD gives gets its own.

A plain name (letters, digits, `_`, `.`, `-`: every name of ours and nearly every published one) is
itself; any other is percent-escaped (`/`, `*`, `$`, `?`, `#`, `%`, spaces, non-ASCII), the same
way on Zenoh and over HTTP. The TD keeps the name as written; only keys and hrefs carry the escape.
"""
from __future__ import annotations

import re
from urllib.parse import quote, unquote

PLAIN = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.-]*\Z")
NAME = PLAIN  # the affordance names a key chunk holds as they are
SLUG = re.compile(r"^[a-z0-9]+(?:-[a-z0-9]+)*\Z")  # a Thing's name on the mesh; \Z, not $: "name\n" is no slug
SAFE = "-._~!&'()+,;=:@"  # kept as they are (besides letters and digits): valid in a key chunk and a path
WILDCARDS = ("*", "**")


def escaped(name: str) -> str:
    """The name's key chunk and URL segment; `*` and `**` stay wildcards."""
    return name if PLAIN.match(name) or name in WILDCARDS else quote(name, safe=SAFE)


def unescaped(chunk: str) -> str:
    """The name a chunk or segment stands for (`escaped` undone)."""
    return unquote(chunk) if "%" in chunk else chunk
