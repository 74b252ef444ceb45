"""points.csv, the sampled workspace as a file: `x,y,z,collision,<joint names>` (mm, 0/1, deg or mm).

Made once per generation (`encode`), read by target checks (`read`, `read_bytes`). A scene change
keeps the sampled configurations and changes only some collision flags, so a live update re-flags
the previous file in place (`Flags`): one byte per row, at offsets found once, instead of formatting
80,000 rows again (0.2 s). The bytes are those `encode` gives for the same samples.
"""
from __future__ import annotations

import hashlib
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from numba import njit, prange

from tdgen.robot.cores import LAUNCH

if TYPE_CHECKING:
    from tdgen.robot.model import Robot

HEADER = ["x", "y", "z", "collision"]  # the columns every reader relies on; the joints follow


def encode(robot: Robot, positions: np.ndarray, collision: np.ndarray, q: np.ndarray) -> bytes:
    """The file's bytes: positions in mm with 3 decimals, collision 0/1, then each joint of q (SI) in deg
    or mm with 6 decimals (each value rounded half to even at its last decimal)."""
    joints = np.ascontiguousarray(robot.to_user_units(q), dtype=float).reshape(len(q), len(robot.joints))
    header = (",".join([*HEADER, *(j.name for j in robot.joints)]) + "\n").encode()
    # the longest a row can be: per value a sign, its digits (one more: rounding up), the point, decimals, a comma
    row = 3 * (3 + len(str(int(np.abs(positions).max(initial=0.0)))) + 4) + 2
    row += joints.shape[1] * (3 + len(str(int(np.abs(joints).max(initial=0.0)))) + 7) + 1
    out = np.empty(len(joints) * row, dtype=np.uint8)
    with LAUNCH:
        ends = _format_blocks(np.ascontiguousarray(positions, dtype=float), np.asarray(collision, dtype=np.bool_),
                              joints, out, row, BLOCK_ROWS)
    starts = np.arange(len(ends)) * BLOCK_ROWS * row
    return b"".join([header, *(out[s:e].data for s, e in zip(starts, ends))])


BLOCK_ROWS = 32_768  # rows formatted by one core at a time, each block into its own part of the buffer


@njit(cache=True, parallel=True)
def _format_blocks(positions, collision, joints, out, row, block):  # pragma: no cover (compiled)
    """Blocks of `block` rows formatted on all cores, block b from b * block * row on (`row`: the longest
    a row can be); returns where each ends."""
    blocks = (positions.shape[0] + block - 1) // block
    ends = np.empty(blocks, dtype=np.int64)
    for b in prange(blocks):
        first = b * block
        last = min(first + block, positions.shape[0])
        ends[b] = _format(positions, collision, joints, out, first * row, first, last)
    return ends


@njit(cache=True)
def _format(positions, collision, joints, out, at, first, last):  # pragma: no cover (compiled)
    """Rows first..last as text into `out` from `at` on; returns where they end. numpy's savetxt takes 3 s
    for 1,000,000 rows, one Python % per value; this a third of a second on one core."""
    digits = np.empty(24, dtype=np.uint8)
    for r in range(first, last):
        for c in range(3 + 1 + joints.shape[1]):
            if c:
                out[at] = 44  # ,
                at += 1
            if c < 3:
                d, v = 3, np.int64(np.rint(positions[r, c] * 1e3))
            elif c == 3:
                d, v = 0, np.int64(1 if collision[r] else 0)
            else:
                d, v = 6, np.int64(np.rint(joints[r, c - 4] * 1e6))
            if v < 0:
                out[at] = 45  # -
                at += 1
                v = -v
            n = 0
            while v > 0 or n <= d:  # at least one digit before the point
                digits[n] = 48 + v % 10
                v //= 10
                n += 1
            for k in range(n - 1, -1, -1):
                out[at] = digits[k]
                at += 1
                if k == d and d > 0:
                    out[at] = 46  # .
                    at += 1
        out[at] = 10  # newline
        at += 1
    return at


def read_bytes(data: bytes, source: str = "points.csv") -> tuple[np.ndarray, np.ndarray]:
    """(positions (N, 3) mm, collision (N,) bool) from the file's bytes."""
    header = data.split(b"\n", 1)[0].decode(errors="replace").strip().split(",")
    if header[:4] != HEADER:
        raise ValueError(f"{source}: not a points CSV (header starts {header[:4]})")
    table = np.loadtxt(io.BytesIO(data), delimiter=",", skiprows=1, usecols=(0, 1, 2, 3), ndmin=2)
    return table[:, :3], table[:, 3].astype(bool)


