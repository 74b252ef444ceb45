"""The mesh's cost grows linearly with its devices: peers link to the router only (a star), so the file
descriptors each light adds stay the same as their number doubles (with Zenoh's default gossip,
every peer linking to every other, they grow with N: tests/bench/bench_topology.py measures both).
Real sessions on loopback, one router, lights exposed as `twinmesh up lights` does (each on its own
peer session).
"""
from __future__ import annotations

import time
from contextlib import ExitStack

import psutil
from labs import free_port

from twinmesh.fabric.client import MeshClient
from twinmesh.fabric.session import open_session
from twinmesh.fabric.settings import MeshSettings
from twinmesh.things.lights import Light


def descriptors_per_light(star: bool, sizes: tuple[int, ...]) -> list[float]:
    """Descriptors this process gains per light added, from each size to the next."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    settings = MeshSettings(connect=(endpoint,), star=star)
    me = psutil.Process()
    with ExitStack() as stack:
        stack.enter_context(open_session(settings.as_router()))
        consumer = MeshClient(stack.enter_context(open_session(MeshSettings(connect=(endpoint,), mode="client"))),
                              settings)
        counts, lights = [], 0
        for n in sizes:
            while lights < n:
                session = stack.enter_context(open_session(settings))
                stack.enter_context(Light(session, f"light-{lights}", settings.keys).thing)
                lights += 1
            deadline = time.monotonic() + 30
            while len(consumer.things()) < n and time.monotonic() < deadline:
                time.sleep(0.2)
            time.sleep(1.5)  # gossip and autoconnect settle
            assert consumer.read(f"light-{n - 1}", "lightState") is False  # it answers through the mesh
            counts.append(me.num_fds())
    return [(counts[i + 1] - counts[i]) / (sizes[i + 1] - sizes[i]) for i in range(len(sizes) - 1)]


def test_descriptors_per_light_stay_bounded_as_the_lights_double():
    star = descriptors_per_light(True, (8, 16, 32))
    print(f"\nstar: descriptors per light added, 8->16: {star[0]:.1f}, 16->32: {star[1]:.1f}")
    assert star[1] <= star[0] * 1.5 + 1 and star[1] <= 12

