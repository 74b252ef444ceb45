"""Where things stand: the iot-platform table, the iot-lab room, obstacles added at run time."""
