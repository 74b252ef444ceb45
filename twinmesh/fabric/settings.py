"""One typed settings object for a peer; CLI flags and environment map onto it."""
from __future__ import annotations

import json
from typing import Literal

import msgspec

from twinmesh.fabric.keys import Keys

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
MIN_SPEED, MAX_SPEED = 0.01, 1000.0  # sane simulation speed factors: slower freezes a lab, faster is `max`
Mode = Literal["peer", "client", "router"]


class MeshSettings(msgspec.Struct, frozen=True, kw_only=True):
    """How a process joins the mesh.

    Defaults give a closed loopback lab: every peer connects to the lab's router on
    127.0.0.1:7447 (started by `twinmesh up`) and multicast scouting is off, so a test run never
    meets a neighbour's lab. `listen`/`connect` and `mode="router"` let peers on other hosts join.
    """

    prefix: str = "wot"
    mode: Mode = "peer"
    connect: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    listen: tuple[str, ...] = ()
    multicast: bool = False
    query_timeout: float = 5.0   # reads, writes, TDs
    action_timeout: float = 300.0  # motions return when done, which can take minutes at speed 1

    @property
    def keys(self) -> Keys:
        return Keys(self.prefix)

    def zenoh_config(self):  # -> zenoh.Config (import kept local: zenoh loads a native library)
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
        return conf

    def as_router(self, listen: tuple[str, ...] | None = None) -> "MeshSettings":
        """The settings of the lab's router: it listens where the peers connect."""
        return msgspec.structs.replace(self, mode="router", listen=listen or self.connect, connect=())


def parse_speed(value: str) -> float | None:
    """A simulation speed factor from the command line: a positive number, or 'max' (None)."""
    if value == "max":
        return None
    try:
        f = float(value)
    except ValueError:
        raise ValueError(f"speed must be a positive number or 'max', not {value!r}") from None
    if not MIN_SPEED <= f <= MAX_SPEED:
        raise ValueError(f"speed must be within {MIN_SPEED:g}..{MAX_SPEED:g}, or 'max', not {value!r}")
    return f
