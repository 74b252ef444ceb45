"""The `twinmesh tdgen` and `twinmesh check` commands (mounted on the twinmesh CLI by `devices.cli.main`).

Every failure a user can cause (a missing or broken URDF, a bad scene, too few calibration pairs,
a workspace with no volume) ends as a one-line click error, never a traceback.
"""
from __future__ import annotations

from pathlib import Path
from typing import cast

import click

from mesh.cli.exits import usage_exit
from mesh.http.credentials import Auth
from mesh.messages.scene_description import DEFAULT_SAMPLES, CollisionModel
from mesh.wot.thing_description import NOSEC
from tdgen.cli.arm_options import ArmChoice, arm_options, mount_options
from tdgen.cli.counts import SampleCount
from tdgen.generate import Frame, generate
from tdgen.robot.calibration import CalibrationError, Model
from tdgen.robot.model import RobotError
from tdgen.robot.surroundings import RobotPlacement, SceneError, load_scene
from tdgen.robot.workspace import WorkspaceError
from tdgen.robot.workspace_check import DEFAULT_K, DEFAULT_MAX_PROBABILITY, DEFAULT_RADIUS_MM, Workspace
from tdgen.robot_td import slug
from tdgen.sampling import COLLISION_MODELS

USER_ERRORS = (RobotError, SceneError, CalibrationError, WorkspaceError)


SECURITY = {"nosec": NOSEC, "basic": Auth("basic", "").security(), "bearer": Auth("bearer", "").security()}


@click.command("tdgen")
@click.argument("urdf")
@click.option("--scene", help="Scene file (a tdgen scene, or a world Thing's scene.json), or a shipped scene: "
              "table-and-wall, cluttered-lab, iot-platform [default: the robot on its mounting surface].")
@click.option("--scene-robot", metavar="NAME", help="With a world's scene.json: the robot of that scene whose place "
              "this one takes (iot-platform: uarm or dobot).")
@click.option("--samples", type=SampleCount(1), default=DEFAULT_SAMPLES, show_default=True,
              help="Random joint configurations to sample.")
@click.option("--seed", type=int, default=0, show_default=True, help="Random seed (same seed, same points).")
@click.option("--out", "out_dir", type=click.Path(file_okay=False), help="Output directory [default: td-<robot>].")
@click.option("--base-url", metavar="URL", help="The Thing's URL on the HTTP adapter (http://HOST:PORT/<thing>): writes "
              "td.json, exactly the TD served there. Without it: tm.json, a Thing Model with {{BASE_URL}} open.")
@click.option("--security", type=click.Choice(["nosec", "basic", "bearer"]), default="nosec", show_default=True,
              help="The adapter's HTTP security (twinmesh up --auth), as the TD declares it.")
@click.option("--calibration", type=click.Path(dir_okay=False),
              help="CSV of twin_x,twin_y,twin_z,real_x,real_y,real_z pairs, all mm; the twin side in the robot's "
                   "base frame (where tdgen's points are).")
@click.option("--calibration-model", type=click.Choice(["auto", "two-point", "per-axis", "affine"]),
              default="auto", show_default=True, help="Calibration map to use for --frame real.")
@click.option("--frame", type=click.Choice(["twin", "real"]), default="twin", show_default=True,
              help="Frame of the TD's Cartesian data and of the artefacts (real needs --calibration).")
@click.option("--concave", is_flag=True, help="Also write an alpha shape, workspace-concave.stl.")
@click.option("--name", help="Thing name, a slug [default: the base URL's last segment, else from the robot's name].")
@click.option("--id", "thing_id", help="TD id, an absolute URI [default: urn:twinmesh:robot:<name>].")
@click.option("--workers", type=click.IntRange(min=1), help="Processes for collision checking [default: all cores].")
@click.option("--no-progress", is_flag=True, help="No progress bar.")
@click.option("--collision-model", type=click.Choice(COLLISION_MODELS), default="fast", show_default=True,
              help="fast: spheres and hull faces in compiled code, pybullet only where they cannot decide (the same "
                   "answers); exact: pybullet's contact test for every sample.")
