"""Running a lab: scenes (which processes), their entry points, the supervisor, readiness."""
