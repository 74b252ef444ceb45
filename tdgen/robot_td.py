"""A robot's Thing Description (SPEC §4), built once for every place that needs it.

`robot_td` is the TD a robot Thing serves on the mesh (relative forms and links: `files/...`); the
tdgen service writes it and the robot serves it as it is. `served_td` is what the HTTP adapter
then serves at a Thing URL (the adapter's own rewriting, `mesh.http.tdrewrite`), and
`thing_model` the same with `{{BASE_URL}}` left open: a WoT Thing Model (TD 1.1 §10) for when no
base URL is known. So `twinmesh tdgen` writes exactly what a running robot serves.
"""
from __future__ import annotations

import re

import numpy as np

from mesh.http.tdrewrite import http_td
from mesh.messages import relations
from mesh.messages.scene_description import TWIN_CHANGED, TWIN_FILE
from mesh.wot import units
from mesh.wot.thing_description import (
    JSON,
    NOSEC,
    TD_CONTEXT,
    ActionAffordance,
    DataSchema,
    EventAffordance,
    Form,
    Link,
    PropertyAffordance,
    Security,
    ThingDescription,
    decode_td,
    zenoh_forms,
)
from tdgen.robot.model import Robot

CONTEXT = TD_CONTEXT
ARTEFACTS = {  # file name -> (rel, media type)
    "workspace.stl": (relations.WORKSPACE, "model/stl"),
    "points.csv": (relations.POINTS, "text/csv"),
    "scene.json": (relations.SCENE, "application/json"),
}
URDF_TYPE = "application/xml"
BASE_URL = "{{BASE_URL}}"  # the Thing Model's placeholder for the adapter's address


def slug(name: str) -> str:
    """A Thing name from a robot name: `lbr_iiwa_14_r820` -> `lbr-iiwa-14-r820`."""
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-") or "robot"


def robot_id(name: str) -> str:
    """A stable absolute URI for a robot: `urn:twinmesh:robot:<name>`."""
    return "urn:twinmesh:robot:" + (re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip("-") or "robot")


def _number(unit: str, low: float, high: float) -> DataSchema:
    return DataSchema(type="number", unit=unit, minimum=round(float(low), 6), maximum=round(float(high), 6))


def joint_schema(robot: Robot) -> DataSchema:
    """One number per main joint: deg (revolute, continuous) or mm (prismatic), within the limits."""
    lows, highs = robot.to_user_units(robot.lows()), robot.to_user_units(robot.highs())
    fields = {j.name: _number(joint_unit(j.type), lo, hi)
              for j, lo, hi in zip(robot.joints, lows, highs)}
    return DataSchema(type="object", properties=fields, required=list(fields))


def cartesian_schema(low: np.ndarray, high: np.ndarray) -> DataSchema:
    """x, y, z in mm within the bounds of the collision-free points."""
    fields = {axis: _number(units.MILLIMETRE, lo, hi) for axis, lo, hi in zip("xyz", low, high)}
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


def _numbers(unit: str) -> DataSchema:
    return DataSchema(type="array", items=DataSchema(type="number", unit=unit))


def joint_unit(joint_type: str) -> str:
    """SPEC §4: deg for revolute (and continuous) joints, mm for prismatic ones."""
    return units.MILLIMETRE if joint_type == "prismatic" else units.DEGREE


def _joint_values(robot: Robot) -> DataSchema:
    """One configuration in joint order, each value with its joint's unit: one `items` schema when every
    joint has the same unit (most consumers, wotpy among them, take no tuple form), else one per slot."""
    n = len(robot.joints)
    slots = [DataSchema(type="number", unit=joint_unit(j.type)) for j in robot.joints]
    alike = all(s == slots[0] for s in slots)
    return DataSchema(type="array", items=slots[0] if alike and slots else slots, minItems=n, maxItems=n)


