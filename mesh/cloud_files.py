"""Point-cloud files read from their bytes: PCD, PLY and XYZ text, the formats a `points` body names most.

Both the robot library (`tdgen.robot.scan_io`, which builds a scan into collision shapes from a path) and
the recorder (`mesh.recorder.scene_assets`, which draws the file a Thing serves) read them, so they are
read here, once, below both. A file that is not what its name says raises `CloudFileError` with a
line for people (the caller adds the file's name); a library's own failure on a broken file is left to
the caller to word.
"""
from __future__ import annotations

import io
import re

import numpy as np

TEXT_SUFFIXES = (".xyz", ".pts", ".txt", ".csv")
SUFFIXES = (".pcd", ".ply", *TEXT_SUFFIXES)


class CloudFileError(ValueError):
    """The file's content is not a cloud of its format."""


def read_cloud_bytes(suffix: str, data: bytes) -> np.ndarray:
    """The points of a cloud file (N, 3), as the file holds them (NaN points kept), by its `suffix`."""
    if suffix == ".pcd":
        from pypcd4 import PointCloud

        cloud = PointCloud.from_fileobj(io.BytesIO(data))  # type: ignore[arg-type]  # any binary file object
        missing = [f for f in "xyz" if f not in cloud.fields]
        if missing:
            raise CloudFileError(f"the PCD file has no {'/'.join(missing)} field (fields: {', '.join(cloud.fields)})")
        return np.asarray(cloud.numpy(("x", "y", "z")), dtype=np.float64).reshape(-1, 3)
    if suffix == ".ply":
        import trimesh

        loaded = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
        return np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)  # type: ignore[attr-defined]
    if suffix in TEXT_SUFFIXES:
        return xyz_text(data.decode(errors="replace"))
    raise CloudFileError(f"unknown point cloud format {suffix or '(no extension)'!r} (known: {', '.join(SUFFIXES)})")


def xyz_text(text: str) -> np.ndarray:
    """Plain XYZ text: x y z first on each line (spaces, commas or semicolons), more columns ignored,
    a header line and `#` comments skipped."""
    rows: list[list[float]] = []
    for line in text.splitlines():
        fields = [f for f in re.split(r"[\s,;]+", line.split("#", 1)[0].strip()) if f]
        if not fields:
            continue
        try:
            rows.append([float(f) for f in fields[:3]])
        except ValueError:
            if rows:  # a header is the first line, not one in the middle
                raise CloudFileError(f"line {line[:60]!r} is not x y z numbers") from None
            continue
        if len(rows[-1]) != 3:
            raise CloudFileError(f"line {line[:60]!r} has fewer than 3 numbers")
    return np.array(rows, dtype=float).reshape(-1, 3)
