"""The robot library's errors: a URDF (or its files), or a scene (or its files), that cannot be used."""
from __future__ import annotations


class RobotError(Exception):
    """A URDF that cannot be used; the message names the file and the problem."""


class SceneError(Exception):
    """A scene file that cannot be used; the message names the file and the problem."""
