"""Assemble a robot's Thing Description (SPEC §4) from its joints and its sampled workspace.

Built on the mesh's TD model (`twinmesh.wot.td`), so what tdgen writes is what the mesh serves. Forms are
HTTP-style and relative (`properties/getJointposition`); `base` is set when a base URL is given, and
the HTTP adapter rewrites forms to its own address anyway.
"""
from __future__ import annotations

import re

import numpy as np

from twinmesh.robot.model import Robot
from twinmesh.wot.td import JSON, ActionAffordance, DataSchema, Form, Link, PropertyAffordance, ThingDescription

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


def _action(schema: DataSchema | None, name: str, description: str, output: DataSchema | None = None,
            safe: bool | None = None) -> ActionAffordance:
    return ActionAffordance(input=schema, output=output, description=description, synchronous=True, safe=safe,
                            forms=[Form(href=f"actions/{name}", op="invokeaction", contentType=JSON)])


def _numbers(unit: str | None = None) -> DataSchema:
    return DataSchema(type="array", items=DataSchema(type="number", unit=unit))


def move_output_schema(robot: Robot) -> DataSchema:
    """What a move (or its dry run) answers: the collision-free path, where it ends, how it was found."""
    xyz = {axis: DataSchema(type="number", unit="mm") for axis in "xyz"}
    names = [j.name for j in robot.joints]
    return DataSchema(type="object", required=["path", "reached", "error_mm", "method", "planning_ms"], properties={
        "path": DataSchema(type="object", required=["joints", "points", "times"], description=(
            "Joint-space waypoints from where the arm was (first) to where it ends (last), each in the joint "
            f"order of `joints` ({', '.join(names)}; deg for revolute, mm for prismatic joints); `times` in "
            "simulated seconds from the start. The arm stops at every waypoint."), properties={
            "joints": DataSchema(type="array", items=DataSchema(type="string", enum=names)),
            "points": DataSchema(type="array", items=_numbers()),
            "times": _numbers("s"),
            "tip": DataSchema(type="array", items=_numbers("mm"), description=(
                "The end effector along the path (mm, the TD's frame), several points per segment: what "
                "the move sweeps, for drawing."))}),
        "reached": DataSchema(type="object", properties=xyz, required=list(xyz),
                              description="Where the end effector ends (mm, the TD's frame)."),
        "error_mm": DataSchema(type="number", unit="mm", minimum=0.0,
                               description="Distance from the Cartesian target (0 for joint moves)."),
        "method": DataSchema(type="string", enum=["straight", "planned"],
                             description="straight: the direct joint-space path was free; planned: by OMPL."),
        "planning_ms": DataSchema(type="number", unit="ms", minimum=0.0),
        "collision_probability": DataSchema(type="number", minimum=0.0, maximum=1.0, description=(
            "Share of colliding samples among the target's nearest sampled points (information; Cartesian "
            "targets with sampled neighbours only)."))})


def plan_input_schema(joints: DataSchema, cartesian: DataSchema) -> DataSchema:
    """Either a Cartesian target (x, y, z) or `joints` (the joint move's input)."""
    return DataSchema(type="object", description="Either x, y, z (mm) or joints, as the move actions take them.",
                      properties={**(cartesian.properties or {}), "joints": joints})


FRAMES = {"twin": "the robot's base frame", "real": "the real robot's frame (calibrated)"}


def build_td(robot: Robot, low: np.ndarray, high: np.ndarray, *, frame: str = "twin", title: str | None = None,
             thing_id: str | None = None, description: str = "", base_url: str | None = None) -> dict:
    """The TD as a JSON-ready dict; `low`/`high` are the collision-free bounds (mm, in `frame`)."""
    joints, cartesian = joint_schema(robot), cartesian_schema(low, high)
    output = move_output_schema(robot)
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
            "moveToJointPosition": _action(joints, "moveToJointPosition", "Move to these joint values along a "
                                           "collision-free path; returns when the motion has finished, with the "
                                           "path. Refused (422, nothing moves) where the goal collides "
                                           "(`collision`) or no path is found (`no-path`).", output),
            "moveToCartesianPosition": _action(cartesian, "moveToCartesianPosition",
                                               "Move the end effector to this position (mm) along a collision-free "
                                               "path; returns when the motion has finished, with the path. Refused "
                                               "(422, nothing moves) outside the workspace (`outside-workspace`), "
                                               "where no joint configuration reaches (`unreachable`), where every "
                                               "one found collides (`collision`) or no path is found (`no-path`).",
                                               output),
            "planMove": _action(plan_input_schema(joints, cartesian), "planMove",
                                "A dry run: answers exactly as the move would (path or refusal), from where the "
                                "arm stands now, without moving.", output, safe=True),
            "stop": _action(None, "stop", "Halt a move under way where the arm is (the move answers 409 "
                            "move-stopped); `stopped` says whether one was under way.",
                            DataSchema(type="object", required=["stopped"],
                                       properties={"stopped": DataSchema(type="boolean")})),
        },
        links=[Link(href=name, rel=rel, type=media) for name, (rel, media) in ARTEFACTS.items()],
    )
    return td.to_dict()
