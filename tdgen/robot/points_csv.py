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

from tdgen.robot.cores import LAUNCH, compiled, njit, prange

if TYPE_CHECKING:
    from tdgen.robot.model import Robot

HEADER = ["x", "y", "z", "collision"]  # the columns every reader relies on; the joints follow


def encode(robot: Robot, positions: np.ndarray, collision: np.ndarray, q: np.ndarray,
           compile_here: bool | None = None) -> bytearray:
    """The file's bytes: positions in mm with 3 decimals, collision 0/1, then each joint of q (SI) in deg
    or mm with 6 decimals (each value rounded half to even at its last decimal).

    Two passes on all cores: each block's length, then each block formatted where it starts, into the
    one buffer returned: no join of per-block buffers, no numpy savetxt (both slower: docs/benchmarks.md).
    On a machine whose compiled code is not on disk yet (`cores.compiled`), unless `compile_here`, the
    same bytes from `encode_uncompiled`: compiling would hold a first workspace up longer."""
    joints = np.ascontiguousarray(robot.to_user_units(q), dtype=float).reshape(len(q), len(robot.joints))
    header = (",".join([*HEADER, *(j.name for j in robot.joints)]) + "\n").encode()
    positions = np.ascontiguousarray(positions, dtype=float)
    collision = np.asarray(collision, dtype=np.bool_)
    if not (compiled() if compile_here is None else compile_here):
        return bytearray(header + encode_uncompiled(positions, collision, joints))
    with LAUNCH:
        sizes = _block_sizes(positions, collision, joints, BLOCK_ROWS, _POW10)
        starts = len(header) + np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)
        out = bytearray(len(header) + int(sizes.sum()))
        out[:len(header)] = header
        _format_blocks(positions, collision, joints, np.frombuffer(out, dtype=np.uint8), starts, BLOCK_ROWS, _POW10,
                       _PAIRS)
    return out


def encode_uncompiled(positions: np.ndarray, collision: np.ndarray, joints: np.ndarray) -> bytes:
    """`encode`'s rows, the same bytes, by numpy and one `%` of Python's: nothing to compile, several times
    slower than the compiled code once that is there."""
    n = len(positions)
    columns = [(np.rint(positions[:, c] * 1e3).astype(np.int64), 3) for c in range(3)]
    columns += [(np.rint(joints[:, c] * 1e6).astype(np.int64), 6) for c in range(joints.shape[1])]
    args = np.empty((n, 3 * len(columns) + 1), dtype=object)
    for k, (v, d) in enumerate(columns):
        at = 3 * k + (1 if k >= 3 else 0)  # the collision flag after x, y, z
        whole, part = np.divmod(np.abs(v), 10 ** d)
        args[:, at] = np.where(v < 0, "-", "")
        args[:, at + 1] = whole.tolist()
        args[:, at + 2] = part.tolist()
    args[:, 9] = collision.astype(np.int64).tolist()
    row = ",".join(["%s%d.%03d"] * 3 + ["%d"] + ["%s%d.%06d"] * joints.shape[1]) + "\n"
    return ((row * n) % tuple(args.ravel().tolist())).encode()


BLOCK_ROWS = 32_768  # rows one core measures, then formats, at a time
_PAIRS = np.frombuffer("".join(f"{i:02d}" for i in range(100)).encode(), dtype=np.uint8).copy()  # "00".."99"
_POW10 = np.array([10 ** k for k in range(19)], dtype=np.uint64)


@njit(cache=True, inline="always")
def _scaled(positions, collision, joints, r, c):  # pragma: no cover (compiled)
    """Value c of row r as (its decimals d, the integer of its last decimal: value * 10**d, rounded half to even)."""
    if c < 3:
        return 3, np.int64(np.rint(positions[r, c] * 1e3))
    if c == 3:
        return 0, np.int64(1 if collision[r] else 0)
    return 6, np.int64(np.rint(joints[r, c - 4] * 1e6))


@njit(cache=True, inline="always")
def _width(v, d, pow10):  # pragma: no cover (compiled)
    """Characters of v (a value times 10**d) written with d decimals: its sign, its digits (at least d + 1:
    one before the point), the point."""
    sign = 0
    if v < 0:
        sign = 1
        v = -v
    u = np.uint64(v)
    digits = 1
    while digits < 19 and u >= pow10[digits]:
        digits += 1
    return sign + max(digits, d + 1) + (1 if d > 0 else 0)


@njit(cache=True, parallel=True)
def _block_sizes(positions, collision, joints, block, pow10):  # pragma: no cover (compiled)
    """Bytes of each block of `block` rows, on all cores."""
    rows, cols = positions.shape[0], 4 + joints.shape[1]
    blocks = (rows + block - 1) // block
    sizes = np.zeros(blocks, dtype=np.int64)
    for b in prange(blocks):
        total = 0
        for r in range(b * block, min(rows, (b + 1) * block)):
            total += cols  # the commas and the newline
            for c in range(cols):
                d, v = _scaled(positions, collision, joints, r, c)
                total += _width(v, d, pow10)
        sizes[b] = total
    return sizes


@njit(cache=True, parallel=True)
def _format_blocks(positions, collision, joints, out, starts, block, pow10, pairs):  # pragma: no cover (compiled)
    """Block b's rows as text into `out` from starts[b] on, on all cores: each value written from its last
    digit back, two digits per division."""
    rows, cols = positions.shape[0], 4 + joints.shape[1]
    hundred, ten = np.uint64(100), np.uint64(10)
    for b in prange(starts.shape[0]):
        at = starts[b]
        for r in range(b * block, min(rows, (b + 1) * block)):
            for c in range(cols):
                d, v = _scaled(positions, collision, joints, r, c)
                end = at + _width(v, d, pow10)
                if v < 0:
                    out[at] = 45  # -
                    v = -v
                u, p = np.uint64(v), end
                if d > 0:
                    for _ in range(d // 2):
                        q = u // hundred
                        two = (u - q * hundred) * np.uint64(2)
                        out[p - 1], out[p - 2] = pairs[two + np.uint64(1)], pairs[two]
                        p, u = p - 2, q
                    if d % 2:
                        q = u // ten
                        out[p - 1] = np.uint8(48 + (u - q * ten))
                        p, u = p - 1, q
                    out[p - 1] = 46  # .
                    p -= 1
                while u >= hundred:  # the integer part, at least one digit
                    q = u // hundred
                    two = (u - q * hundred) * np.uint64(2)
                    out[p - 1], out[p - 2] = pairs[two + np.uint64(1)], pairs[two]
                    p, u = p - 2, q
                if u >= ten:
                    out[p - 1], out[p - 2] = pairs[u * np.uint64(2) + np.uint64(1)], pairs[u * np.uint64(2)]
                else:
                    out[p - 1] = np.uint8(48 + u)
                out[end] = 44 if c < cols - 1 else 10  # , or newline
                at = end + 1
    return starts


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
        """The file's bytes (re-flagged on first use: one copy)."""
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
