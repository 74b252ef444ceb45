"""`twinmesh scene show FILE`: what a scene holds, as tdgen and the lab will use it.

Each body with what it was made into (a scan's points kept, voxels and boxes; a mesh's hulls or its
surface's triangles), its bounding box in the scene frame as pybullet holds it, and how long the
scene took to load (a scan or mesh read and prepared, or taken from the cache).
"""
from __future__ import annotations

import time

import click

from mesh.cli.exits import usage_exit
from tdgen.robot.surroundings import FileBody, SceneError, build_into, load_scene, prepare


@click.group("scene")
def scene_group() -> None:
    """Scene files: the static surroundings a robot stands in."""


@scene_group.command("show")
@click.argument("scene")
@click.option("--scene-robot", default=None, metavar="NAME",
              help="For a world's scene.json: the robot that stands in it.")
def show_command(scene: str, scene_robot: str | None) -> None:
    """Print each body of SCENE (a file or a shipped scene's name): its kind, what a scan or a mesh was
    made into, its bounding box (m, scene frame), and the load time."""
    import pybullet as pb

    start = time.perf_counter()
    try:
        loaded = load_scene(scene, scene_robot)
    except SceneError as exc:
        raise usage_exit(str(exc)) from None
    seconds = time.perf_counter() - start
    client = pb.connect(pb.DIRECT)
    try:
        ids = build_into(loaded, client)
        boxes = [_aabb(pb, client, i) for i in ids]
    finally:
        pb.disconnect(client)
    r = loaded.robot
    click.echo(f"{loaded.name}: {len(loaded.bodies)} bodies; robot at {_vec(r.position)} m, "
               f"rpy {_vec(r.rpy)} deg; loaded in {seconds:.2f} s")
    for k, (body, (lo, hi)) in enumerate(zip(loaded.bodies, boxes)):
        kind = type(body).__struct_config__.tag
        what = ""
        if isinstance(body, FileBody):
            made = prepare(body)
            counts = ", ".join(f"{v:,} {n}" for n, v in made.stats.items())
            what = f" {made.kind} ({counts}) from {body.file}{' [cached]' if made.cached else ''}"
        click.echo(f"  {body.name or f'body {k}'}: {kind}{what}; box {_vec(lo)} .. {_vec(hi)} m")


def _aabb(pb, client: int, body: int) -> tuple[list[float], list[float]]:
    links = range(-1, pb.getNumJoints(body, physicsClientId=client))
    boxes = [pb.getAABB(body, link, physicsClientId=client) for link in links]
    return ([min(b[0][k] for b in boxes) for k in range(3)], [max(b[1][k] for b in boxes) for k in range(3)])


def _vec(v) -> str:
    return "(" + ", ".join(f"{x:.3f}" for x in v) + ")"
