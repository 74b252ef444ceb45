"""`twinmesh workflow`: the lab's workflows against a running lab, over Zenoh or WoT HTTP."""
from __future__ import annotations

import click

from devices.apps.cube_workflow import SENSOR_TIMEOUT, Step, StepFailed, cube_workflow
from mesh.cli.consumers import consumer_for


# --- the commands ----------------------------------------------------------------------------------
@click.group("workflow")
def workflow_command() -> None:
    """Run the lab's workflows against a running lab (by affordance name only)."""


@workflow_command.command("cube")
@click.option("--via", metavar="URL", help="Use the WoT HTTP Things at URL (e.g. the adapter, "
              "http://127.0.0.1:8080) instead of Zenoh.")
@click.option("--auth", envvar="TWINMESH_HTTP_AUTH", metavar="SCHEME:CREDENTIALS",
              help="With --via: bearer:TOKEN or basic:USER:PASS.")
@click.option("--runs", default=1, show_default=True, type=click.IntRange(1), help="Run the workflow this many times.")
@click.option("--sensor-timeout", default=SENSOR_TIMEOUT, show_default=True, type=click.FloatRange(min=0.1),
              help="Seconds a belt may run before the cube counts as lost.")
@click.pass_obj
def cube_command(settings, via: str | None, auth: str | None, runs: int, sensor_timeout: float) -> None:
    """The lab's cube workflow: dobot getCube, belt 2 to infrared sensor 2, uarm picks the cube, shows it to
    the colour sensor and puts it on belt 1, belt 1 to infrared sensor 1, dobot returnCube."""
    with consumer_for(settings, via, auth) as consumer:
        for n in range(1, runs + 1):
            if runs > 1:
                click.echo(f"run {n} of {runs}")
            try:
                run = cube_workflow(consumer, _print_step, sensor_timeout)
            except StepFailed as e:
                click.echo(f"  {e.step.number}. {e.step.title}: FAILED after {e.step.seconds:.2f} s", err=True)
                raise click.ClickException(str(e)) from None
            click.echo(f"cube workflow done in {run.seconds:.2f} s: the cube is {run.color_name} {run.color}")


def _print_step(s: Step) -> None:
    click.echo(f"  {s.number}. {s.title}: {s.seconds:.2f} s" + (f" -- {s.detail}" if s.detail else ""))
