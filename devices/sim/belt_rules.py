"""A conveyor belt's rules as the real lab's TD states them (speeds, event texts), without a physics world:
the fleet's belts (devices.sim.stations) follow them in processes that load no pybullet."""
from __future__ import annotations

from mesh.wot.problem import BadInput

MAX_SPEED_MM_S = 60.0  # surface speed at 100 %
DEFAULT_SPEED = 100
STARTED = "Conveyor belt started"
STOPPED = "Conveyor belt stopped"


def belt_speed(belt: str, value: object) -> int:
    """A belt's speed as the real lab's TD allows it: an integer from 1 to 100 (%)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or value != int(value) or not 1 <= value <= 100:
        raise BadInput(f"{belt}: speed must be an integer from 1 to 100 (%), got {value!r}")
    return int(value)
