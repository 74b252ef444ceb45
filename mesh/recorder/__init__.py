"""Rerun recording of the lab: TD-to-entity mapping, the scene, the robots, the logger, repair."""
