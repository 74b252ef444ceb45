"""HTTP under load: readproperty at 10 and 50 keep-alive connections, and 500 SSE observers of one
property, the twinmesh adapter beside node-wot 0.9.2's own servient, measured in one run.

The load comes from another process: `wrk` when it is on PATH, else an asyncio generator of raw
HTTP/1.1 keep-alive requests (the server, not the client, is the limit: one process, no parsing
beyond the framing). Each server is measured for `--seconds` per connection count, alternating
adapter / node-wot, after a warm-up. Then 500 SSE connections observe `lightState` and the bench
writes it 100 times (one write every 20 ms): every observer must receive every change; the
delivery time is from just before the write's request to the event's arrival.

    python tests/bench/bench_http_load.py [--seconds 8] [--observers 500] [--changes 100]

Client and servers share this machine's cores: the ratios (adapter / node-wot) are the figures to
read. Throughput ratio > 1 and latency ratio < 1 mean the adapter is ahead.
"""
from __future__ import annotations

import argparse
import asyncio
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, interop

from interop import npm  # noqa: E402
from labs import start_lab  # noqa: E402

CONNECTIONS = (10, 50)


# --- the load generator (run as `--generate URL CONNECTIONS SECONDS` in its own process) --------------
async def generate(url: str, connections: int, seconds: float) -> dict:
    parsed = httpx.URL(url)
    request = (f"GET {parsed.raw_path.decode()} HTTP/1.1\r\nHost: {parsed.host}:{parsed.port}\r\n"
               f"Accept: application/json\r\n\r\n").encode()
    times: list[float] = []
    warm_until = time.perf_counter() + 1.0
    stop_at = warm_until + seconds

    async def worker() -> None:
        reader, writer = await asyncio.open_connection(parsed.host, parsed.port)
        while (t0 := time.perf_counter()) < stop_at:
            writer.write(request)
            head = (await reader.readuntil(b"\r\n\r\n")).lower()
            if not head.startswith(b"http/1.1 200"):
                raise RuntimeError(head.decode())
            if b"transfer-encoding: chunked" in head:  # node-wot streams its replies
                while (size := int((await reader.readuntil(b"\r\n")).strip(), 16)):
                    await reader.readexactly(size + 2)
                await reader.readexactly(2)
            else:
                await reader.readexactly(int(head.split(b"content-length:")[1].split(b"\r\n")[0]))
            if t0 >= warm_until:
                times.append(time.perf_counter() - t0)
        writer.close()

    await asyncio.gather(*(worker() for _ in range(connections)))
    ms = np.array(times) * 1e3
    return {"rps": len(times) / seconds, "p50": float(np.percentile(ms, 50)), "p99": float(np.percentile(ms, 99))}


def _wrk(url: str, connections: int, seconds: float) -> dict:
    out = subprocess.run(["wrk", "-t2", f"-c{connections}", f"-d{int(seconds)}s", "--latency", url],
                         capture_output=True, text=True, check=True).stdout

    def ms(label: str) -> float:
        value, unit = re.search(rf"{label}%\s+([\d.]+)(us|ms|s)", out).groups()  # type: ignore[union-attr]
        return float(value) * {"us": 1e-3, "ms": 1.0, "s": 1e3}[unit]

    rps = float(re.search(r"Requests/sec:\s+([\d.]+)", out).group(1))  # type: ignore[union-attr]
    return {"rps": rps, "p50": ms("50"), "p99": ms("99")}


def load(url: str, connections: int, seconds: float) -> dict:
    if shutil.which("wrk"):
        return _wrk(url, connections, seconds)
    out = subprocess.run([sys.executable, __file__, "--generate", url, str(connections), str(seconds)],
                         capture_output=True, text=True, check=True).stdout
    return json.loads(out.strip().splitlines()[-1])


