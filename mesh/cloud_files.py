"""Point-cloud files read from their bytes: PCD, PLY and XYZ text, the formats a `points` body names most,
and LAS/LAZ (laspy) and E57 (pye57) scans when those are installed (`pip install 'twinmesh[scans]'`).

Both the robot library (`tdgen.robot.scan_io`, which builds a scan into collision shapes from a path) and
the recorder (`mesh.recorder.scene_assets`, which draws the file a Thing serves) read them, so they are
read here, once, below both. A file that is not what its name says raises `CloudFileError` with a
line for people (the caller adds the file's name); a library's own failure on a broken file is left to
the caller to word. An E57 file is read from a path (libE57Format reads no memory): from bytes, through a
temporary file.
"""
from __future__ import annotations

import io
import re
import tempfile
from pathlib import Path

import numpy as np

TEXT_SUFFIXES = (".xyz", ".pts", ".txt", ".csv")
LAS_SUFFIXES = (".las", ".laz")
SUFFIXES = (".pcd", ".ply", *TEXT_SUFFIXES, *LAS_SUFFIXES, ".e57")


class CloudFileError(ValueError):
    """The file's content is not a cloud of its format."""


def read_cloud_bytes(suffix: str, data: bytes) -> np.ndarray:
    """The points of a cloud file (N, 3), as the file holds them (NaN points kept), by its `suffix`."""
    if suffix == ".pcd":
        return _pcd(data)
    if suffix == ".ply":
        import trimesh

        loaded = trimesh.load(io.BytesIO(data), file_type="ply", process=False)
        return np.asarray(loaded.vertices, dtype=np.float64).reshape(-1, 3)  # type: ignore[attr-defined]
    if suffix in TEXT_SUFFIXES:
        return xyz_text(data.decode(errors="replace"))
    if suffix in LAS_SUFFIXES:
        return _las(io.BytesIO(data))
    if suffix == ".e57":
        with tempfile.NamedTemporaryFile(suffix=".e57") as f:
            f.write(data)
            f.flush()
            return _e57(Path(f.name))
    raise CloudFileError(f"unknown point cloud format {suffix or '(no extension)'!r} (known: {', '.join(SUFFIXES)})")


def _pcd(data: bytes) -> np.ndarray:
    from pypcd4 import Encoding, MetaData, PointCloud

    source = io.BytesIO(data)
    lines: list[str] = []
    for line in source:  # the header as pypcd4 reads it (`PointCloud.from_fileobj`)
        text = line.decode("utf-8").strip()
        if text and not text.startswith("#"):
            lines.append(text)
            if text.startswith("DATA") or len(lines) >= 10:
                break
    meta = MetaData.parse_header(lines)
    missing = [f for f in "xyz" if f not in meta.fields]
    if missing:
        raise CloudFileError(f"the PCD file has no {'/'.join(missing)} field (fields: {', '.join(meta.fields)})")
    counts = dict(zip(meta.fields, meta.count))
    if meta.data == Encoding.BINARY_COMPRESSED and meta.points and all(counts[f] == 1 for f in "xyz"):
        return _compressed_xyz(meta, data[source.tell():])
    source.seek(0)
    cloud = PointCloud.from_fileobj(source)  # type: ignore[arg-type]  # any binary file object
    return np.asarray(cloud.numpy(("x", "y", "z")), dtype=np.float64).reshape(-1, 3)


def _compressed_xyz(meta, body: bytes) -> np.ndarray:
    """x, y and z of an LZF binary_compressed PCD body, straight from their columns (the format stores each field
    as one block): pypcd4 interleaves every field of every point into a record first, half the read's time for
    a scan with labels and colours."""
    import lzf  # pypcd4's LZF codec

    if len(body) < 8:
        raise CloudFileError("the PCD file's compressed data is cut short")
    compressed, size = np.frombuffer(body[:8], dtype="<u4")
    buffer = lzf.decompress(body[8:8 + int(compressed)], int(size))
    if buffer is None or len(buffer) != size:
        raise CloudFileError(f"the PCD file's compressed data does not decompress to its {int(size):,} bytes")
    dtype, offset, columns = meta.build_dtype(), 0, {}
    for name in dtype.names:
        field = dtype[name]
        columns[name] = (offset, field)
        offset += field.itemsize * meta.points
    if offset > len(buffer):
        raise CloudFileError(f"the PCD file's data holds {len(buffer):,} bytes, not the {offset:,} of its points")
    points = np.empty((3, meta.points))  # column by column, as pypcd4's arrays are laid out
    for k, name in enumerate("xyz"):
        at, field = columns[name]
        points[k] = np.frombuffer(buffer, dtype=field, count=meta.points, offset=at)
    return points.T


def read_cloud_file(path: Path) -> np.ndarray:
    """The points of the cloud file at `path`, as `read_cloud_bytes` reads them (an E57 file where it is)."""
    suffix = path.suffix.lower()
    return _e57(path) if suffix == ".e57" else read_cloud_bytes(suffix, path.read_bytes())


def _las(source: io.BytesIO) -> np.ndarray:
    try:
        import laspy
    except ImportError:
        raise CloudFileError("LAS/LAZ scans need laspy (pip install 'twinmesh[scans]')") from None
    _las_header_fits(source.getbuffer())
    las = laspy.read(source)  # a LAZ file through lazrs, when installed (laspy says so otherwise)
    return np.column_stack([las.x, las.y, las.z]).astype(np.float64)


LAS_VLR_HEADER = 54  # bytes: the least a variable-length record takes


def _las_header_fits(data: memoryview) -> None:
    """The header's record count and point offset within the file: laspy reads a broken header's records
    until their count, past the end, for as long as that takes (hours for a count of billions)."""
    if len(data) < 104 or bytes(data[:4]) != b"LASF":
        raise CloudFileError("not a LAS file (no LASF header)")
    header_size, point_offset, records = np.frombuffer(data[94:104], dtype=np.dtype("<u2, <u4, <u4"))[0]
    if not header_size <= point_offset <= len(data) or header_size + records * LAS_VLR_HEADER > point_offset:
        raise CloudFileError(f"the LAS header is broken ({records} records, points at byte {point_offset} of "
                             f"{len(data)})")


def _e57(path: Path) -> np.ndarray:
    """Every scan of the file in the file's frame (each placed by its own pose)."""
    try:
        import pye57
    except ImportError:
        raise CloudFileError("E57 scans need pye57 (pip install 'twinmesh[scans]')") from None
    e57 = pye57.E57(str(path))
    scans = [e57.read_scan(k, ignore_missing_fields=True, transform=True) for k in range(e57.scan_count)]
    if not scans:
        return np.zeros((0, 3))
    return np.vstack([np.column_stack([s["cartesianX"], s["cartesianY"], s["cartesianZ"]]) for s in scans])


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
