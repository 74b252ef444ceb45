"""The live view's stream with the current state of everything in it sent again every few seconds.

The live view's gRPC server keeps only the newest part of the stream for a browser that opens late
(`mesh.recorder.view.MEMORY`, static data besides), so that the late viewer has little to take in
before it is current. A state logged once and then left alone (a lamp switched on an hour ago, an
obstacle, a joint at rest, a Thing's TD) would drop out of that part, and the late viewer would draw
it as it was at the start (or not at all). So the view's RecordingStream is wrapped: every temporal
value logged through it is remembered per entity and component (the last row of a `send_columns`
batch), and on each flush an entity not logged for `refresh` seconds (`mesh.recorder.view.REFRESH`)
is logged again as it is now, at the present time. The server's window then always holds the
whole current state, however long the lab has run. Log lines (`TextLog`) are history, not state:
never repeated. A `Clear` forgets what it clears. The `.rrd` file of `--record` is written by
another recorder, without this.
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


class LiveState:
    """A RecordingStream that logs the current state again on a flush (see the module's docstring);
    everything else is the stream's own (`send_blueprint`, `send_chunks`, `set_sinks`, ...)."""

    def __init__(self, rec: rr.RecordingStream, refresh: float, clock=time.monotonic):
        self.rec = rec
        self.refresh = refresh
        self._clock = clock
        self._state: dict[str, dict[str, Any]] = {}  # entity -> component -> its latest value
        self._logged: dict[str, float] = {}  # entity -> when it was last logged (clock)
        self._times: dict[str, dict[str, Any]] = {}  # timeline -> the set_time arguments now in force

    def __getattr__(self, name: str) -> Any:
        return getattr(self.rec, name)

    def set_time(self, timeline: str, **value: Any) -> None:
        self._times[timeline] = value
        self.rec.set_time(timeline, **value)

    def log(self, path: str, entity: Any, *extra: Any, static: bool = False, **kwargs: Any) -> None:
        self.rec.log(path, entity, *extra, static=static, **kwargs)
        if isinstance(entity, rr.Clear):
            self._forget(path, _recursive(entity))
        elif not static and not isinstance(entity, rr.TextLog):
            self._remember(path, [b for e in (entity, *extra) for b in _batches(e)])

    def send_columns(self, path: str, indexes: Any, columns: Any, **kwargs: Any) -> None:
        self.rec.send_columns(path, indexes, columns, **kwargs)
        self._remember(path, [_Row(c.component_descriptor(), c.as_arrow_array()[-1].values) for c in columns])

    def flush(self, *args: Any, **kwargs: Any) -> None:
        self.log_current_state()
        self.rec.flush(*args, **kwargs)

    def log_current_state(self) -> int:
        """Log again each entity left alone for `refresh` s, at the present time; returns how many."""
        now = self._clock()
        stale = [path for path, at in self._logged.items() if now - at >= self.refresh]
        if not stale or "time" not in self._times:
            return 0
        self.rec.set_time("time", timestamp=time.time())
        for path in stale:
            self.rec.log(path, list(self._state[path].values()))
            self._logged[path] = now
        self.rec.set_time("time", **self._times["time"])  # what is logged next keeps its own time
        return len(stale)

    def _remember(self, path: str, batches: list[Any]) -> None:
        if not batches:
            return
        state = self._state.setdefault(path, {})
        for batch in batches:
            state[str(batch.component_descriptor())] = batch
        self._logged[path] = self._clock()

    def _forget(self, path: str, recursive: bool) -> None:
        gone = [p for p in self._state if p == path or (recursive and p.startswith(path.rstrip("/") + "/"))]
        for p in gone:
            del self._state[p], self._logged[p]


def _recursive(clear: rr.Clear) -> bool:
    flags = clear.is_recursive.as_arrow_array().to_pylist() if clear.is_recursive is not None else []
    return bool(flags and flags[0])


def _batches(entity: Any) -> list[DescribedComponentBatch]:
    if hasattr(entity, "as_component_batches"):
        return list(entity.as_component_batches())
    return list(entity)
