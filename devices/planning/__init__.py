"""Motion planning: collision-free joint paths (OMPL glue)."""
