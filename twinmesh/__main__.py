from twinmesh.cli.main import main

main()
