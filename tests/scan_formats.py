"""Test scans written as LAS, LAZ and E57 (the `scans` extra's libraries), for tdgen and the recorder alike.

The scan's finite points only (LAS and E57 have no NaN points); LAS keeps them to 0.01 mm.
"""
from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tests.scans import Scan


def write_las(scan: Scan, path: Path) -> Path:
    """`.las` or `.laz` (LAZ through lazrs) by the name's suffix."""
    import laspy

    points = scan.finite()
    header = laspy.LasHeader(point_format=0, version="1.2")
    header.scales, header.offsets = [1e-5] * 3, points.min(axis=0)
    las = laspy.LasData(header)
    las.x, las.y, las.z = points.T
    las.write(str(path))
    return path


def write_e57(scan: Scan, path: Path) -> Path:
    import pye57

    points = scan.finite()
    e57 = pye57.E57(str(path), mode="w")
    e57.write_scan_raw({"cartesianX": points[:, 0], "cartesianY": points[:, 1], "cartesianZ": points[:, 2]})
    e57.close()
    return path
