"""Robot TD generation: workspace sampling, the generate pipeline, TD assembly."""
