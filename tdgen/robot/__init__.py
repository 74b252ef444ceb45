"""A plain robot library: URDF model, kinematics, IK, collision, surroundings, calibration,
workspace (points, hull, check) and collision-free joint paths. Knows nothing of the mesh."""
