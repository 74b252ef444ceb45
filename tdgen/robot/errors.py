"""The robot library's error: a URDF (or its files) that cannot be used."""
from __future__ import annotations


class RobotError(Exception):
    """A URDF that cannot be used; the message names the file and the problem."""
