"""What an idle lab's simulation costs: the CPU of its world (physics, sensors, snapshots) left alone.

    python tests/bench/bench_idle_world.py [--seconds 20]

Builds the iot-lab's and the iot-platform's pybullet worlds in this process at speed max (an idle world steps
in real time), lets each settle, and measures the process's CPU over `seconds` twice, side by side: the
baseline with `world.rest = False` (the physics engine steps every step, as before resting worlds) and the
default (an idle world whose bodies are still rests). Prints % of one core, steps and physics steps per
second, and the ratio. Nothing else should run in this process; other load on the machine shows in the
figures (they are CPU seconds, steadier than wall time).
"""
from __future__ import annotations

import argparse
import os
import threading
import time


def until(world, condition, timeout: float) -> bool:
    """Wait until `condition()` holds at one of the world's snapshots (every 1/30 s of simulated time, on
    its notifier thread: nothing polls in this process); False after `timeout` s."""
    held = threading.Event()
    unsubscribe = world.on_snapshot(lambda snap: held.set() if condition() else None)
    try:
        return held.wait(timeout)
    finally:
        unsubscribe()


def measure(build, rest: bool, seconds: float) -> tuple[float, float, float]:
    """% of a core, steps/s and physics steps/s of the world `build()` makes, idle, resting or not."""
    lab = build(speed=None)
    world = lab.world
    world.rest = rest
    try:
        if rest:
            assert until(world, lambda: world.resting, 30), "the idle world did not come to rest within 30 s"
        else:  # settled as the other: 2 s of simulated time, its start-up not measured
            start = world.time
            assert until(world, lambda: world.time >= start + 2.0, 30), "the world did not step"
        cpu, steps, physics, wall = time.process_time(), world.steps, world.physics_steps, time.monotonic()
        start = world.time  # idle, the world runs in real time: `seconds` of it are as many on the wall clock
        assert until(world, lambda: world.time >= start + seconds, 3 * seconds), "the world did not step"
        wall = time.monotonic() - wall
        return (100 * (time.process_time() - cpu) / wall, (world.steps - steps) / wall,
                (world.physics_steps - physics) / wall)
    finally:
        lab.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=20.0)
    args = parser.parse_args()
    from devices.sim.layouts.lab import build_lab
    from devices.sim.layouts.platform_layout import build_platform

    print(f"{os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}; {args.seconds:g} s each")
    print(f"{'world':14} {'physics every step':>28} {'resting (default)':>28} {'ratio':>6}")
    for name, build in (("iot-lab", build_lab), ("iot-platform", build_platform)):
        before = measure(build, False, args.seconds)
        after = measure(build, True, args.seconds)
        print(f"{name:14} {before[0]:6.1f} % ({before[1]:.0f} / {before[2]:.0f} per s) "
              f"{after[0]:10.1f} % ({after[1]:.0f} / {after[2]:.0f} per s) {before[0] / max(after[0], 0.01):6.1f}x")
    print("(% of one core for the process; steps / physics steps per second)")


if __name__ == "__main__":
    main()
