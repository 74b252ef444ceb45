"""The options that say which arm of a URDF to use, the same on `tdgen`, `ik` and `robot`.

`--ee` and `--base-link` pick the chain's links, `--fix-joint NAME=VALUE` holds a joint (a torso
lift) at a value in the TD's units (deg, or mm for prismatic joints), `--package-path NAME=DIR`
says where a ROS package named in `package://NAME/...` mesh URIs is (after it: ROS_PACKAGE_PATH,
AMENT_PREFIX_PATH, then pybullet's search upward from the URDF).
"""
from __future__ import annotations

import functools
from collections.abc import Callable
from pathlib import Path
from typing import Any

import click

from tdgen.robot.arm_choice import ArmChoice
from tdgen.robot.surroundings import RobotPlacement


def _pairs(option: str, values: tuple[str, ...], number: bool) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for value in values:
        name, sep, rest = value.partition("=")
        if not name or not sep or not rest:
            raise click.BadParameter(f"{value!r} is not NAME=VALUE", param_hint=option)
        if number:
            try:
                out[name] = float(rest)
            except ValueError:
                raise click.BadParameter(f"{value!r}: {rest!r} is not a number", param_hint=option) from None
        else:
            if not Path(rest).expanduser().is_dir():
                raise click.BadParameter(f"{value!r}: {rest} is not a directory", param_hint=option)
            out[name] = str(Path(rest).expanduser().resolve())
    return out


def _link_pairs(values: tuple[str, ...]) -> tuple[tuple[str, str], ...]:
    pairs = []
    for value in values:
        a, sep, b = value.partition("/")
        if not a or not sep or not b:
            raise click.BadParameter(f"{value!r} is not LINK/LINK", param_hint="--allow-collision")
        pairs.append((a, b))
    return tuple(pairs)


def arm_options(function: Callable) -> Callable:
    """Adds --ee, --base-link, --fix-joint and --package-path (below `@click.command`); the command
    function gets them as one `arm: ArmChoice`."""
    @functools.wraps(function)
    def with_arm(*args: Any, ee: str | None = None, base_link: str | None = None, fix_joint: tuple[str, ...] = (),
                 package_path: tuple[str, ...] = (), allow_collision: tuple[str, ...] = (), **kwargs: Any) -> Any:
        arm = ArmChoice(ee, base_link, _pairs("--fix-joint", fix_joint, number=True),
                        _pairs("--package-path", package_path, number=False), _link_pairs(allow_collision))
        return function(*args, arm=arm, **kwargs)

    options = [
        click.option("--ee", "--tip", "ee", metavar="LINK",
                     help="The tip link [default: where the longest arm chain ends, before gripper and finger "
                     "joints, on through fixed joints to the most distal frame, a flange or tool frame first]."),
        click.option("--base-link", help="Link the arm chain starts at [default: the URDF's root link]; joints "
                     "above it are held (at 0, or as --fix-joint says)."),
        click.option("--fix-joint", "fix_joint", multiple=True, metavar="NAME=VALUE",
                     help="Hold a joint at a value, deg (mm for a prismatic joint), instead of moving it "
                          "(repeatable; e.g. torso_lift_joint=150)."),
        click.option("--package-path", "package_path", multiple=True, metavar="NAME=DIR",
                     help="Directory of the ROS package NAME for package://NAME/... meshes (repeatable; also "
                          "ROS_PACKAGE_PATH and AMENT_PREFIX_PATH)."),
        click.option("--allow-collision", "allow_collision", multiple=True, metavar="LINK/LINK",
                     help="A link pair whose contact is no collision, as an SRDF's disabled collisions (repeatable; "
                          "for collision meshes that overlap by design, which tdgen warns about)."),
    ]
    for option in reversed(options):
        with_arm = option(with_arm)
    return with_arm


def mount_options(function: Callable) -> Callable:
    """Adds --base, --base-tilt, --base-quat and --no-surface (below `@click.command`); the command function gets
    `mount: RobotPlacement | None` (None: the scene's placement) and `surface: bool`."""
    @functools.wraps(function)
    def with_mount(*args: Any, base: tuple[float, ...] | None = None, base_tilt: tuple[float, ...] | None = None,
                   base_quat: tuple[float, ...] | None = None, no_surface: bool = False, **kwargs: Any) -> Any:
        mount = None
        if base_quat and (base_tilt or (base and base[3])):
            raise click.UsageError("--base-quat gives the whole orientation: not with --base-tilt or a --base yaw")
        if base or base_tilt or base_quat:
            x, y, z, yaw = base or (0.0, 0.0, 0.0, 0.0)
            roll, pitch = base_tilt or (0.0, 0.0)
            mount = RobotPlacement(position=(x, y, z), yaw=yaw, roll=roll, pitch=pitch)
            if base_quat:
                if abs(sum(v * v for v in base_quat)) < 1e-12:
                    raise click.BadParameter("a quaternion of length 0", param_hint="--base-quat")
                mount = RobotPlacement.from_quaternion((x, y, z), base_quat)  # type: ignore[arg-type]
        return function(*args, mount=mount, surface=not no_surface, **kwargs)

    options = [
        click.option("--base", nargs=4, type=float, metavar="X Y Z YAW",
                     help="Where the robot base stands in the scene frame: position in m, yaw about z in deg "
                          "[default: the scene's robot placement]."),
        click.option("--base-tilt", nargs=2, type=float, metavar="ROLL PITCH",
                     help="Tilt of a wall or ceiling mount, deg about x then y (fixed axes, before the yaw; "
                          "--base-tilt 180 0 hangs the arm from the ceiling)."),
        click.option("--base-quat", nargs=4, type=float, metavar="QX QY QZ QW",
                     help="The base's whole orientation as a quaternion instead of yaw and tilt."),
        click.option("--no-surface", is_flag=True,
                     help="Without --scene: the robot alone, no mounting surface (by default a floor, wall or ceiling "
                          "slab through the base, across its z axis, keeps the workspace on the reachable side)."),
    ]
    for option in reversed(options):
        with_mount = option(with_mount)
    return with_mount
