from devices.cli.main import main

main()
