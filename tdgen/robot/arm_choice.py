"""Which arm of a URDF to use: the tip, the chain's first link, held joints, package folders, allowed contacts.

The same choice is made on `tdgen`, `ik` and `robot` (tdgen/cli/arm_options.py turns their options into
it) and travels with a robot process's setup to its twin.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from tdgen.robot.model import Robot


@dataclass(frozen=True)
class ArmChoice:
    """What the options chose; `load` reads the URDF with it."""

    ee: str | None = None
    base_link: str | None = None
    fixed: dict[str, float] = field(default_factory=dict)     # deg or mm
    packages: dict[str, str] = field(default_factory=dict)    # ROS package name -> directory
    allowed_collisions: tuple[tuple[str, str], ...] = ()      # link pairs whose contact does not count

    def load(self, urdf: str | Path) -> Robot:
        from tdgen.robot.model import Robot

        return Robot.load(urdf, ee=self.ee, base_link=self.base_link, fixed=self.fixed,
                          packages={k: Path(v) for k, v in self.packages.items()},
                          allowed_collisions=self.allowed_collisions)
