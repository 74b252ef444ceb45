"""Things from outside the mesh: a foreign TD taken in (`intake`), the remote Thing it describes driven
through its own forms (`remote`), and put on the mesh under a name (`bridged`, run by `twinmesh
bridge`): then the adapter, the recorder, the control page and the CLI see it like any device."""
