"""Twin-to-real calibration: the map from the twin's Cartesian frame to the real robot's (mm).

Input: a CSV of pairs measured for the same joint configuration, six columns
`twin_x,twin_y,twin_z,real_x,real_y,real_z` (a header line is optional, `#` lines are comments),
all in mm: the twin side is the twin's tool position in the robot's base frame (the frame of
tdgen's sampled points), the real side what the real robot reports. A fitted scale beyond 100 or
below 1/100 is refused as a unit or frame mixup (metres against mm, scene against base frame).
Fits, all reported with per-pair residuals:
- "two-point": per axis, `real = k*twin + b` through the two pairs farthest apart on that axis
  (the minimum the lab's procedure asks for; needs 2 pairs);
- "per-axis": the same model by least squares over all pairs (3 or more pairs);
- "affine": a least-squares 3x4 map, real = A twin + t, which also absorbs a rotation between the
  frames (4 or more pairs not all on one plane).
The map used for `--frame real` is the richest one the pairs allow, unless a model is named.
"""
from __future__ import annotations

import csv
from pathlib import Path
from typing import Literal

import msgspec
import numpy as np

Model = Literal["auto", "two-point", "per-axis", "affine"]
AXES = "xyz"


class CalibrationError(Exception):
    """Pairs that cannot give a calibration; the message says why."""


class AxisFit(msgspec.Struct):
    axis: str
    k: float
    b: float
    pairs: list[int] | None = None  # rows (0-based) the two-point fit went through


class Fit(msgspec.Struct):
    method: str
    matrix: list[list[float]]  # 3x4 [A | t]: real = A @ twin + t (A diagonal for per-axis fits)
    residuals_mm: list[float]  # |real - map(twin)| per pair
    rms_mm: float
    axes: list[AxisFit] | None = None


class Calibration(msgspec.Struct):
    twin: list[tuple[float, float, float]]
    real: list[tuple[float, float, float]]
    fits: list[Fit]
    used: str  # the method `apply` uses

    def fit(self, method: str) -> Fit:
        return next(f for f in self.fits if f.method == method)

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Twin-frame points (N, 3) or (3,) -> real frame."""
        m = np.array(self.fit(self.used).matrix)
        return np.asarray(points, dtype=float) @ m[:, :3].T + m[:, 3]

    def to_json(self) -> bytes:
        return msgspec.json.format(msgspec.json.encode(self), indent=2) + b"\n"

    def residual_table(self) -> str:
        """Per pair, the residual (mm) of every fit, the one in use marked with *; then each fit's RMS."""
        names = [f.method + ("*" if f.method == self.used else "") for f in self.fits]
        widths = [max(len(n), 10) for n in names]
        lines = ["pair  twin (mm)                     real (mm)                     "
                 + "  ".join(n.rjust(w) for n, w in zip(names, widths))]
        for k, (t, r) in enumerate(zip(self.twin, self.real)):
            cells = "  ".join(f"{f.residuals_mm[k]:{w}.3f}" for f, w in zip(self.fits, widths))
            lines.append(f"{k + 1:>4}  {_xyz(t):<28}  {_xyz(r):<28}  {cells}")
        lines.append("rms".rjust(4) + " " * 62 + "  ".join(f"{f.rms_mm:{w}.3f}" for f, w in zip(self.fits, widths)))
        return "\n".join(lines)


def _xyz(p: tuple[float, float, float]) -> str:
    return ", ".join(f"{v:.2f}" for v in p)


