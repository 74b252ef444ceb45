"""A robot's joints written as two chunks per flush, whatever the number of its joints.

Rerun's web viewer takes in new data for about the same time per chunk whatever its rows
(`mesh.recorder.view`), so the number of chunks a second is what a slow browser cannot keep up with;
one chunk per joint per flush made a robot's joints most of a busy lab's chunks. So a robot's joints go
out as one entity for their values and one for their transforms:
- the values: one `Scalars` row per sample with every joint's value, one series per joint (Rerun plots
  each scalar of a row as its own series, named in order by one `SeriesLines`);
- the transforms: one `Transform3D` row per joint that moved, each naming its own child and parent
  frame, all on one entity (a frame still belongs to one entity, as Rerun requires), computed from the
  URDF in one call (`UrdfTree.compute_joint_transform_batches`).
A sample in which no joint moved is not written (Rerun holds the last value until the next).
"""
from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np
import pyarrow as pa
import rerun as rr
from rerun.urdf import UrdfTree

from mesh.recorder.batches import SampleBatch


@dataclass
class JointRows:
    """One robot's joint samples waiting for the next flush (values in rad or m)."""

    names: list[str] = field(default_factory=list)  # the series, in the order of a row (grows only)
    last: dict[str, float] = field(default_factory=dict)  # each joint's latest value
    rows: SampleBatch = field(default_factory=SampleBatch)  # values: one list per sample, in `names` order
    moved: SampleBatch = field(default_factory=SampleBatch)  # values: {joint: value} of those that moved
    whole: bool = False  # the next sample goes out with every joint, moved or not (`redrawn`)

    def redrawn(self) -> None:
        """The robot was drawn again (its model's zero pose): its next sample places every joint."""
        self.whole = True

    def add(self, wall: float, seq: int, sim: float | None, values: dict[str, float]) -> None:
        moved = dict(values) if self.whole else {j: v for j, v in values.items() if self.last.get(j) != v}
        if not moved:
            return
        self.whole = False
        self.names += [j for j in moved if j not in self.last]
        self.last.update(moved)
        self.rows.add(wall, seq, sim, [self.last[j] for j in self.names])
        self.moved.add(wall, seq, sim, moved)

    def take(self) -> tuple[SampleBatch, SampleBatch]:
        """The rows and moves queued so far; the queue starts again empty (the latest values stay)."""
        rows, moved = self.rows, self.moved
        self.rows, self.moved = SampleBatch(), SampleBatch()
        return rows, moved


def send_values(rec, path: str, names: list[str], units: list[str], rows: SampleBatch,
                made: dict[tuple[int, ...], list[rr.TimeColumn]], styled: dict[str, list[str]]) -> None:
    """The rows as one `send_columns` to `path` (one more per row width, should a joint join later), the
    series named `<joint> (<unit>)` in row order once, and again when a name or unit changes."""
    labels = [f"{j} ({u})" for j, u in zip(names, units)]
    if styled.get(path) != labels:
        rec.log(path, rr.SeriesLines(names=labels, interpolation_mode="StepAfter"), static=True)
        styled[path] = labels
    widths = {len(v) for v in rows.values}
    for width in sorted(widths):
        part = rows if len(widths) == 1 else rows.where(functools.partial(_has_width, width))
        rec.send_columns(path, part.indexes(made), rr.Scalars.columns(scalars=np.array(part.values)))


def _has_width(width: int, row: list[float]) -> bool:
    return len(row) == width


def send_transforms(rec, path: str, tree: UrdfTree, joints: set[str], moved: SampleBatch) -> None:
    """The moved joints' transforms as one `send_columns` to `path`, one row per joint and sample, each row
    naming its frames (joints the URDF does not have are left out)."""
    names = [[j for j in m if j in joints] for m in moved.values]
    counts = np.array([len(n) for n in names])
    if not counts.sum():
        return
    values = [[float(m[j]) for j in n] for m, n in zip(moved.values, names)]
    batches = tree.compute_joint_transform_batches(pa.array(names, type=pa.list_(pa.utf8())),
                                                   pa.array(values, type=pa.list_(pa.float64())), clamp=False)
    rows = batches.flatten()
    translation = np.asarray(rows.field("translation").flatten(), dtype=np.float32).reshape(-1, 3)
    quaternion = np.asarray(rows.field("quaternion").flatten(), dtype=np.float32).reshape(-1, 4)
    indexes = moved.indexes(repeats=counts)
    columns = rr.Transform3D.columns(translation=translation, quaternion=quaternion,
                                     parent_frame=rows.field("parent_frame").to_pylist(),
                                     child_frame=rows.field("child_frame").to_pylist())
    rec.send_columns(path, indexes, columns)
