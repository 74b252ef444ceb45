"""Box obstacles a user adds to a running scene (a box put on the UR10's table), as the world Thing takes them.

One value, three uses: the world Thing's action input (`OBSTACLE_SCHEMA`, validated before the
handler runs), a static body in the pybullet world (`build`), and a body of the robots' tdgen
scene (`scene_body`), so that the collision checks and the regenerated workspace see exactly the
box the recorder draws.
"""
from __future__ import annotations

import math
from typing import Any

import msgspec
import pybullet as pb

from devices.sim.pybullet_world import static_box
from mesh.wot import units
from tdgen.robot.surroundings import BoxBody

PREFIX = "obstacle-"  # the body name of obstacle `name` in the scene: obstacle-<name>
COLOR = (0.95, 0.45, 0.1)

_VEC3 = {"type": "array", "minItems": 3, "maxItems": 3}
OBSTACLE_SCHEMA: dict[str, Any] = {
    "type": "object", "required": ["name", "size", "position"],
    "properties": {
        "name": {"type": "string", "pattern": "^[a-z0-9-]{1,40}$", "description": "Slug naming the obstacle."},
        "size": {**_VEC3, "items": {"type": "number", "minimum": 0.01, "maximum": 3, "unit": units.METRE},
                 "description": "Full extents x, y, z (m)."},
        "position": {**_VEC3, "items": {"type": "number", "minimum": -10, "maximum": 10, "unit": units.METRE},
                     "description": "Centre in the scene frame (m; z = 0 the floor)."},
        "yaw": {"type": "number", "minimum": -180, "maximum": 180, "unit": units.DEGREE, "description": "About z."},
        "color": {**_VEC3, "items": {"type": "number", "minimum": 0, "maximum": 1, "unit": units.UNITLESS},
                  "description": "sRGB 0..1 (default orange)."},
    },
}


class Obstacle(msgspec.Struct, kw_only=True, omit_defaults=True):
    name: str
    size: tuple[float, float, float]
    position: tuple[float, float, float]
    yaw: float = 0.0
    color: tuple[float, float, float] = COLOR

    @property
    def body_name(self) -> str:
        return PREFIX + self.name


def from_input(value: object) -> Obstacle:
    """The obstacle of an `addObstacle` input (already checked against OBSTACLE_SCHEMA)."""
    return msgspec.convert(value, Obstacle)


def scene_body(obstacle: Obstacle) -> BoxBody:
    """The obstacle as a body of a tdgen scene (what robot checks and workspaces are computed with)."""
    return BoxBody(name=obstacle.body_name, size=obstacle.size, position=obstacle.position,
                   rpy=(0.0, 0.0, obstacle.yaw), rgba=(*obstacle.color, 1.0))


def build(client: int, obstacle: Obstacle) -> int:
    """The obstacle as a static box in pybullet client `client` (stepping thread); returns its body id."""
    orn = pb.getQuaternionFromEuler([0.0, 0.0, math.radians(obstacle.yaw)])
    return static_box(client, [s / 2 for s in obstacle.size], obstacle.position, orn, rgba=(*obstacle.color, 1.0))
