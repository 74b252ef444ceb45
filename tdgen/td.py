"""Assemble a robot's Thing Description (SPEC §4) from its joints and its sampled workspace.

Built on the mesh's TD model (`mesh.td`), so what tdgen writes is what the mesh serves. Forms are
HTTP-style and relative (`properties/getJointposition`); `base` is set when a base URL is given, and
the HTTP adapter rewrites forms to its own address anyway.
"""
from __future__ import annotations

import re

import numpy as np

from mesh.td import (JSON, ActionAffordance, DataSchema, Form, Link, PropertyAffordance,
                     ThingDescription)
from tdgen.robot import Robot

CONTEXT = ["https://www.w3.org/2019/wot/td/v1", "https://www.w3.org/2022/wot/td/v1.1"]
ARTEFACTS = {  # file name -> (rel, media type)
    "workspace.stl": ("workspace", "model/stl"),
    "points.csv": ("dataset-points", "text/csv"),
    "scene.json": ("scene", "application/json"),
}


def robot_id(name: str) -> str:
    """A stable absolute URI for a robot: `urn:twinmesh:robot:<name>`."""
    return "urn:twinmesh:robot:" + (re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-") or "robot")


def _number(unit: str, low: float, high: float) -> DataSchema:
    return DataSchema(type="number", unit=unit, minimum=round(float(low), 6), maximum=round(float(high), 6))


def joint_schema(robot: Robot) -> DataSchema:
    """One number per main joint: deg (revolute, continuous) or mm (prismatic), within the limits."""
    lows, highs = robot.to_user_units(robot.lows()), robot.to_user_units(robot.highs())
    fields = {j.name: _number("mm" if j.type == "prismatic" else "deg", lo, hi)
              for j, lo, hi in zip(robot.joints, lows, highs)}
    return DataSchema(type="object", properties=fields, required=list(fields))


def cartesian_schema(low: np.ndarray, high: np.ndarray) -> DataSchema:
    """x, y, z in mm within the bounds of the collision-free points."""
    fields = {axis: _number("mm", lo, hi) for axis, lo, hi in zip("xyz", low, high)}
    return DataSchema(type="object", properties=fields, required=list(fields))


def _property(schema: DataSchema, name: str, description: str) -> PropertyAffordance:
    href = f"properties/{name}"
    return PropertyAffordance(
        type=schema.type, properties=schema.properties, required=schema.required, description=description,
        readOnly=True, observable=True,
        forms=[Form(href=href, op="readproperty", contentType=JSON),
               Form(href=href, op=["observeproperty", "unobserveproperty"], contentType=JSON,
                    subprotocol="longpoll")])


def _action(schema: DataSchema, name: str, description: str) -> ActionAffordance:
    return ActionAffordance(input=schema, description=description, synchronous=True,
                            forms=[Form(href=f"actions/{name}", op="invokeaction", contentType=JSON)])


FRAMES = {"twin": "the robot's base frame", "real": "the real robot's frame (calibrated)"}


def build_td(robot: Robot, low: np.ndarray, high: np.ndarray, *, frame: str = "twin", title: str | None = None,
             thing_id: str | None = None, description: str = "", base_url: str | None = None) -> dict:
    """The TD as a JSON-ready dict; `low`/`high` are the collision-free bounds (mm, in `frame`)."""
    joints, cartesian = joint_schema(robot), cartesian_schema(low, high)
    td = ThingDescription(
        title=title or robot.name,
        context=list(CONTEXT),
        id=thing_id or robot_id(robot.name),
        description=description or None,
        base=base_url,
        properties={
            "getJointposition": _property(joints, "getJointposition", "Joint values: deg for revolute joints, "
                                          "mm for prismatic ones."),
            "getCartesianposition": _property(cartesian, "getCartesianposition",
                                              f"End-effector position (mm) in {FRAMES[frame]}."),
        },
        actions={
            "moveToJointPosition": _action(joints, "moveToJointPosition", "Move to these joint values; "
                                           "returns when the motion has finished."),
            "moveToCartesianPosition": _action(cartesian, "moveToCartesianPosition",
                                               "Move the end effector to this position (mm); refused outside the "
                                               "workspace or where a collision is likely."),
        },
        links=[Link(href=name, rel=rel, type=media) for name, (rel, media) in ARTEFACTS.items()],
    )
    return td.to_dict()
