"""How a pybullet world describes its bodies for the recorder (the `mesh.messages.scene_description` contract).

Scenes build their furniture from pybullet primitives; this turns a body id back into the
`Body` a recorder draws (shape, size, pose, colour), so a scene never states its geometry twice.
"""
from __future__ import annotations

import pybullet as pb

from mesh.messages.scene_description import Body, Pose


def pose(p: tuple) -> Pose:
    """A `Pose` from pybullet's ((x, y, z), (qx, qy, qz, qw))."""
    pos, orn = p
    return Pose(tuple(float(v) for v in pos), tuple(float(v) for v in orn))  # type: ignore[arg-type]


def box(client: int, name: str, body: int, moving: bool = False) -> Body:
    """The `Body` of a box-shaped pybullet body, with its colour and opacity."""
    shape = pb.getVisualShapeData(body, physicsClientId=client)[0]
    if shape[2] != pb.GEOM_BOX:  # pragma: no cover - scenes are built of boxes
        raise ValueError(f"{name}: only boxes are described")
    rgba = [float(v) for v in shape[7]]
    pos, orn = pb.getBasePositionAndOrientation(body, physicsClientId=client)
    return Body(name=name, shape="box", size=tuple(float(v) for v in shape[3]), pose=pose((pos, orn)),
                color=tuple(rgba[:3]), opacity=rgba[3], moving=moving)  # type: ignore[arg-type]
