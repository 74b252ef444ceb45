"""Link relation types in twinmesh TDs (RFC 8288 §2.1): registered types where one fits, URIs otherwise.

RFC 8288 wants an extension relation type to be a URI; twinmesh's live under `VOCABULARY`, the
same home as its problem types (`mesh.wot.problem.PROBLEM_BASE`). The README's "Link
relations" table says what each one points at.
"""
from __future__ import annotations

VOCABULARY = "https://twinmesh.dev/rel/"

SELF = "self"               # registered: the TD itself, where the adapter serves it
MODEL = "describedby"       # registered: the robot's URDF (on the world Thing, anchored at each robot's Thing)
WORKSPACE = VOCABULARY + "workspace"     # the workspace hull: convex hull of the collision-free tip positions (STL)
POINTS = VOCABULARY + "dataset-points"   # the sampled configurations: CSV x,y,z,collision,<joints>
SCENE = VOCABULARY + "scene"             # the surroundings: a robot's generation scene, the world's scene file
TWIN = VOCABULARY + "twin"               # the twin description (twin.json) the tdgen service generates from
SCENE_ASSET = VOCABULARY + "scene-asset"  # a file a body of the served scene names: a CAD mesh, a scan

DESCRIPTIONS = {
    MODEL: "the robot's URDF (application/xml); on the world Thing one per robot, `anchor` = the robot's id",
    WORKSPACE: "the workspace hull, convex hull of the collision-free end-effector positions (model/stl, mm)",
    POINTS: "the sampled joint configurations with their tip position and collision state (text/csv)",
    SCENE: "the surroundings: the scene a robot's workspace was generated in, or the world's scene file (JSON)",
    TWIN: "the twin description the tdgen service generates a robot's TD and files from (JSON)",
    SCENE_ASSET: "a file a mesh or points body of the served scene names (a CAD mesh, a scan), under the name the "
                 "scene gives it: relative to scene.json (model/stl, model/obj, application/octet-stream for PLY "
                 "and PCD, ...)",
}
