"""Mesh topology: what N lights cost in one process, each on its own Zenoh session in peer mode,
with every peer linking to every other (Zenoh's default gossip, the baseline) beside peers that link
to the lab's router only (`MeshSettings.star`, the default since), measured in the same run.

For each N a fresh process opens N sessions against one router, exposes a light on each, waits
until the router sees them all, and reports its file descriptors, threads and RSS; then one
consumer reads every light once through the mesh (answers / N).

    python tests/bench/bench_topology.py [--sizes 10,20,40,80]
"""
from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

import msgspec
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs

from labs import free_port  # noqa: E402


def child(endpoint: str, n: int, star: bool) -> dict:
    from contextlib import ExitStack

    from twinmesh.fabric.client import MeshClient
    from twinmesh.fabric.session import one_shot_session, open_session
    from twinmesh.fabric.settings import MeshSettings
    from twinmesh.things.lights import Light

    settings = MeshSettings(connect=(endpoint,), star=star)
    me = psutil.Process()
    with ExitStack() as stack:
        started = time.perf_counter()
        try:
            for i in range(n):
                session = stack.enter_context(open_session(settings))
                stack.enter_context(Light(session, f"light-{i}", settings.keys).thing)
        except Exception as e:  # the full mesh runs out of descriptors at some N
            return {"n": n, "star": star, "failed": f"{type(e).__name__}: {e}"[:200]}
        with one_shot_session(msgspec.structs.replace(settings, mode="client")) as s:
            client = MeshClient(s, settings)
            deadline = time.monotonic() + 60
            while len(client.things()) < n and time.monotonic() < deadline:
                time.sleep(0.2)
            seconds = time.perf_counter() - started
            time.sleep(2.0)  # links settle
            fds, threads, rss = me.num_fds(), me.num_threads(), me.memory_info().rss
            answered = 0
            t0 = time.perf_counter()
            for i in range(n):
                try:
                    client.read(f"light-{i}", "lightState")
                    answered += 1
                except Exception:
                    pass
            read_ms = (time.perf_counter() - t0) * 1e3 / n
    return {"n": n, "star": star, "fds": fds, "threads": threads, "rss_mb": rss / 2**20, "ready_s": seconds,
            "answered": answered, "read_ms": read_ms}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="10,20,40,80")
    ap.add_argument("--child", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.child:
        endpoint, n, star = args.child
        print(json.dumps(child(endpoint, int(n), star == "star")))
        return
    from twinmesh.fabric.session import open_session
    from twinmesh.fabric.settings import MeshSettings

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    router = MeshSettings(connect=(endpoint,)).as_router()
    rows = []
    with open_session(router):
        for n in [int(v) for v in args.sizes.split(",")]:
            for topology in ("mesh", "star"):
                out = subprocess.run([sys.executable, __file__, "--child", endpoint, str(n), topology],
                                     capture_output=True, text=True, timeout=600,
                                     env={**os.environ, "TWINMESH_ZENOH_LOG": "off"})
                lines = out.stdout.strip().splitlines()
                rows.append(json.loads(lines[-1]) if lines else {"n": n, "star": topology == "star",
                                                                   "failed": out.stderr[-200:]})
                time.sleep(1.0)
    print(f"{'N':>5} {'topology':<22} {'fds':>6} {'fds/N':>6} {'threads':>8} {'RSS MB':>7} {'MB/N':>6} "
          f"{'ready s':>8} {'read ms':>8} {'answered':>9}")
    for r in rows:
        label = "star (peers -> router)" if r["star"] else "full mesh (baseline)"
        if "failed" in r:
            print(f"{r['n']:>5} {label:<22} failed: {r['failed']}")
            continue
        print(f"{r['n']:>5} {label:<22} {r['fds']:>6} {r['fds'] / r['n']:>6.1f} {r['threads']:>8} {r['rss_mb']:>7.0f} "
              f"{r['rss_mb'] / r['n']:>6.2f} {r['ready_s']:>8.2f} {r['read_ms']:>8.2f} {r['answered']:>6}/{r['n']}")


if __name__ == "__main__":
    main()
