"""What a lab says about itself on the mesh: its readiness (`<prefix>/_lab/status`, what `twinmesh wait`
asks), the tdgen service's per-robot status, and the record of each action call (published on the
action's key after each invocation, for the recorder)."""
from __future__ import annotations

from typing import Any

import msgspec


class LabStatus(msgspec.Struct, kw_only=True):
    """What `<prefix>/_lab/status` answers: enough for a script to find the lab's doors."""

    ready: bool
    scene: str
    things: list[str]
    http: str | None = None   # base URL of the HTTP adapter, if one runs
    zenoh: str = ""           # the endpoint the lab's router listens on


class RobotStatus(msgspec.Struct, omit_defaults=True):
    """The tdgen service's `robots` property holds one per robot: how far its workspace is."""

    status: str                 # generating | ready | failed
    version: int                # of the robot's twin
    hash: str | None = None
    seconds: float | None = None
    cached: bool | None = None
    error: str | None = None
    progress: float | None = None  # 0..1 of the workspace sampling, while generating
    live: bool | None = None       # ready by a live update of the previous scene's samples (tdgen.live)


class ActionCall(msgspec.Struct, omit_defaults=True):
    """Published on `<prefix>/<thing>/actions/<a>` after each invocation, so calls can be recorded."""

    input: Any = None
    output: Any = None
    error: str | None = None
    status: int = 200
    seconds: float = 0.0
