"""From a URDF and its surroundings to a TD or TM: the robot library (`robot`), workspace sampling,
the generate pipeline, TD/TM assembly, the tdgen service Thing and its commands."""
