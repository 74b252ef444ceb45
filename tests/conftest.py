"""Shared fixtures; test helpers (`labs`, `tdschema`, `interop`) import from this folder."""
import sys
from pathlib import Path

import pytest

sys.path.insert(0, str(Path(__file__).parent))


@pytest.fixture(scope="session")
def ur10():
    """The UR10 written from its DH parameters (tdgen/robot/models/ur10.urdf)."""
    from tdgen.robot.model import Robot

    return Robot.load("ur10.urdf")


@pytest.fixture(scope="session")
def scene():
    """The shipped `table-and-wall` scene: a table, a wall beside it, the robot on the table."""
    from tdgen.robot.surroundings import load_scene

    return load_scene("table-and-wall")
