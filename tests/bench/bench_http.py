"""HTTP benchmark: readproperty through the twinmesh adapter against node-wot's own HTTP servient.

Both serve `light-left`'s `lightState` on 127.0.0.1; the same httpx client (keep-alive) measures
both, side by side: a sequential run (latency p50/p99 and throughput, one request at a time) and
concurrent runs with `--concurrency` requests in flight, on an httpx AsyncClient (which is itself
the bottleneck at a few hundred req/s) and on bare keep-alive sockets (server-bound). Also: the
adapter's uncached path, a non-observable property (`probe.serial`) read through the mesh on
every request (HTTP -> worker thread -> Zenoh query -> device -> reply).

    python tests/bench/bench_http.py [--requests 2000] [--concurrency 16]

Client and servers share the machine's cores: figures are for comparison on one machine, not
absolute capacity. Ratios are adapter / node-wot (latency: > 1 means slower; throughput: < 1).
"""
from __future__ import annotations

import argparse
import asyncio
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, interop

from interop import npm  # noqa: E402
from labs import start_lab  # noqa: E402
from probe import spawn_device  # noqa: E402

WARMUP = 200


def sequential(url: str, n: int) -> dict:
    with httpx.Client() as client:
        for _ in range(WARMUP):
            client.get(url).raise_for_status()
        times = np.empty(n)
        started = time.perf_counter()
        for i in range(n):
            t0 = time.perf_counter()
            client.get(url).raise_for_status()
            times[i] = time.perf_counter() - t0
        total = time.perf_counter() - started
    return {"p50": np.percentile(times, 50) * 1e3, "p99": np.percentile(times, 99) * 1e3, "rps": n / total}


async def _concurrent(url: str, n: int, concurrency: int) -> dict:
    limits = httpx.Limits(max_connections=concurrency, max_keepalive_connections=concurrency)
    async with httpx.AsyncClient(limits=limits) as client:
        for _ in range(WARMUP // 10):
            await asyncio.gather(*(client.get(url) for _ in range(concurrency)))
        times: list[float] = []
        todo = iter(range(n))

        async def worker() -> None:
            for _ in todo:
                t0 = time.perf_counter()
                (await client.get(url)).raise_for_status()
                times.append(time.perf_counter() - t0)

        started = time.perf_counter()
        await asyncio.gather(*(worker() for _ in range(concurrency)))
        total = time.perf_counter() - started
    return {"p50": np.percentile(times, 50) * 1e3, "p99": np.percentile(times, 99) * 1e3, "rps": n / total}


async def _raw(url: str, n: int, concurrency: int) -> dict:
    """Keep-alive connections driven by a minimal HTTP/1.1 client: the server, not the client, is the limit."""
    parsed = httpx.URL(url)
    request = (f"GET {parsed.raw_path.decode()} HTTP/1.1\r\nHost: {parsed.host}:{parsed.port}\r\n"
               f"Accept: application/json\r\n\r\n").encode()
    times: list[float] = []
    todo = iter(range(n + WARMUP))

    async def worker() -> None:
        reader, writer = await asyncio.open_connection(parsed.host, parsed.port)
        for i in todo:
            t0 = time.perf_counter()
            writer.write(request)
            head = (await reader.readuntil(b"\r\n\r\n")).lower()
            if not head.startswith(b"http/1.1 200"):
                raise RuntimeError(head.decode())
            if b"transfer-encoding: chunked" in head:  # node-wot streams its replies
                while (size := int((await reader.readuntil(b"\r\n")).strip(), 16)):
                    await reader.readexactly(size + 2)
                await reader.readexactly(2)
            else:
                length = int(head.split(b"content-length:")[1].split(b"\r\n")[0])
                await reader.readexactly(length)
            if i >= WARMUP:
                times.append(time.perf_counter() - t0)
        writer.close()

    started = time.perf_counter()
    await asyncio.gather(*(worker() for _ in range(concurrency)))
    total = time.perf_counter() - started
    return {"p50": np.percentile(times, 50) * 1e3, "p99": np.percentile(times, 99) * 1e3,
            "rps": (n + WARMUP) / total}


RUNS = {
    "sequential (httpx.Client)": lambda url, n, c: sequential(url, n),
    "concurrent (httpx.AsyncClient)": lambda url, n, c: asyncio.run(_concurrent(url, n, c)),
    "concurrent (raw keep-alive sockets)": lambda url, n, c: asyncio.run(_raw(url, n, c)),
}


def measure(url: str, n: int, concurrency: int) -> dict:
    return {run: fn(url, n, concurrency) for run, fn in RUNS.items()}


def row(label: str, figures: dict) -> str:
    return f"{label:<36} {figures['p50']:>8.3f} {figures['p99']:>8.3f} {figures['rps']:>9.0f}"


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--requests", type=int, default=2000)
    parser.add_argument("--concurrency", type=int, default=16)
    args = parser.parse_args()

    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        lab = start_lab(Path(tmp), "lights", http=True, things={"light-left"})
        try:
            spawn_device(lab, "probe", "probe")
            base = f"{lab.http}/light-left/properties/lightState"
            for _ in range(50):  # the adapter learns the probe's TD from liveliness
                if httpx.get(f"{lab.http}/probe/properties/serial").status_code == 200:
                    break
                time.sleep(0.1)
            results["adapter (cached, observable)"] = measure(base, args.requests, args.concurrency)
            results["adapter (through the mesh)"] = measure(f"{lab.http}/probe/properties/serial",
                                                            args.requests, args.concurrency)
        finally:
            clean = lab.stop()
    with npm.start_baseline_servient() as servient:
        results["node-wot 0.9.2 servient"] = measure(
            f"http://127.0.0.1:{servient.port}/light-left/properties/lightState", args.requests, args.concurrency)

    print(f"readproperty, {args.requests} requests per run, httpx keep-alive, "
          f"concurrency {args.concurrency} in the concurrent run")
    for run in RUNS:
        print(f"\n{run:<36} {'p50 ms':>8} {'p99 ms':>8} {'req/s':>9}")
        for label, figures in results.items():
            print(row(label, figures[run]))
        ours, theirs = results["adapter (cached, observable)"][run], results["node-wot 0.9.2 servient"][run]
        print(f"{'ratio adapter(cached) / node-wot':<36} {ours['p50'] / theirs['p50']:>8.2f} "
              f"{ours['p99'] / theirs['p99']:>8.2f} {ours['rps'] / theirs['rps']:>9.2f}")
    if not clean:
        print("\nwarning: the lab did not stop cleanly", file=sys.stderr)


if __name__ == "__main__":
    main()
