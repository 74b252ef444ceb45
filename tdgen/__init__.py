"""twinmesh robot TD generation: introspection, kinematics, workspace sampling, hull, checks, calibration."""