def read_pairs(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """(twin (N, 3), real (N, 3)) from a calibration CSV."""
    path = Path(path)
    try:
        rows = [r for r in csv.reader(path.read_text().splitlines()) if r and not r[0].lstrip().startswith("#")]
    except (OSError, UnicodeDecodeError) as exc:
        raise CalibrationError(f"{path}: cannot read it ({exc})") from None
    values = []
    for line, row in enumerate(rows, 1):
        try:
            numbers = [float(v) for v in row]
        except ValueError:
            if line == 1:
                continue  # a header
            raise CalibrationError(f"{path}: row {line} is not six numbers: {row}") from None
        if len(numbers) != 6:
            raise CalibrationError(f"{path}: row {line} has {len(numbers)} values, expected six "
                                   "(twin_x,twin_y,twin_z,real_x,real_y,real_z)")
        values.append(numbers)
    table = np.array(values).reshape(-1, 6)
    return table[:, :3], table[:, 3:]


def _fit_from_matrix(method: str, m: np.ndarray, twin: np.ndarray, real: np.ndarray,
                     axes: list[AxisFit] | None = None) -> Fit:
    residuals = np.linalg.norm(real - (twin @ m[:, :3].T + m[:, 3]), axis=1)
    return Fit(method, m.tolist(), residuals.tolist(), float(np.sqrt(np.mean(residuals ** 2))), axes)


def _per_axis_matrix(axes: list[AxisFit]) -> np.ndarray:
    m = np.zeros((3, 4))
    for i, a in enumerate(axes):
        m[i, i], m[i, 3] = a.k, a.b
    return m


def two_point(twin: np.ndarray, real: np.ndarray) -> Fit:
    """Per axis, the line through the two pairs farthest apart on that axis."""
    axes = []
    for i, name in enumerate(AXES):
        lo, hi = int(np.argmin(twin[:, i])), int(np.argmax(twin[:, i]))
        span = twin[hi, i] - twin[lo, i]
        if span == 0:
            raise CalibrationError(f"all pairs have the same twin {name} ({twin[lo, i]:g}): the {name} scale is unknown")
        k = (real[hi, i] - real[lo, i]) / span
        axes.append(AxisFit(name, float(k), float(real[lo, i] - k * twin[lo, i]), [lo, hi]))
    return _fit_from_matrix("two-point", _per_axis_matrix(axes), twin, real, axes)


def per_axis(twin: np.ndarray, real: np.ndarray) -> Fit:
    """Per axis, real = k*twin + b by least squares over all pairs."""
    axes = []
    for i, name in enumerate(AXES):
        design = np.column_stack([twin[:, i], np.ones(len(twin))])
        (k, b), *_ = np.linalg.lstsq(design, real[:, i], rcond=None)
        axes.append(AxisFit(name, float(k), float(b)))
    return _fit_from_matrix("per-axis", _per_axis_matrix(axes), twin, real, axes)


def affine(twin: np.ndarray, real: np.ndarray) -> Fit:
    """real = A twin + t by least squares (needs 4 pairs not on one plane)."""
    design = np.column_stack([twin, np.ones(len(twin))])
    if np.linalg.matrix_rank(design) < 4:
        raise CalibrationError("the twin points lie on one plane: an affine map is not determined")
    solution, *_ = np.linalg.lstsq(design, real, rcond=None)  # (4, 3)
    return _fit_from_matrix("affine", solution.T, twin, real)


MAX_SCALE = 100.0  # a calibration corrects mm-level errors; a scale this far from 1 is a unit or frame mixup


def fit_calibration(twin: np.ndarray, real: np.ndarray, model: Model = "auto") -> Calibration:
    """Every fit the pairs allow, and the one to use (`auto`: affine > per-axis > two-point)."""
    twin, real = np.asarray(twin, dtype=float), np.asarray(real, dtype=float)
    n = len(twin)
    if n < 2:
        raise CalibrationError(f"{n} pair{'s' if n != 1 else ''} given: calibration needs at least two "
                               "(twin, real) pairs, spread out on every axis")
    fits = [two_point(twin, real)]
    if n >= 3:
        fits.append(per_axis(twin, real))
    affine_error = None
    if n >= 4:
        try:
            fits.append(affine(twin, real))
        except CalibrationError as exc:
            affine_error = str(exc)
    available = [f.method for f in fits]
    used = available[-1] if model == "auto" else model
    if used not in available:
        need = {"per-axis": "3 pairs", "affine": "4 pairs not on one plane"}[used]
        raise CalibrationError(f"the {used} model needs {need}; {n} given" + (f" ({affine_error})" if affine_error else ""))
    m = np.array(next(f for f in fits if f.method == used).matrix)
    if abs(np.linalg.det(m[:, :3])) < 1e-9:
        raise CalibrationError(f"the {used} map is singular (a zero scale): the real frame would be flat")
    scales = np.linalg.svd(m[:, :3], compute_uv=False)
    if scales.max() > MAX_SCALE or scales.min() < 1 / MAX_SCALE:
        odd = scales.max() if scales.max() > MAX_SCALE else scales.min()
        raise CalibrationError(f"the {used} map scales by {odd:.4g}: the two sides are in different units (metres "
                               "against mm?) or frames. Both sides are mm; the twin side is the twin's tool in the "
                               "robot's base frame, as tdgen samples it")
    def point(p) -> tuple[float, float, float]:
        return float(p[0]), float(p[1]), float(p[2])

    return Calibration([point(p) for p in twin], [point(p) for p in real], fits, used)


def load_calibration(path: str | Path, model: Model = "auto") -> Calibration:
    """Read a pairs CSV and fit it."""
    twin, real = read_pairs(path)
    try:
        return fit_calibration(twin, real, model)
    except CalibrationError as exc:
        raise CalibrationError(f"{path}: {exc}") from None
