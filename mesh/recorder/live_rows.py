"""The live view's stream with each transform frame's newest row only: what a browser can take in.

Rerun's web viewer takes in a transform row (a pose placing a frame) at a cost each, in the frames
it draws; a busy lab at `--speed max` sends many poses a second per frame (every sample of every
joint, cube and moving base), and a browser drawing a few frames a second (software WebGL, a loaded
machine) took them in slower than they came and fell minutes behind, whatever the chunks
(`tests/bench/bench_viewer_capacity.py` varies one thing at a time: rows of transforms are what
counts; plots, chunks of scalars and the scene's size are not). Nobody sees the poses in between:
the view shows where everything is now. So the stream is wrapped: of a `send_columns` of transforms
(one per entity and flush), only the newest row of each frame goes out (of an entity without frame
names, its newest row); every other column and call is the stream's own. The `.rrd` file of
`--record` is written by another recorder and keeps every row.
"""
from __future__ import annotations

from typing import Any

import pyarrow as pa

CHILD_FRAME = "Transform3D:child_frame"
TRANSFORM = "Transform3D:"


class _Taken:
    """A time or component column with some of its rows, as `send_columns` takes it."""

    def __init__(self, column: Any, rows: pa.Array):
        self._column, self._array = column, column.as_arrow_array().take(rows)

    def timeline_name(self) -> str:
        return self._column.timeline_name()

    def component_descriptor(self) -> Any:
        return self._column.component_descriptor()

    def as_arrow_array(self) -> pa.Array:
        return self._array


def newest_rows(columns: list[Any]) -> list[int] | None:
    """The rows to send of a batch of component columns: the newest of each transform frame, in their
    order; None: send all (no transforms, or no row to leave out)."""
    arrays = {c.component_descriptor().component: c.as_arrow_array() for c in columns}
    if not any(name.startswith(TRANSFORM) for name in arrays):
        return None
    n = len(next(iter(arrays.values())))
    frames = arrays[CHILD_FRAME].to_pylist() if CHILD_FRAME in arrays else [None] * n
    newest = {str(f[0]) if f else None: i for i, f in enumerate(frames)}
    return None if len(newest) == n else sorted(newest.values())


class NewestTransforms:
    """A RecordingStream whose `send_columns` of transforms sends each frame's newest row only (see the
    module's docstring); everything else is the stream's own."""

    def __init__(self, rec: Any):
        self.rec = rec

    def __getattr__(self, name: str) -> Any:
        return getattr(self.rec, name)

    def send_columns(self, path: str, indexes: Any, columns: Any, **kwargs: Any) -> None:
        indexes, columns = list(indexes), list(columns)
        rows = newest_rows(columns)
        if rows is not None:
            taken = pa.array(rows, type=pa.int64())
            indexes = [_Taken(i, taken) for i in indexes]
            columns = [_Taken(c, taken) for c in columns]
        self.rec.send_columns(path, indexes, columns, **kwargs)
