"""The `twinmesh` command line (click lives only here)."""
