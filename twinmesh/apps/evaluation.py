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
from typing import Any, Iterable, Protocol

import click

from twinmesh.fabric.client import NOTHING
from twinmesh.wot.problem import Problem

MOVE, WHERE, JOINTS = "moveToCartesianPosition", "getCartesianposition", "getJointposition"


class Consumer(Protocol):
    def read(self, thing: str, prop: str) -> Any: ...
    def invoke(self, thing: str, action: str, input: Any = NOTHING) -> Any: ...


@dataclass
class IkRow:
    target: tuple[float, float, float]
    status: str                               # reached | refused
    reached: tuple[float, float, float] | None
    error_mm: float | None
    reason: str = ""
    detail: str = ""
    joints: dict[str, float] = field(default_factory=dict)


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
                raise click.BadParameter(f"{path}: row {n} does not start with three numbers: {row}") from None
            targets.append((x, y, z))
    if not targets:
        raise click.BadParameter(f"{path}: no target in it")
    return targets


def evaluate_ik(c: Consumer, thing: str, targets: Iterable[tuple[float, float, float]]) -> list[IkRow]:
    """One row per target, in order (pass a progress-reporting iterable to show progress)."""
    rows = []
    for target in targets:
        status, reason, detail = "reached", "", ""
        try:
            c.invoke(thing, MOVE, dict(zip("xyz", target)))
        except Problem as p:
            if p.status >= 500 and p.status != 503:
                raise
            status, reason, detail = "refused", p.reason or p.slug, p.detail
        if status == "refused":  # nothing moved: the pose is the previous target's, not this one's
            rows.append(IkRow(target, status, None, None, reason, detail))
            continue
        where = c.read(thing, WHERE)
        reached = (float(where["x"]), float(where["y"]), float(where["z"]))
        rows.append(IkRow(target, status, reached, math.dist(reached, target), reason, detail, c.read(thing, JOINTS)))
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


# --- consumers ------------------------------------------------------------------------------------
class HttpThings:
    """A minimal WoT HTTP consumer for Things whose TDs are at `{base}/{thing}` (the adapter's layout):
    readproperty and invokeaction through the TDs' forms; problem+json errors become Problems."""

    def __init__(self, base: str, action_timeout: float = 300.0):
        import httpx

        self.base = base.rstrip("/")
        self.http = httpx.Client(timeout=httpx.Timeout(10.0))
        self.action_timeout = action_timeout
        self._tds: dict[str, dict] = {}

    def close(self) -> None:
        self.http.close()

    def _check(self, r) -> Any:
        if r.status_code >= 300:
            if r.headers.get("content-type", "").startswith("application/problem+json"):
                raise Problem.from_json(r.content)
            raise Problem(f"{r.request.method} {r.request.url}: HTTP {r.status_code} {r.text[:200]}",
                          status=r.status_code)
        return r.json() if r.content else None

    def href(self, thing: str, kind: str, name: str, op: str) -> str:
        if thing not in self._tds:
            self._tds[thing] = self._check(self.http.get(f"{self.base}/{thing}"))
        for form in self._tds[thing].get(kind, {}).get(name, {}).get("forms", []):
            ops = form.get("op", [])
            if op in ([ops] if isinstance(ops, str) else ops):
                return form["href"]
        raise Problem(f"{thing} has no {op} form for {name!r}", status=404)

    def read(self, thing: str, prop: str) -> Any:
        url = self.href(thing, "properties", prop, "readproperty")
        return self._check(self.http.get(url, headers={"Accept": "application/json"}))

    def invoke(self, thing: str, action: str, input: Any = NOTHING) -> Any:
        url = self.href(thing, "actions", action, "invokeaction")
        kwargs: dict[str, Any] = {"timeout": self.action_timeout}
        if input is not NOTHING:
            kwargs["json"] = input
        return self._check(self.http.post(url, **kwargs))
