"""`twinmesh ik`: joint values for a Cartesian target (or a CSV of them), in the units of the TD.

Coordinates are mm in the robot's base frame; joint values are printed in deg (revolute) and
mm (prismatic). A CSV of targets is solved row by row, each row seeded with the previous
solution, so a path of nearby targets gives a continuous joint path.
"""
from __future__ import annotations

import csv
import io
import math
import sys
import time
from pathlib import Path

import click
import numpy as np
from tqdm import tqdm

from mesh.cli.exits import usage_exit
from tdgen.cli.arm_options import ArmChoice, arm_options
from tdgen.robot import ik
from tdgen.robot.kinematics import ForwardKinematics
from tdgen.robot.model import RobotError
from tdgen.robot.pose_ik import solve_pose


def _load(urdf: str, arm: ArmChoice) -> ForwardKinematics:
    try:
        return ForwardKinematics(arm.load(urdf))
    except RobotError as exc:
        raise usage_exit(str(exc)) from None


def _seed(fk: ForwardKinematics, text: str | None) -> np.ndarray | None:
    if text is None:
        return None
    try:
        values = [float(v) for v in text.split(",")]
    except ValueError:
        raise usage_exit(f"--seed: expected comma-separated numbers, got {text!r}") from None
    if len(values) != fk.n:
        raise usage_exit(f"--seed: {fk.robot.name} has {fk.n} main joints, got {len(values)} values")
    return fk.robot.from_user_units(np.array(values))


def _read_targets(path: Path) -> np.ndarray:
    """x,y,z rows in mm; a first row that is not numeric is a header; blank lines are skipped."""
    try:
        text = path.read_text()
    except OSError as exc:
        raise usage_exit(f"{path}: cannot read targets ({exc.strerror})") from None
    rows = []
    for line_no, row in enumerate(csv.reader(io.StringIO(text)), start=1):
        if not row or not "".join(row).strip():
            continue
        try:
            if len(row) != 3:
                raise ValueError
            rows.append([float(v) for v in row])
        except ValueError:
            if line_no == 1:
                continue
            raise usage_exit(f"{path} line {line_no}: expected x,y,z in mm, got {','.join(row)!r}") from None
    if not rows:
        raise usage_exit(f"{path}: no targets")
    return np.array(rows)


def _fmt(xyz) -> str:
    return "(" + ", ".join(f"{v:.3f}" for v in xyz) + ")"


@click.command("ik", context_settings={"ignore_unknown_options": True})
@click.argument("urdf")
@click.argument("xyz", nargs=-1, type=float, metavar="[X Y Z]")
@click.option("--targets", "targets_csv", type=click.Path(dir_okay=False, path_type=Path),
              help="CSV of targets (x,y,z in mm, header optional) instead of X Y Z.")
@click.option("--out", type=click.Path(dir_okay=False, path_type=Path),
              help="Where to write the solutions of --targets [default: stdout].")
@click.option("--seed", metavar="J1,J2,...", help="Starting joint values (deg/mm), e.g. the current pose.")
@click.option("--tol", type=float, default=ik.TOL_M * 1000, show_default=True, help="Tolerance in mm.")
@click.option("--rpy", nargs=3, type=float, metavar="ROLL PITCH YAW",
              help="Also the tip's orientation, deg about the base frame's fixed x, y, z axes (as a URDF's rpy); "
                   "solved within --tol and 0.01 deg.")
