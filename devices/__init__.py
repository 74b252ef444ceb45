"""twinmesh twins: the pybullet world, device behaviours, robot models and scenes."""
