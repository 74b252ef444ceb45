"""The guard's price: an accepted uArm move through the guarding twin against the same move sent straight
to the "real" uArm (the mock real lab, tests/interop/real-lab.mjs), p50 and p99, side by side.

Three ways of one `goTo`, alternating between two points so that every call is a move:
- direct: POST to the real uArm's own form (what a client without a twin does);
- twin alone: POST to the adapter of a lab without --real (the twin's check and its simulated motion);
- guarded: POST to the adapter of a lab with --real uarm=... (the twin's check, the forward to the real
  uArm and its answer, then the twin's motion).
guarded - direct is what the guard adds to a client's call; guarded - twin alone is what the forward
adds to the twin. Both labs run the simulation as fast as the machine allows (`--speed max`).

    python tests/bench/bench_guard.py [--moves 200]
"""
from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, interop

from interop import npm  # noqa: E402
from labs import start_lab  # noqa: E402

CREDENTIALS = {"username": "lab", "password": "bench"}
POINTS = [{"x": 160, "y": -40, "z": 70}, {"x": 170, "y": 40, "z": 80}]
WARMUP = 10


def timed_moves(client: httpx.Client, url: str, n: int) -> np.ndarray:
    for i in range(WARMUP):
        client.post(url, json=POINTS[i % 2]).raise_for_status()
    times = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        client.post(url, json=POINTS[i % 2]).raise_for_status()
        times[i] = time.perf_counter() - t0
    return times * 1e3


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--moves", type=int, default=200)
    args = parser.parse_args()
    auth = (CREDENTIALS["username"], CREDENTIALS["password"])
    with tempfile.TemporaryDirectory() as tmp, npm.RealLab(CREDENTIALS) as real:
        results: dict[str, np.ndarray] = {}
        with httpx.Client(auth=auth, timeout=60) as client:
            results["direct"] = timed_moves(client, f"{real.base}/uarm/actions/goto", args.moves)
        plain = start_lab(Path(tmp), "iot-platform", extra_args=("--speed", "max"))
        try:
            with httpx.Client(timeout=60) as client:
                results["twin alone"] = timed_moves(client, f"{plain.http}/uarm/actions/goTo", args.moves)
        finally:
            plain.stop()
        guarded = start_lab(Path(tmp), "iot-platform", extra_args=(
            "--speed", "max", "--real", f"uarm={real.url('Uarm')}",
            "--real-auth", f"basic:{CREDENTIALS['username']}:{CREDENTIALS['password']}"))
        try:
            with httpx.Client(timeout=60) as client:
                results["guarded"] = timed_moves(client, f"{guarded.http}/uarm/actions/goTo", args.moves)
        finally:
            guarded.stop()
    print(f"uArm goTo, {args.moves} moves each, alternating between two points (ms)")
    print(f"{'path':<12} {'p50':>8} {'p99':>8} {'mean':>8}")
    for name, t in results.items():
        print(f"{name:<12} {np.percentile(t, 50):8.2f} {np.percentile(t, 99):8.2f} {t.mean():8.2f}")
    g, d, a = ({q: np.percentile(results[k], q) for q in (50, 99)} for k in ("guarded", "direct", "twin alone"))
    print(f"guard's added latency over a direct call: p50 {g[50] - d[50]:.2f} ms, p99 {g[99] - d[99]:.2f} ms "
          f"(ratio p50 {g[50] / d[50]:.1f}x)")
    print(f"forward's added latency over the twin alone: p50 {g[50] - a[50]:.2f} ms, p99 {g[99] - a[99]:.2f} ms")


if __name__ == "__main__":
    main()
