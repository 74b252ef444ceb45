"""One WoT binding per device kind: lights, platform devices, pan-tilts, robots, the world, tdgen."""
