"""twinmesh mesh fabric: key expressions, Zenoh sessions, Thing runtime, TD model, HTTP adapter, recorder, CLI."""
