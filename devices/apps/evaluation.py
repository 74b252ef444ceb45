"""`twinmesh eval`: measure a running lab's robots by their affordances (over Zenoh or WoT HTTP).

`twinmesh eval ik --thing NAME --targets CSV [--via URL] [--out CSV]` drives a robot Thing to each
target (mm, in its TD's frame) with `moveToCartesianPosition`, then reads `getCartesianposition` and
`getJointposition`, and writes one row per target: the target, `reached` or `refused`, where the end
effector is, the error (mm) and the joint values (reached targets only: a refused target leaves
those columns empty, since nothing moved), the refusal reason; then the mean and max error. Only
the affordance names of SPEC §4 are used, so the same command measures any robot Thing that has
them, twin or not.
"""
from __future__ import annotations

import csv
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterable

from mesh import Consumer
from mesh.wot.problem import Problem

MOVE, WHERE, JOINTS = "moveToCartesianPosition", "getCartesianposition", "getJointposition"



@dataclass
class IkRow:
    target: tuple[float, float, float]
    status: str                               # reached | refused
    reached: tuple[float, float, float] | None
    error_mm: float | None
    reason: str = ""
    detail: str = ""
    joints: dict[str, float] = field(default_factory=dict)


class TargetsError(ValueError):
    """A targets file that cannot be used; the message names the file and the row."""


def read_targets(path: str | Path) -> list[tuple[float, float, float]]:
    """x,y,z (mm) per row; a header line and `#` comments are skipped; extra columns are ignored."""
    targets: list[tuple[float, float, float]] = []
    with open(path, newline="") as f:
        for n, row in enumerate(csv.reader(f), 1):
            if not row or row[0].lstrip().startswith("#"):
                continue
            try:
                x, y, z = (float(v) for v in row[:3])
            except ValueError:
                if not targets and n == 1:
                    continue  # a header
                raise TargetsError(f"{path}: row {n} does not start with three numbers: {row}") from None
            targets.append((x, y, z))
    if not targets:
        raise TargetsError(f"{path}: no target in it")
    return targets


def evaluate_ik(c: Consumer, thing: str, targets: Iterable[tuple[float, float, float]]) -> list[IkRow]:
    """One row per target, in order (pass a progress-reporting iterable to show progress)."""
    rows = []
    robot = c.thing(thing)
    for target in targets:
        status, reason, detail = "reached", "", ""
        try:
            robot.invoke_action(MOVE, dict(zip("xyz", target)))
        except Problem as p:
            if p.status >= 500 and p.status != 503:
                raise
            status, reason, detail = "refused", p.reason or p.slug, p.detail
        if status == "refused":  # nothing moved: the pose is the previous target's, not this one's
            rows.append(IkRow(target, status, None, None, reason, detail))
            continue
        where = robot.read_property(WHERE)
        reached = (float(where["x"]), float(where["y"]), float(where["z"]))
        rows.append(IkRow(target, status, reached, math.dist(reached, target), reason, detail, robot.read_property(JOINTS)))
    return rows


def write_table(rows: list[IkRow], out) -> None:
    joints = next((list(r.joints) for r in rows if r.joints), [])
    w = csv.writer(out)
    w.writerow(["target_x", "target_y", "target_z", "status", "reached_x", "reached_y", "reached_z", "error_mm",
                "reason", *joints])
    for r in rows:
        reached = [f"{v:.4f}" for v in r.reached] if r.reached else ["", "", ""]
        w.writerow([*(f"{v:g}" for v in r.target), r.status, *reached,
                    "" if r.error_mm is None else f"{r.error_mm:.6f}", r.reason,
                    *(f"{r.joints[j]:.6f}" if j in r.joints else "" for j in joints)])


def summary(rows: list[IkRow]) -> str:
    errors = [r.error_mm for r in rows if r.error_mm is not None]
    refused = [r for r in rows if r.status == "refused"]
    text = f"{len(rows)} targets: {len(errors)} reached, {len(refused)} refused"
    if errors:
        text += f"; error mean {sum(errors) / len(errors):.6f} mm, max {max(errors):.6f} mm"
    reasons: dict[str, int] = {}
    for r in refused:
        reasons[r.reason] = reasons.get(r.reason, 0) + 1
    if reasons:
        text += " (" + ", ".join(f"{n} {reason}" for reason, n in sorted(reasons.items())) + ")"
    return text