def read(path: Path) -> tuple[np.ndarray, np.ndarray]:
    return read_bytes(Path(path).read_bytes(), str(path))


class Flags:
    """Where each row's collision flag is in a points.csv: re-flag it, or read only the flags. A re-flagged
    file is made when its bytes are first asked for (`data`): a robot that takes a scene change's flags
    keeps serving the file without copying 7.5 MB until someone downloads it."""

    def __init__(self, data: bytes | bytearray, offsets: np.ndarray | None = None, samples_sha: bytes | None = None,
                 flags: np.ndarray | None = None):
        """`offsets`: known already (the file re-flagged from one whose offsets were found), and with them
        `samples_sha`, if known (re-flagging keeps the samples), and `flags`: the flag bytes ('0'/'1') this
        file has instead of those of `data`, if any."""
        self._data = data
        self._flags = flags
        self._samples_sha = samples_sha
        if offsets is not None:
            self.offsets = offsets
            return
        buf = np.frombuffer(data, dtype=np.uint8)
        lines = np.flatnonzero(buf == ord("\n"))
        commas = np.flatnonzero(buf == ord(","))
        header_commas = int(np.searchsorted(commas, lines[0]))
        per_row = header_commas  # every row has as many fields as the header
        rows = len(lines) - 1
        if rows < 0 or per_row < 3 or len(commas) != per_row * (rows + 1):
            raise ValueError("not a points CSV with one flag per row")
        self.offsets = commas[per_row + 2::per_row][:rows] + 1  # after each row's third comma
        flags, after = buf[self.offsets], buf[np.minimum(self.offsets + 1, len(buf) - 1)]
        if not np.isin(flags, (ord("0"), ord("1"))).all() or not np.isin(after, (ord(","), ord("\n"))).all():
            raise ValueError("not a points CSV with a 0/1 collision column")

    @property
    def data(self) -> bytes | bytearray:
        """The file's bytes (re-flagged on first use: one copy, 8 ms for 7.5 MB)."""
        if self._flags is not None:
            buf = bytearray(self._data)
            np.frombuffer(buf, dtype=np.uint8)[self.offsets] = self._flags
            self._data, self._flags = buf, None
        return self._data

    @property
    def collision(self) -> np.ndarray:
        flags = self._flags if self._flags is not None else np.frombuffer(self._data, dtype=np.uint8)[self.offsets]
        return flags == ord("1")

    def reflagged(self, collision: np.ndarray) -> Flags:
        """The same file with these collision flags (its bytes made when asked for)."""
        if len(collision) != len(self.offsets):
            raise ValueError(f"{len(collision)} flags for {len(self.offsets)} rows")
        flags = np.where(collision, ord("1"), ord("0")).astype(np.uint8)
        return Flags(self._data, self.offsets, self._samples_sha, flags)

    @property
    def samples_sha(self) -> bytes:
        """The sha256 (hex) of the file with every flag 0: which samples it holds, whatever their flags.
        Computed once per file and kept by every re-flagged copy."""
        if self._samples_sha is None:
            buf = bytearray(self._data)  # whichever flags it holds: all are zeroed
            np.frombuffer(buf, dtype=np.uint8)[self.offsets] = ord("0")
            self._samples_sha = hashlib.sha256(buf).hexdigest().encode()
        return self._samples_sha

    def digest(self) -> bytes:
        """This file as a peer that holds its samples needs it: the sha256 (hex) of its samples
        (`samples_sha`), a newline, the collision flags packed 8 to a byte (80,000 rows: 10 kB
        instead of 7.5 MB). The same samples keep the same sha: no file is hashed on a scene change."""
        return self.samples_sha + b"\n" + np.packbits(self.collision).tobytes()

    def from_digest(self, digest: bytes) -> Flags | None:
        """The file a `digest` stands for, made from this one (the same samples, other flags); None when
        it does not stand for such a file (other samples: fetch the file itself)."""
        sha, _, packed = digest.partition(b"\n")
        rows = len(self.offsets)
        if len(packed) != (rows + 7) // 8 or sha != self.samples_sha:
            return None
        return self.reflagged(np.unpackbits(np.frombuffer(packed, dtype=np.uint8), count=rows).astype(bool))
