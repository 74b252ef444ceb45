"""Memory under sustained invokes: what a consumer's process keeps per synchronous invocation.

zenoh-python 1.10 keeps a query's state (about 1 KB) until the query's timeout, even after the last
reply. A synchronous invocation carried by one query that may last as long as a robot's motion
(timeout: the 300 s action timeout) therefore holds memory for 300 s per invoke; `MeshClient.invoke`
now carries it as an asynchronous invocation whose queries are short long-polls (`?async;sync;wait=2`,
timeout 2 + 5 s). Each run is a fresh process with its own Zenoh session against one lab
(`twinmesh up lights`) invoking `light-left`'s `switchOn` from 8 threads; its RSS growth is printed
per invoke, baseline (one long query per invoke, as before) and now side by side. Then the HTTP
adapter's own RSS under the same invokes over HTTP (it invokes through MeshClient.invoke).

    python tests/bench/bench_invoke_memory.py [--invokes 20000]
"""
from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs

from labs import start_lab  # noqa: E402

THREADS = 8
BATCHES = 3
PAUSE = 8.0  # s after each batch (> 2 + 5 s, the timeout of the new queries)


def phase(endpoint: str, mode: str, invokes: int) -> dict:
    """In the child: `invokes` switchOn calls, RSS before and after (MB), elapsed seconds."""
    from mesh.fabric.mesh_client import MeshClient
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    settings = MeshSettings(mode="client", connect=(endpoint,))
    me = psutil.Process()
    with open_session(settings) as session:
        client = MeshClient(session, settings)
        key = client.keys.action("light-left", "switchOn")
        call = ((lambda: client.request(key, None, settings.action_timeout, "light-left")) if mode == "baseline"
                else (lambda: client.invoke("light-left", "switchOn")))
        for _ in range(200):  # warm-up: routes, pools, allocator
            call()
        time.sleep(0.5)
        rss = [me.memory_info().rss / 2**20]
        seconds = 0.0
        for _ in range(BATCHES):
            todo = iter(range(invokes))
            lock = threading.Lock()

            def worker() -> None:
                while True:
                    with lock:
                        if next(todo, None) is None:
                            return
                    call()

            started = time.perf_counter()
            threads = [threading.Thread(target=worker) for _ in range(THREADS)]
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            seconds += time.perf_counter() - started
            time.sleep(PAUSE)  # longer than the new queries' timeout: what is still held now is kept
            rss.append(me.memory_info().rss / 2**20)
    return {"mode": mode, "invokes": invokes * BATCHES, "seconds": seconds, "rss_mb": rss}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--invokes", type=int, default=20_000)
    ap.add_argument("--phase", choices=["baseline", "now"], help=argparse.SUPPRESS)
    ap.add_argument("--endpoint", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.phase:
        print(json.dumps(phase(args.endpoint, args.phase, args.invokes)))
        return
    with tempfile.TemporaryDirectory() as tmp:
        lab = start_lab(Path(tmp), "lights", http=True, things={"light-left"})
        try:
            results = {}
            for mode in ("baseline", "now"):
                out = subprocess.run([sys.executable, __file__, "--phase", mode, "--endpoint", lab.endpoint,
                                      "--invokes", str(args.invokes)], capture_output=True, text=True, check=True)
                results[mode] = json.loads(out.stdout.strip().splitlines()[-1])
            adapter = over_http(lab, args.invokes)
        finally:
            lab.stop()
    print(f"{BATCHES} batches of {args.invokes} synchronous invokes of light-left.switchOn from {THREADS} threads, "
          f"{PAUSE:g} s pause after each; one fresh process per mode")
    print(f"{'':<46} {'invokes/s':>9}  {'RSS after warm-up, then after each batch (MB)':<46} {'per invoke':>10} "
          f"{'last batch':>10}")
    per = {}
    for mode, label in (("baseline", "baseline: one query per invoke, 300 s timeout"),
                        ("now", "now: async + long-poll queries (2 + 5 s)")):
        r = results[mode]
        rss = r["rss_mb"]
        per[mode] = (rss[-1] - rss[0]) * 1024 / r["invokes"]
        last = (rss[-1] - rss[-2]) * 1024 / args.invokes  # steady state: the first batch also fills pools
        print(f"{label:<46} {r['invokes'] / r['seconds']:>9.0f}  {' -> '.join(f'{v:.1f}' for v in rss):<46} "
              f"{per[mode]:>7.3f} KB {last:>7.3f} KB")
    ratio = per["now"] / per["baseline"] if per["baseline"] > 0 else float("nan")
    print(f"ratio now / baseline, memory kept per invoke: {ratio:.3f}")
    rss = adapter["rss_mb"]
    print(f"\nthe HTTP adapter's process under POST /light-left/actions/switchOn from {THREADS} threads "
          f"({adapter['invokes'] / adapter['seconds']:.0f} invokes/s): RSS {' -> '.join(f'{v:.1f}' for v in rss)} MB, "
          f"last batch {(rss[-1] - rss[-2]) * 1024 / args.invokes:.3f} KB per invoke")


def over_http(lab, invokes: int) -> dict:
    """The adapter's RSS (MB) after warm-up and after each batch of synchronous HTTP invokes."""
    import httpx

    adapter = next(p for p in psutil.Process(lab.proc.pid).children(recursive=True) if "adapter" in " ".join(p.cmdline()))
    url = f"{lab.http}/light-left/actions/switchOn"
    clients = [httpx.Client() for _ in range(THREADS)]
    for _ in range(100):
        clients[0].post(url).raise_for_status()
    rss, seconds = [adapter.memory_info().rss / 2**20], 0.0
    for _ in range(BATCHES):
        todo = iter(range(invokes))
        lock = threading.Lock()

        def worker(client: httpx.Client) -> None:
            while True:
                with lock:
                    if next(todo, None) is None:
                        return
                client.post(url).raise_for_status()

        started = time.perf_counter()
        threads = [threading.Thread(target=worker, args=(c,)) for c in clients]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
        seconds += time.perf_counter() - started
        time.sleep(PAUSE)
        rss.append(adapter.memory_info().rss / 2**20)
    for c in clients:
        c.close()
    return {"invokes": invokes * BATCHES, "seconds": seconds, "rss_mb": rss}


if __name__ == "__main__":
    main()
