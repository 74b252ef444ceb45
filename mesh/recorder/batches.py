"""Rows of one entity held for one `send_columns`: the recorder writes a few times a second, not once a sample.

One `log` call per value costs far more than a row of a `send_columns`, and makes a chunk of its own
(see `mesh.recorder.scene_drawer`); so joint values and poses wait here until the drawer flushes.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable

import numpy as np
import rerun as rr


@dataclass
class SampleBatch:
    """Rows of one entity waiting for one `send_columns`: the timelines and the values.

    `sim` is None for a row without simulated time (a robot Thing before any world's poses); the
    batch then goes out on `time` and `seq` only."""

    wall: list[float] = field(default_factory=list)
    seq: list[int] = field(default_factory=list)
    sim: list[float | None] = field(default_factory=list)
    values: list[Any] = field(default_factory=list)

    def add(self, wall: float, seq: int, sim: float | None, value: Any) -> None:
        self.wall.append(wall)
        self.seq.append(seq)
        self.sim.append(sim)
        self.values.append(value)

    def where(self, keep: Callable[[Any], bool]) -> "SampleBatch":
        """The rows whose value `keep` accepts."""
        rows = [i for i, v in enumerate(self.values) if keep(v)]
        return SampleBatch([self.wall[i] for i in rows], [self.seq[i] for i in rows], [self.sim[i] for i in rows],
                           [self.values[i] for i in rows])

    def indexes(self, made: dict[tuple[int, ...], list[rr.TimeColumn]] | None = None,
                repeats: np.ndarray | None = None) -> list[rr.TimeColumn]:
        """The time columns, each row's time `repeats[i]` times if given (rows of several frames at one
        time); batches of the same samples share them through `made`."""
        key = tuple(self.seq)
        columns = made.get(key) if made is not None and repeats is None else None
        if columns is None:  # numpy arrays: rerun converts lists element by element
            n = np.ones(len(self.seq), dtype=np.int64) if repeats is None else repeats
            columns = [rr.TimeColumn("time", timestamp=np.repeat(np.array(self.wall), n)),
                       rr.TimeColumn("seq", sequence=np.repeat(np.array(self.seq, dtype=np.int64), n))]
            if None not in self.sim:
                columns.append(rr.TimeColumn("sim_time", duration=np.repeat(np.array(self.sim, dtype=float), n)))
            if made is not None and repeats is None:
                made[key] = columns
        return columns
