"""twinmesh: a digital-twin lab for the Web of Things.

The packages, each importing only those listed before it: `wot` (protocol-neutral TD model,
validation, problems), `messages` (wire Structs), `fabric` (the Zenoh binding), `http` (the WoT
HTTP binding), `robot` (URDF, kinematics, IK, collision, workspace, planning), `tdgen` (robot TD
generation), `sim` (pybullet world and device models), `things` (one binding per device kind),
`recorder` (Rerun), `apps` (cube workflow, evaluation), `lab` (processes, scenes, supervisor),
`cli` (click only). Nothing imports `lab` or `cli`.
"""
