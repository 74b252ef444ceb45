"""Applications that consume the lab's Things: the cube workflow, the IK evaluation."""