# --- SSE fan-out ------------------------------------------------------------------------------------
async def fan_out(base: str, sse_url: str, observers: int, changes: int) -> dict:
    parsed = httpx.URL(sse_url)
    request = (f"GET {parsed.raw_path.decode()} HTTP/1.1\r\nHost: {parsed.host}:{parsed.port}\r\n"
               f"Accept: text/event-stream\r\n\r\n").encode()
    sent: dict[bool, list[float]] = {True: [], False: []}
    received: list[list[tuple[float, str]]] = [[] for _ in range(observers)]
    ready = asyncio.Event()
    opened = 0

    async def observe(i: int) -> None:
        nonlocal opened
        reader, writer = await asyncio.open_connection(parsed.host, parsed.port, limit=1 << 20)
        writer.write(request)
        head = await reader.readuntil(b"\r\n\r\n")
        if not head.lower().startswith(b"http/1.1 200"):
            raise RuntimeError(head.decode())
        opened += 1
        if opened == observers:
            ready.set()
        try:
            while True:
                line = await reader.readline()
                if not line:
                    return
                if b"data:" in line:
                    received[i].append((time.perf_counter(), line.split(b"data:", 1)[1].strip().decode()))
        except (asyncio.CancelledError, ConnectionError):
            return
        finally:
            writer.close()

    tasks = [asyncio.create_task(observe(i)) for i in range(observers)]
    await asyncio.wait_for(ready.wait(), 60)
    await asyncio.sleep(0.5)  # every stream registered on the server
    async with httpx.AsyncClient() as client:
        state = False
        for _ in range(changes):
            state = not state
            sent[state].append(time.perf_counter())
            r = await client.put(f"{base}/light-left/properties/lightState", json=state)
            r.raise_for_status()
            await asyncio.sleep(0.02)
    await asyncio.sleep(2.0)
    for t in tasks:
        t.cancel()
    await asyncio.gather(*tasks, return_exceptions=True)
    delays, complete = [], 0
    for got in received:
        values = [(at, json.loads(v)) for at, v in got if v in ("true", "false")]
        if len(values) >= changes:
            complete += 1
        index = {True: 0, False: 0}
        for at, v in values[-changes:]:
            if index[v] < len(sent[v]):
                delays.append(at - sent[v][index[v]])
                index[v] += 1
    ms = np.array(delays) * 1e3
    return {"complete": complete, "observers": observers, "p50": float(np.percentile(ms, 50)),
            "p99": float(np.percentile(ms, 99)), "deliveries": len(delays)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=8.0)
    ap.add_argument("--observers", type=int, default=500)
    ap.add_argument("--changes", type=int, default=100)
    ap.add_argument("--generate", nargs=3, help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.generate:
        url, connections, seconds = args.generate
        print(json.dumps(asyncio.run(generate(url, int(connections), float(seconds)))))
        return

    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp, npm.start_baseline_servient() as servient:
        lab = start_lab(Path(tmp), "lights", http=True, things={"light-left"})
        try:
            urls = {"adapter": f"{lab.http}/light-left/properties/lightState",
                    "node-wot": f"http://127.0.0.1:{servient.port}/light-left/properties/lightState"}
            for c in CONNECTIONS:
                for name, url in urls.items():
                    results[f"{name} {c}"] = load(url, c, args.seconds)
            fans = {"adapter": asyncio.run(fan_out(lab.http, f"{urls['adapter']}/sse", args.observers, args.changes)),
                    "node-wot": asyncio.run(fan_out(f"http://127.0.0.1:{servient.port}",
                                                    f"{urls['node-wot']}/sse", args.observers, args.changes))}
        finally:
            lab.stop()

    generator = "wrk" if shutil.which("wrk") else "asyncio raw keep-alive generator, own process"
    print(f"readproperty light-left/lightState, {args.seconds:g} s per run after 1 s warm-up ({generator})")
    print(f"{'connections':<12} {'server':<10} {'req/s':>9} {'p50 ms':>8} {'p99 ms':>8}")
    for c in CONNECTIONS:
        ours, theirs = results[f"adapter {c}"], results[f"node-wot {c}"]
        for name, r in (("adapter", ours), ("node-wot", theirs)):
            print(f"{c:<12} {name:<10} {r['rps']:>9.0f} {r['p50']:>8.2f} {r['p99']:>8.2f}")
        print(f"{c:<12} {'ratio':<10} {ours['rps'] / theirs['rps']:>9.2f} {ours['p50'] / theirs['p50']:>8.2f} "
              f"{ours['p99'] / theirs['p99']:>8.2f}")
    print(f"\n{args.observers} SSE observers of lightState, {args.changes} writes 20 ms apart")
    print(f"{'server':<10} {'observers with every change':>28} {'deliveries':>11} {'p50 ms':>8} {'p99 ms':>8}")
    for name, f in fans.items():
        print(f"{name:<10} {f['complete']:>20} of {f['observers']:<5} {f['deliveries']:>11} {f['p50']:>8.2f} "
              f"{f['p99']:>8.2f}")


if __name__ == "__main__":
    main()
