"""From a URDF and its surroundings to a TD or TM: the robot library (`robot`), workspace sampling,
the generate pipeline, TD/TM assembly, the tdgen service Thing and its commands."""

from mesh.process import quiet_pybullet_import

quiet_pybullet_import()  # pybullet's build-time banner stays out of stderr, in tdgen's worker processes too