def move_output_schema(robot: Robot) -> DataSchema:
    """What a move (or its dry run) answers: the collision-free path, where it ends, how it was found."""
    xyz = {axis: DataSchema(type="number", unit=units.MILLIMETRE) for axis in "xyz"}
    names = [j.name for j in robot.joints]
    return DataSchema(type="object", required=["path", "reached", "error_mm", "method", "planning_ms"], properties={
        "path": DataSchema(type="object", required=["joints", "points", "times"], description=(
            "Joint-space waypoints from where the arm was (first) to where it ends (last), each in the joint "
            f"order of `joints` ({', '.join(names)}; deg for revolute, mm for prismatic joints); `times` in "
            "simulated seconds from the start. The arm stops at every waypoint."), properties={
            "joints": DataSchema(type="array", items=DataSchema(type="string", enum=names)),
            "points": DataSchema(type="array", items=_joint_values(robot)),
            "times": _numbers(units.SECOND),
            "tip": DataSchema(type="array", items=_numbers(units.MILLIMETRE), description=(
                "The end effector along the path (mm, the TD's frame), several points per segment: what "
                "the move sweeps, for drawing."))}),
        "reached": DataSchema(type="object", properties=xyz, required=list(xyz),
                              description="Where the end effector ends (mm, the TD's frame)."),
        "error_mm": DataSchema(type="number", unit=units.MILLIMETRE, minimum=0.0,
                               description="Distance from the Cartesian target (0 for joint moves)."),
        "method": DataSchema(type="string", enum=["straight", "planned"],
                             description="straight: the direct joint-space path was free; planned: by OMPL."),
        "planning_ms": DataSchema(type="number", unit=units.MILLISECOND, minimum=0.0),
        "collision_probability": DataSchema(type="number", unit=units.UNITLESS, minimum=0.0, maximum=1.0, description=(
            "Share of colliding samples among the target's nearest sampled points (information; Cartesian "
            "targets with sampled neighbours only).")),
        "orientation": DataSchema(type="object", required=list(RPY), properties=_rpy(), description=(
            "Where the tip points when the move ends (roll, pitch, yaw; fixed axes, base frame); not in a "
            "calibrated robot's real frame, which maps positions only.")),
        "error_deg": DataSchema(type="number", unit=units.DEGREE, minimum=0.0,
                                description="Pose moves: the angle between the tip's orientation and the target's.")})


RPY = ("roll", "pitch", "yaw")


def _rpy() -> dict[str, DataSchema]:
    return {a: DataSchema(type="number", unit=units.DEGREE, minimum=-180.0, maximum=180.0) for a in RPY}


def pose_schema(cartesian: DataSchema) -> DataSchema:
    """A pose: x, y, z (mm, as the Cartesian moves take them) and roll, pitch, yaw (deg, fixed axes x, y, z
    of the base frame, as a URDF's rpy)."""
    return DataSchema(type="object", required=[*"xyz", *RPY], properties={**(cartesian.properties or {}), **_rpy()},
                      description="Tip position (mm) and orientation: roll, pitch, yaw in deg about the base "
                                  "frame's fixed x, y and z axes (as a URDF's rpy).")


def plan_input_schema(joints: DataSchema, cartesian: DataSchema) -> DataSchema:
    """One target of the move actions: a Cartesian one (x, y, z), a pose (x, y, z, roll, pitch, yaw) or
    `joints`; exactly one."""
    pose = pose_schema(cartesian)
    return DataSchema(type="object", description="x, y, z (mm), a pose (x, y, z and roll, pitch, yaw in deg) or "
                                                 "joints, as the move actions take them.",
                      oneOf=[DataSchema(type="object", title="Cartesian target", required=list("xyz"),
                                        properties=cartesian.properties, additionalProperties=False),
                             DataSchema(type="object", title="Pose target", required=pose.required,
                                        properties=pose.properties, additionalProperties=False),
                             DataSchema(type="object", title="Joint target", required=["joints"],
                                        properties={"joints": joints}, additionalProperties=False)])


FRAMES = {"twin": "the frame of the robot's root link {root}", "real": "the real robot's frame (calibrated)"}
POLICY = ("Every move follows a collision-free joint path (straight where that is free, else planned with OMPL in "
          "the live scene); Cartesian moves are refused outside the workspace hull{gate}, where no joint "
          "configuration reaches, where every configuration found collides, or where no path is found.")


def policy(max_collision_probability: float | None = None) -> str:
    """How the robot decides to move, for its TD's description."""
    gate = ("" if max_collision_probability is None else
            f", where the collision probability of the sampled neighbours exceeds {max_collision_probability:g}")
    return POLICY.format(gate=gate)


def _links(urdf_file: str, generated: bool) -> list[Link]:
    links = [Link(href=f"files/{name}", rel=rel, type=media) for name, (rel, media) in ARTEFACTS.items()
             if generated]
    return links + [Link(href=f"files/{TWIN_FILE}", rel=relations.TWIN, type=JSON),
                    Link(href=f"files/{urdf_file}", rel=relations.MODEL, type=URDF_TYPE)]


