"""The pybullet world and the device models; `layouts` builds the platform and the lab."""