@arm_options
@mount_options
def tdgen_command(urdf: str, scene: str | None, samples: int, seed: int, out_dir: str | None, base_url: str | None,
                  calibration: str | None, calibration_model: str, frame: str, arm: ArmChoice, concave: bool,
                  name: str | None, thing_id: str | None, workers: int | None, no_progress: bool, security: str,
                  mount: RobotPlacement | None, surface: bool, scene_robot: str | None,
                  collision_model: CollisionModel) -> None:
    """Generate a robot's Thing Description and workspace artefacts from its URDF and its scene."""
    try:
        robot = arm.load(urdf)
        surroundings = load_scene(scene, scene_robot) if scene else None
        click.echo(f"{robot.name}: {robot.describe_chain()}", err=True)
        for note in robot.notes():
            click.echo(f"{robot.name}: {note}", err=True)
        result = generate(robot, surroundings, samples, seed, Path(out_dir or f"td-{slug(robot.name)}"), base_url,
                          calibration, cast(Frame, frame), concave, progress=not no_progress, name=name,
                          thing_id=thing_id, workers=workers, calibration_model=cast(Model, calibration_model),
                          security=SECURITY[security], mount=mount, surface=surface, collision_model=collision_model)
    except (*USER_ERRORS, ValueError) as exc:
        said = str(exc)
        raise usage_exit(said if said.startswith(urdf) or str(Path(urdf).resolve()) in said.split(":")[0]
                         else f"{urdf}: {said}") from None
    low, high = result.low_mm, result.high_mm
    sampling = result.timings["sampling"]
    click.echo(f"{robot.name}: {result.samples} samples, {result.collision_free} collision-free; sampling "
               f"{sampling:.2f} s ({result.samples / max(sampling, 1e-9):,.0f} samples/s, {collision_model} collision "
               f"model), generation {result.timings.get('total', sampling):.2f} s")
    click.echo(f"workspace hull: {result.volume_mm3 / 1e9:.4f} m^3"
               + (f", alpha shape: {result.concave_volume_mm3 / 1e9:.4f} m^3"
                  if result.concave_volume_mm3 is not None else ""))
    click.echo("bounds (mm, {} frame): x {:.1f}..{:.1f}, y {:.1f}..{:.1f}, z {:.1f}..{:.1f}".format(
        result.frame, low[0], high[0], low[1], high[1], low[2], high[2]))
    if result.calibration is not None:
        click.echo(f"calibration residuals (mm; * = the {result.calibration.used} map in use):")
        click.echo(result.calibration.residual_table())
    for warning in result.warnings:
        click.echo(f"warning: {warning}", err=True)
    if concave and result.concave_volume_mm3 is None:
        click.echo("no alpha shape: the collision-free points are too few or too flat", err=True)
    for path in result.files.values():
        click.echo(f"wrote {path}")


@click.command("check", context_settings={"ignore_unknown_options": True})  # lets X Y Z be negative
@click.argument("td_dir", type=click.Path(exists=True, file_okay=False))
@click.argument("x", type=float)
@click.argument("y", type=float)
@click.argument("z", type=float)
@click.option("--k", type=click.IntRange(min=1), default=DEFAULT_K, show_default=True,
              help="Nearest sampled points the collision probability uses.")
@click.option("--radius", type=click.FloatRange(min=0, min_open=True), default=DEFAULT_RADIUS_MM, show_default=True,
              help="Only sampled points within this distance (mm) count.")
@click.option("--max-probability", type=click.FloatRange(0, 1), default=DEFAULT_MAX_PROBABILITY, show_default=True,
              help="Refuse targets more likely than this to collide.")
def check_command(td_dir: str, x: float, y: float, z: float, k: int, radius: float, max_probability: float) -> None:
    """Check a target X Y Z (mm, the TD's frame) against a generated TD directory.

    Exit code 0 when the robot may move there, 1 when the move is refused (the reason is printed).
    """
    try:
        workspace = Workspace.load(td_dir)
    except (OSError, ValueError, WorkspaceError) as exc:
        raise usage_exit(str(exc)) from None
    result = workspace.check((x, y, z), k=k, radius=radius, max_probability=max_probability)
    click.echo(f"{'OK' if result.ok else 'REFUSED'}: {result.reason} (target {x:g}, {y:g}, {z:g} mm)")
    if not result.ok:
        raise click.exceptions.Exit(1)