def twin_changed_event() -> EventAffordance:
    return EventAffordance(
        title="Twin changed", description="The robot's surroundings changed: its workspace, TD and files are being "
        "regenerated (the TD on the mesh is replaced when they are ready).",
        data=DataSchema(type="object", required=["robot", "version"], properties={
            "robot": DataSchema(type="string"), "version": DataSchema(type="integer", minimum=0)}),
        forms=[Form(href=f"events/{TWIN_CHANGED}", op=["subscribeevent", "unsubscribeevent"], contentType=JSON)])


def robot_td(robot: Robot, low: np.ndarray | None, high: np.ndarray | None, *, name: str, frame: str = "twin",
             thing_id: str | None = None, description: str = "", version: int = 0) -> dict:
    """The TD robot Thing `name` serves on the mesh, as a JSON-ready dict.

    `low`/`high` are the collision-free bounds (mm, in `frame`); None while the workspace is not
    generated yet (Cartesian values then have no bounds, and the workspace files are not linked).
    """
    generated = low is not None and high is not None
    joints = joint_schema(robot)
    cartesian = (cartesian_schema(low, high) if low is not None and high is not None else
                 DataSchema(type="object", required=list("xyz"),
                            properties={axis: DataSchema(type="number", unit=units.MILLIMETRE) for axis in "xyz"}))
    output = move_output_schema(robot)
    td = ThingDescription(
        title=name,
        context=list(CONTEXT),
        id=thing_id or robot_id(name),
        description=description or None,
        version={"instance": str(version)},
        properties={
            "getJointposition": _property(joints, "getJointposition", f"Joint values of the arm chain from the "
                                          f"base link {robot.base_link} to the tip link {robot.ee_link}: deg for "
                                          "revolute joints, mm for prismatic ones."),
            "getCartesianposition": _property(cartesian, "getCartesianposition",
                                              f"Position (mm) of the tip link {robot.ee_link} in "
                                              f"{FRAMES[frame].format(root=robot.root_link)}."),
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
            "moveToPose": _action(pose_schema(cartesian), "moveToPose",
                                  "Move the tip to this position (mm) in this orientation along a collision-free "
                                  "path (the position within 0.01 mm, the orientation within 0.01 deg); returns when "
                                  "the motion has finished, with the path and the orientation reached. Refused (422, "
                                  "nothing moves) where no joint configuration reaches the pose (`unreachable`), "
                                  "where every one found collides (`collision`) or no path is found (`no-path`).",
                                  output),
            "planMove": _action(plan_input_schema(joints, cartesian), "planMove",
                                "A dry run: answers exactly as the move would (path or refusal), from where the "
                                "arm stands now, without moving.", output, safe=True),
            "stop": _action(None, "stop", "Halt a move under way where the arm is (the move answers 409 "
                            "move-stopped); `stopped` says whether one was under way.",
                            DataSchema(type="object", required=["stopped"],
                                       properties={"stopped": DataSchema(type="boolean")})),
        },
        events={TWIN_CHANGED: twin_changed_event()},
        links=_links(robot.urdf_path.name, generated),
    )
    return td.to_dict()


def served_td(mesh_td: dict, thing_url: str, security: Security = NOSEC) -> dict:
    """What the HTTP adapter serves at `thing_url` (`<adapter>/<thing>`) for a robot serving `mesh_td`."""
    base, _, thing = thing_url.rstrip("/").rpartition("/")
    if not base or not thing:
        raise ValueError(f"a Thing URL is <adapter base>/<thing name>, not {thing_url!r}")
    on_mesh = zenoh_forms(decode_td(mesh_td), "wot", thing).to_dict()  # as mesh.fabric.server serves it
    return http_td(decode_td(on_mesh), thing, base, security, on_mesh)


def thing_model(mesh_td: dict, thing: str, security: Security = NOSEC) -> dict:
    """A Thing Model (TD 1.1 §10) of the robot: the served TD with the adapter's address left as the
    placeholder `{{BASE_URL}}`, and no `id` (an instance's own)."""
    tm = served_td(mesh_td, f"{BASE_URL}/{thing}", security)
    tm.pop("id", None)
    version = tm.pop("version", None) or {}
    return {"@context": tm.pop("@context"), "@type": "tm:ThingModel", **tm,
            "version": {"model": version.get("instance", "0")}}
