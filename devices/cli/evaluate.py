"""`twinmesh eval`: measure a running lab's robots through their affordances."""
from __future__ import annotations

import io
import sys

import click
from tqdm import tqdm

from devices.apps.evaluation import TargetsError, evaluate_ik, read_targets, summary, write_table
from mesh.cli.consumers import consumer_for
from mesh.cli.exits import problem_exit
from mesh.wot.problem import Problem


# --- the command ----------------------------------------------------------------------------------
@click.group("eval")
def eval_command() -> None:
    """Measure a running lab's robots through their affordances."""


@eval_command.command("ik")
@click.option("--thing", required=True, help="The robot Thing.")
@click.option("--targets", required=True, type=click.Path(exists=True, dir_okay=False),
              help="CSV of targets x,y,z (mm, the robot TD's frame); a header line is allowed.")
@click.option("--via", metavar="URL", help="Use the WoT HTTP Things at URL (e.g. the adapter, http://127.0.0.1:8080) "
              "instead of Zenoh.")
@click.option("--auth", envvar="TWINMESH_HTTP_AUTH", metavar="SCHEME:CREDENTIALS",
              help="With --via: bearer:TOKEN or basic:USER:PASS.")
@click.option("--out", type=click.Path(dir_okay=False), help="Write the table to this CSV [default: stdout].")
@click.pass_obj
def ik_command(settings, thing: str, targets: str, via: str | None, auth: str | None, out: str | None) -> None:
    """Move a robot to each target with moveToCartesianPosition and measure where it got to."""
    try:
        points = read_targets(targets)
    except TargetsError as e:
        raise click.BadParameter(str(e), param_hint="--targets") from None
    with consumer_for(settings, via, auth) as c:
        try:
            rows = evaluate_ik(c, thing, tqdm(points, unit="targets", file=sys.stderr, disable=not sys.stderr.isatty()))
        except Problem as p:
            raise problem_exit(p) from None
    if out:
        with open(out, "w", newline="") as f:
            write_table(rows, f)
    else:
        buf = io.StringIO()
        write_table(rows, buf)
        sys.stdout.write(buf.getvalue())
    click.echo(summary(rows), err=bool(not out))
