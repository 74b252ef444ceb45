"""The virtual devices and the lab that runs them: the pybullet world and device models (`sim`), one
Thing binding per device kind (`things`), motion planning (`planning`), the apps (`apps`), process
specs, scenes and the supervisor (`lab`), and the root `twinmesh` command (`cli`)."""
