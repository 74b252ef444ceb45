"""The IoT platform's devices by name, in one light module: a lab's scenes name them without loading the
simulation (`platform_things` binds them)."""
from __future__ import annotations

PLATFORM_DEVICES = ("dobot", "conveyor-belt-1", "conveyor-belt-2", "infrared-sensor-1", "infrared-sensor-2",
                    "color-sensor", "uarm")
