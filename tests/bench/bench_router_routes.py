"""What one Zenoh 1.10 router does per device and per query: plain sessions, declared as a device's.

    python tests/bench/bench_router_routes.py [--sizes 1000,2000,4000] [--exact 0,2] [--pubs 0]
                                              [--processes 4] [--limit 600]

No lab: a router (`MeshSettings.as_router`), a consumer like the HTTP adapter (a subscriber on
`wot/**`, a liveliness subscriber on `wot/*`, each new Thing's TD asked once, from 8 threads), and
`--processes` processes of N/processes client sessions each, every session declaring what a twinmesh
device declares: one queryable on `wot/<thing>/**` and its liveliness token `wot/<thing>`. `--exact K`
declares K more queryables on exact keys (the TD's and K-1 properties', the first one the property
read below); `--pubs P` declares P publishers and publishes once on each. Per size and variant, in the
same run: the seconds from the devices' start until the consumer holds every TD, the router's CPU
until then and its RSS; then 600 reads of the first property of 200 devices spread over the fleet,
p50 / p99, and the router's CPU per read. Where `perf` can count calls on the router's
`Resource::get_matches` (root, a `probe_zenoh:gm` uprobe: `perf probe -x zenoh.abi3.so -a gm=ADDRESS`),
also the calls per read. The finding (docs/explanation/scale.md): a query on a key that no queryable
declares exactly has its route computed anew, each time visiting every Thing's key.
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository

ENDPOINT = "tcp/127.0.0.1:17447"
SAMPLED = 200  # devices read
ROUNDS = 3


def _settings(mode: str = "client"):
    from mesh.fabric.settings import MeshSettings

    settings = MeshSettings(connect=(ENDPOINT,))
    return settings.as_router() if mode == "router" else settings


def router(ready) -> None:
    import zenoh

    with zenoh.open(_settings("router").zenoh_config()):
        ready.set()
        threading.Event().wait()


def devices(first: int, count: int, exact: int, pubs: int, declared) -> None:
    import zenoh

    os.nice(10)  # as the fleet's processes: the router and the consumer first
    held = []
    for i in range(first, first + count):
        session = zenoh.open(_settings().zenoh_config())
        name = f"thing-{i:05d}"
        answer = json.dumps({"title": name}).encode()

        def reply(query, answer=answer) -> None:
            query.reply(query.key_expr, answer)

        held += [session, session.declare_queryable(f"wot/{name}/**", reply),
                 session.liveliness().declare_token(f"wot/{name}")]
        for k in range(exact):
            key = f"wot/{name}/td" if k == 0 else f"wot/{name}/properties/p{k}"
            held.append(session.declare_queryable(key, lambda q: None))  # the `**` queryable answers
        for k in range(pubs):
            publisher = session.declare_publisher(f"wot/{name}/properties/q{k}")
            publisher.put(b"1")
            held.append(publisher)
    declared.release()
    threading.Event().wait()


def consumer(n: int, limit: float, out) -> None:
    from concurrent.futures import ThreadPoolExecutor

    import zenoh

    with zenoh.open(_settings().zenoh_config()) as session, ThreadPoolExecutor(8) as pool:
        got: set[str] = set()
        lock, done = threading.Lock(), threading.Event()

        def fetch(name: str) -> None:
            for _ in range(20):
                if any(r.ok is not None for r in session.get(f"wot/{name}/td", timeout=5.0)):
                    with lock:
                        got.add(name)
                        if len(got) >= n:
                            done.set()
                    return

        def joined(sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                pool.submit(fetch, str(sample.key_expr).split("/")[1])

        session.declare_subscriber("wot/**", lambda sample: None)
        session.liveliness().declare_subscriber("wot/*", joined, history=True)
        out.put(("ready", time.monotonic()))
        done.wait(limit)
        out.put(("listed", time.monotonic(), len(got)))
        names = sorted(got)[:: max(1, len(got) // SAMPLED)][:SAMPLED]
        times = []
        for _ in range(ROUNDS):
            for name in names:
                t = time.perf_counter()
                list(session.get(f"wot/{name}/properties/p1", timeout=5.0))
                times.append((time.perf_counter() - t) * 1000)
        out.put(("reads", times))
        threading.Event().wait()


def _cpu(proc: psutil.Process) -> float:
    t = proc.cpu_times()
    return t.user + t.system


def _counting(pid: int) -> subprocess.Popen | None:
    """`perf stat` counting the router's get_matches calls, where the uprobe exists (else None)."""
    try:
        probes = subprocess.run(["perf", "probe", "-l"], capture_output=True, text=True, timeout=30).stdout
    except (OSError, subprocess.TimeoutExpired):
        return None
    if "probe_zenoh:gm" not in probes:
        return None
    return subprocess.Popen(["perf", "stat", "-x,", "-e", "probe_zenoh:gm", "-p", str(pid)],
                            stderr=subprocess.PIPE, text=True)


