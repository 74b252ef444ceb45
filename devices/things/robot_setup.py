"""One robot process's configuration, typed once: from `twinmesh robot`'s options (or a scene) to the
process entry (devices.lab.robot_process), its twin and the TwinDescription the generation gets."""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from mesh.messages.scene_description import DEFAULT_SAMPLES, CollisionModel
from tdgen.robot.arm_choice import ArmChoice

if TYPE_CHECKING:
    from tdgen.robot.surroundings import RobotPlacement


@dataclass(frozen=True)
class RobotSetup:
    """A robot arm from its URDF as a Thing: which arm, where it stands, how its workspace is sampled,
    how its moves are checked and planned."""

    urdf: str                                 # a path, a shipped name (ur10.urdf) or a pybullet_data path
    arm: ArmChoice = field(default_factory=ArmChoice)
    name: str | None = None                   # the Thing's name (None: a slug of the URDF's robot name)
    scene: str | None = None                  # a scene file or shipped scene (None: the robot on its mounting surface)
    scene_robot: str | None = None            # with a world's scene.json: the robot whose place this one takes
    mount: RobotPlacement | None = None       # where the base stands in the scene frame (None: the scene's placement)
    surface: bool = True                      # without a scene: a mounting surface through the base
    samples: int = DEFAULT_SAMPLES            # random configurations the workspace is sampled with
    seed: int = 0
    calibration: str | None = None            # twin-to-real pairs CSV: TD, checks and moves in the real frame
    max_collision_probability: float | None = None  # refuse targets whose sampled neighbours collide more often
    speed: float | None = 1.0                 # simulation speed factor (None: as fast as the CPU allows)
    planning_budget: float = 1.0              # s a move may plan before it is refused
    collision_model: CollisionModel = "fast"  # what decides collisions for samples, target checks and planning