@arm_options
def ik_command(urdf: str, xyz: tuple[float, ...], targets_csv: Path | None, out: Path | None,
               arm: ArmChoice, seed: str | None, tol: float, rpy: tuple[float, float, float] | None) -> None:
    """Inverse kinematics for URDF: X Y Z in mm (robot base frame), or --targets CSV.

    URDF may be a path, a robot shipped with tdgen (ur10.urdf) or one of pybullet_data
    (franka_panda/panda.urdf). Exits non-zero when the single target is unreachable.
    """
    if (targets_csv is None) == (len(xyz) == 0):
        raise click.UsageError("give either X Y Z or --targets CSV")
    if targets_csv is None and len(xyz) != 3:
        raise click.UsageError(f"expected X Y Z (three numbers in mm), got {len(xyz)}")
    fk = _load(urdf, arm)
    q0 = _seed(fk, seed)
    if targets_csv is not None:
        if rpy:
            raise click.UsageError("--rpy is for one X Y Z target")
        _solve_csv(fk, _read_targets(targets_csv), out, q0, tol / 1000)
        return
    if rpy:
        _solve_pose(fk, xyz, rpy, q0, tol)
        return
    res = ik.solve(fk, np.array(xyz) / 1000, seed=q0, tol=tol / 1000, rng=0)
    if not res.ok:
        raise click.ClickException(
            f"target {_fmt(xyz)} mm is not reachable by {fk.robot.name} (ee {fk.robot.ee_link}): the closest "
            f"point found is {_fmt(res.reached_m * 1000)} mm, {res.error_m * 1000:.3f} mm away")
    robot = fk.robot
    click.echo(f"{robot.name} ({robot.ee_link}) reaches {_fmt(xyz)} mm with:")
    for joint, value in zip(robot.joints, robot.to_user_units(res.q)):
        click.echo(f"  {joint.name:24} {value:12.4f} {'mm' if joint.type == 'prismatic' else 'deg'}")
    click.echo(f"reached {_fmt(res.reached_m * 1000)} mm, error {res.error_m * 1000:.6f} mm")


def _solve_pose(fk: ForwardKinematics, xyz: tuple[float, ...], rpy: tuple[float, float, float],
                q0: np.ndarray | None, tol: float) -> None:
    res = solve_pose(fk, np.array(xyz) / 1000, rpy, seed=q0, tol_m=tol / 1000, rng=0)
    robot = fk.robot
    pose = f"{_fmt(xyz)} mm, roll/pitch/yaw ({', '.join(f'{a:g}' for a in rpy)}) deg"
    if not res.ok:
        raise click.ClickException(f"pose {pose} is not reachable by {robot.name} (ee {robot.ee_link}): the closest "
                                   f"found is {res.error_m * 1000:.3f} mm and {math.degrees(res.error_rad):.3f} deg away")
    click.echo(f"{robot.name} ({robot.ee_link}) reaches {pose} with:")
    for joint, value in zip(robot.joints, robot.to_user_units(res.q)):
        click.echo(f"  {joint.name:24} {value:12.4f} {'mm' if joint.type == 'prismatic' else 'deg'}")
    click.echo(f"reached {_fmt(res.position_m * 1000)} mm, error {res.error_m * 1000:.6f} mm and "
               f"{math.degrees(res.error_rad):.6f} deg")


def _solve_csv(fk: ForwardKinematics, targets_mm: np.ndarray, out: Path | None,
               q0: np.ndarray | None, tol_m: float) -> None:
    robot, rng = fk.robot, np.random.default_rng(0)
    rows, times, solved = [], [], 0
    for target in tqdm(targets_mm, unit="targets", file=sys.stderr, disable=not sys.stderr.isatty()):
        t0 = time.perf_counter()
        res = ik.solve(fk, target / 1000, seed=q0, tol=tol_m, rng=rng)
        times.append(time.perf_counter() - t0)
        solved += res.ok
        if res.ok:
            q0 = res.q
        rows.append([*target, *(res.reached_m * 1000), res.error_m * 1000, *robot.to_user_units(res.q)])
    header = ["x", "y", "z", "reached_x", "reached_y", "reached_z", "error_mm", *(j.name for j in robot.joints)]
    try:
        with click.open_file(str(out) if out else "-", "w") as sink:
            writer = csv.writer(sink, lineterminator="\n")
            writer.writerow(header)
            writer.writerows([[f"{v:.6f}" for v in row] for row in rows])
    except OSError as exc:
        raise usage_exit(f"{out}: cannot write ({exc.strerror})") from None
    n = len(targets_mm)
    click.echo(f"solved {solved}/{n} ({solved / n:.2%}) within {tol_m * 1000:g} mm; "
               f"median {np.median(times) * 1000:.2f} ms per target", err=True)