def measure(n: int, exact: int, pubs: int, processes: int, limit: float) -> dict:
    ctx = mp.get_context("spawn")
    ready, declared, out = ctx.Event(), ctx.Semaphore(0), ctx.Queue()
    started = [ctx.Process(target=router, args=(ready,), daemon=True)]
    started[0].start()
    try:
        ready.wait(60)
        the_router = psutil.Process(started[0].pid)
        started.append(ctx.Process(target=consumer, args=(n, limit, out), daemon=True))
        started[-1].start()
        out.get(timeout=120)
        t0 = time.monotonic()
        share = n // processes
        for k in range(processes):
            started.append(ctx.Process(target=devices, args=(k * share, share, exact, pubs, declared), daemon=True))
            started[-1].start()
        _, listed_at, listed = out.get(timeout=limit + 120)
        cpu_listed, rss = _cpu(the_router), the_router.memory_info().rss
        counter = _counting(the_router.pid)
        cpu0 = _cpu(the_router)
        _, reads = out.get(timeout=ROUNDS * SAMPLED * 6 + 60)
        cpu_reads = _cpu(the_router) - cpu0
        calls = None
        if counter is not None:
            counter.send_signal(signal.SIGINT)
            line = next((x for x in counter.communicate(timeout=30)[1].splitlines() if "probe_zenoh:gm" in x), "")
            calls = int(line.split(",")[0]) / len(reads) if line.split(",")[0].isdigit() else None
        reads.sort()
        return {"listed": listed, "seconds": listed_at - t0, "router_cpu": cpu_listed, "rss_mb": rss / 2**20,
                "p50": statistics.median(reads), "p99": reads[int(len(reads) * 0.99)],
                "cpu_per_read_ms": cpu_reads / len(reads) * 1000, "matches_per_read": calls}
    finally:
        for p in reversed(started):
            if p.pid is not None and p.is_alive():
                p.kill()
        for p in started:
            p.join(30)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", default="1000,2000,4000")
    ap.add_argument("--exact", default="0,2", help="exact-key queryables per device, variants side by side")
    ap.add_argument("--pubs", type=int, default=0)
    ap.add_argument("--processes", type=int, default=4)
    ap.add_argument("--limit", type=float, default=600.0, help="s to wait for every TD")
    opts = ap.parse_args()
    print("| devices | exact-key queryables each | all TDs held after | router CPU until then | router RSS | "
          "read p50 / p99 | router CPU per read | get_matches per read |", flush=True)
    for n in (int(x) for x in opts.sizes.split(",")):
        for exact in (int(x) for x in opts.exact.split(",")):
            r = measure(n, exact, opts.pubs, opts.processes, opts.limit)
            listed = f"{r['seconds']:.1f} s" if r["listed"] >= n else f"{r['listed']:,} of {n:,} in {r['seconds']:.0f} s"
            calls = "-" if r["matches_per_read"] is None else f"{r['matches_per_read']:.1f}"
            print(f"| {n:,} | {exact} | {listed} | {r['router_cpu']:.1f} s | {r['rss_mb']:.0f} MB | "
                  f"{r['p50']:.2f} / {r['p99']:.2f} ms | {r['cpu_per_read_ms']:.2f} ms | {calls} |", flush=True)


if __name__ == "__main__":
    main()
