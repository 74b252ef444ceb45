"""The live view's stream with the current state of everything in it logged again before it is dropped.

The live view's gRPC server keeps only the newest part of the stream for a browser that opens late
(`mesh.recorder.view.MEMORY`, static data besides), so that the late viewer has little to take in
before it is current. A state logged once and then left alone (a lamp switched on an hour ago, an
obstacle, a joint at rest, a Thing's TD) would drop out of that part, and the late viewer would draw
it as it was at the start (or not at all). So the view's RecordingStream is wrapped: every temporal
value logged through it is remembered per entity and component (the last row of a `send_columns`
batch; of an entity whose rows name transform frames, the last row of each frame: a robot's joints),
the bytes logged are counted, and on each flush an entity behind which `budget` bytes have
been logged since it was last logged is logged again as it is now, at the present time. With a
budget well under the server's limit, that newest part always holds the whole current state,
however long the lab has run; a quiet lab logs nothing again (nothing is dropped), and a browser
that can hardly keep up is not sent more than it must. Log lines (`TextLog`) are history, not
state: never repeated. A `Clear` forgets what it clears. The `.rrd` file of `--record` is written
by another recorder, without this.
"""
from __future__ import annotations

import time
from typing import Any

import rerun as rr
from rerun._baseclasses import DescribedComponentBatch


class _Row:
    """One component's value as a batch `rr.log` takes (the last row of a column)."""

    def __init__(self, descriptor: Any, array: Any):
        self._descriptor, self._array = descriptor, array

    def component_descriptor(self) -> Any:
        return self._descriptor

    def as_arrow_array(self) -> Any:
        return self._array


CHILD_FRAME = "Transform3D:child_frame"
_Key = tuple[str, "str | None"]  # an entity, and the transform frame its rows name (None: it names none)
CHUNK_COST = 1024  # bytes counted per log call besides its data: a chunk's schema and metadata on the wire


class LiveState:
    """A RecordingStream that logs the current state again on a flush (see the module's docstring);
    everything else is the stream's own (`send_blueprint`, `send_chunks`, `set_sinks`, ...)."""

    def __init__(self, rec: Any, budget: int):  # a RecordingStream, or one wrapped (`live_rows`)
        self.rec = rec
        self.budget = budget
        self.logged = 0  # bytes of temporal data logged so far (estimated)
        self._state: dict[_Key, dict[str, Any]] = {}  # (entity, frame) -> component -> its latest value
        self._at: dict[_Key, int] = {}  # (entity, frame) -> `logged` when it was last logged
        self._times: dict[str, dict[str, Any]] = {}  # timeline -> the set_time arguments now in force

    def __getattr__(self, name: str) -> Any:
        return getattr(self.rec, name)

    def set_time(self, timeline: str, **value: Any) -> None:
        self._times[timeline] = value
        self.rec.set_time(timeline, **value)

    def log(self, path: str, entity: Any, *extra: Any, static: bool = False, **kwargs: Any) -> None:
        self.rec.log(path, entity, *extra, static=static, **kwargs)
        if static:
            if isinstance(entity, rr.Clear):
                self._forget(path, _recursive(entity))
            return
        batches = [b for e in (entity, *extra) for b in _batches(e)]
        self._count(batches)
        if isinstance(entity, rr.Clear):
            self._forget(path, _recursive(entity))
        elif not isinstance(entity, rr.TextLog):
            self._remember((path, None), batches)

    def send_columns(self, path: str, indexes: Any, columns: Any, **kwargs: Any) -> None:
        self.rec.send_columns(path, indexes, columns, **kwargs)
        arrays = [(c.component_descriptor(), c.as_arrow_array()) for c in columns]
        self.logged += CHUNK_COST + sum(a.nbytes for _, a in arrays)
        frames = next((a for d, a in arrays if d.component == CHILD_FRAME), None)
        if frames is None:
            self._remember((path, None), [_Row(d, a[-1].values) for d, a in arrays])
            return
        last = {str(f[0]) if len(f) else None: i for i, f in enumerate(frames.to_pylist())}  # frame -> its last row
        for frame, i in last.items():
            self._remember((path, frame), [_Row(d, a[i].values) for d, a in arrays])

    def flush(self, *args: Any, **kwargs: Any) -> None:
        self.log_current_state()
        self.rec.flush(*args, **kwargs)

    def log_current_state(self) -> int:
        """Log again, at the present time, each entity behind which `budget` bytes have been logged;
        returns how many."""
        due = [key for key, at in self._at.items() if self.logged - at >= self.budget]
        if not due or "time" not in self._times:
            return 0
        self.rec.set_time("time", timestamp=time.time())
        for key in due:
            batches = list(self._state[key].values())
            self.rec.log(key[0], batches)
            self._count(batches)
            self._at[key] = self.logged
        self.rec.set_time("time", **self._times["time"])  # what is logged next keeps its own time
        return len(due)

    def _count(self, batches: list[Any]) -> None:
        self.logged += CHUNK_COST + sum(b.as_arrow_array().nbytes for b in batches)

    def _remember(self, key: _Key, batches: list[Any]) -> None:
        if not batches:
            return
        state = self._state.setdefault(key, {})
        for batch in batches:
            state[str(batch.component_descriptor())] = batch
        self._at[key] = self.logged

    def _forget(self, path: str, recursive: bool) -> None:
        gone = [k for k in self._state if k[0] == path or (recursive and k[0].startswith(path.rstrip("/") + "/"))]
        for k in gone:
            del self._state[k], self._at[k]


def _recursive(clear: rr.Clear) -> bool:
    flags = clear.is_recursive.as_arrow_array().to_pylist() if clear.is_recursive is not None else []
    return bool(flags and flags[0])


def _batches(entity: Any) -> list[DescribedComponentBatch]:
    if hasattr(entity, "as_component_batches"):
        return list(entity.as_component_batches())
    return list(entity)
