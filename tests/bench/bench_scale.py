"""The mesh at scale: `twinmesh up fleet --fleet N` for N = 10, 100, 1,000 (10,000 with --large).

Two topologies, measured in the same run:
- **star** (now): every device and service a Zenoh client of the host's router, no shared memory;
- **mesh** (the baseline, the old topology): every process a Zenoh peer (each links to every other
  peer), shared memory on (`twinmesh --mode peer --shared-memory up fleet`). It is run up to the
  first N where it fails; larger N are not tried.

For each: start-up time until the `ready` line (the idle windows start as soon as all are listed, and as
soon as the sensors' writes are answered: whatever work is left then counts as idle, an upper bound);
RSS, descriptors and threads of the fleet
processes (per process and per device) and of the whole lab; idle CPU of the whole lab over
10 s (the climate sensors publish every second); `/things?limit=100` latency; readproperty
p50/p99 to random devices over HTTP and over Zenoh; property-change fan-out to 10 SSE observers.

    python tests/bench/bench_scale.py [--sizes 10,100,1000] [--large] [--only star] [--hosts 10 [--direct]]
                                      [--soak S]

With `--hosts H` (root: Linux network namespaces, tests/netns.py) each fleet is spread over H hosts:
the lab and its adapter on the first, `up fleet --join` on the others (each with its gateway, or with
`--direct` none: their devices link straight to the lab's router); figures sum all hosts.
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import random
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import httpx
import psutil

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs
sys.path.insert(0, str(Path(__file__).resolve().parents[2]))  # the repository: tests.netns

from labs import free_port, stop_process, twinmesh_cmd  # noqa: E402

TOPOLOGIES = {"star": [], "mesh": ["--mode", "peer", "--shared-memory"]}
READY_LIMIT = 240.0  # s a fleet may take to be ready before the size counts as failed
IDLE_WINDOW = 10.0   # s of idle CPU measurement
READS = 400
OBSERVERS, CHANGES = 10, 20


def _pct(values: list[float], q: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, int(q * len(values)))]


def _lab_processes(root: psutil.Process) -> list[psutil.Process]:
    return [root, *root.children(recursive=True)]


def _figures(procs: list[psutil.Process]) -> dict:
    rss = pss = fds = threads = 0
    fleet = []
    for p in procs:
        try:
            m, f, t = p.memory_info().rss, p.num_fds(), p.num_threads()
            pss += p.memory_full_info().pss  # shared pages (Zenoh's library in each process) counted once
            title = " ".join(p.cmdline())
        except psutil.Error:
            continue
        rss, fds, threads = rss + m, fds + f, threads + t
        if title.startswith("twinmesh: fleet "):
            fleet.append((m, f, t))
    return {"rss": rss, "pss": pss, "fds": fds, "threads": threads, "fleet": fleet}


def _idle_cpu(procs: list[psutil.Process]) -> float:
    """Share of one core the whole lab uses over IDLE_WINDOW (%)."""
    def cpu() -> float:
        total = 0.0
        for p in procs:
            try:
                t = p.cpu_times()
                total += t.user + t.system
            except psutil.Error:
                pass
        return total
    a = cpu()
    time.sleep(IDLE_WINDOW)
    return (cpu() - a) / IDLE_WINDOW * 100


def _by_role(procs: list[psutil.Process]) -> dict[str, tuple[float, float]]:
    """CPU seconds so far and RSS (MB) summed by role (`twinmesh: router`, `fleet`, `adapter`, ...)."""
    out: dict[str, tuple[float, float]] = {}
    for p in procs:
        try:
            title = " ".join(p.cmdline())
            t, m = p.cpu_times(), p.memory_info().rss / 2**20
        except psutil.Error:
            continue
        role = title.removeprefix("twinmesh: ").split(" ")[0] if title.startswith("twinmesh: ") else "other"
        cpu, rss = out.get(role, (0.0, 0.0))
        out[role] = (cpu + t.user + t.system, rss + m)
    return out


def _quiet(base: str, devices: list[str]) -> int:
    """Every climate sensor's `interval` set to an hour over HTTP: then no device publishes on its own
    (the issue's idle). Returns how many were set."""
    from concurrent.futures import ThreadPoolExecutor

    climate = [d for d in devices if d.startswith("climate-")]
    with httpx.Client(timeout=30) as c, ThreadPoolExecutor(8) as pool:
        codes = list(pool.map(lambda d: c.put(f"{base}/{d}/properties/interval", json=3600).status_code, climate))
    bad = [code for code in codes if code not in (200, 204)]
    assert not bad, f"{len(bad)} writes of interval failed: {bad[:5]}"
    return len(climate)


def _http_reads(base: str, devices: list[str]) -> list[float]:
    targets = {"belt": "speed", "infrared": "objectPresence", "color": "lux", "light": "lightState",
               "climate": "humidity"}
    out = []
    with httpx.Client(timeout=10) as c:
        for _ in range(READS):
            d = random.choice(devices)
            t = time.perf_counter()
            r = c.get(f"{base}/{d}/properties/{targets[d.split('-')[0]]}")
            out.append((time.perf_counter() - t) * 1000)
            assert r.status_code == 200, r.text
    return out


def _zenoh_reads(endpoint: str, devices: list[str]) -> list[float]:
    """Reads of random devices over Zenoh, from a process of their own (the names go on stdin: 10,000
    of them do not fit on a command line)."""
    sample = devices[:20] + random.choices(devices, k=READS)
    code = f"""
import json, sys, time
from mesh.fabric.mesh_client import MeshClient
from mesh.fabric.session import one_shot_session
from mesh.fabric.settings import MeshSettings
targets = {{"belt": "speed", "infrared": "objectPresence", "color": "lux", "light": "lightState", "climate": "humidity"}}
devices = json.load(sys.stdin)
s = MeshSettings(connect=({endpoint!r},))
with one_shot_session(s) as session:
    c = MeshClient(session, s)
    for d in devices[:20]:
        c.read(d, targets[d.split('-')[0]])
    out = []
    for d in devices[20:]:
        t = time.perf_counter(); c.read(d, targets[d.split('-')[0]]); out.append((time.perf_counter() - t) * 1000)
print(json.dumps(out))
"""
    r = subprocess.run([sys.executable, "-c", code], input=json.dumps(sample), capture_output=True, text=True,
                       timeout=300)
    if r.returncode != 0:
        raise RuntimeError(r.stderr[-500:])
    return json.loads(r.stdout.strip().splitlines()[-1])


def _fan_out(base: str, light: str) -> list[float]:
    """ms from each PUT of lightState to its arrival at each of OBSERVERS SSE observers."""
    arrivals: list[list[tuple[float, bool]]] = [[] for _ in range(OBSERVERS)]
    ready = threading.Barrier(OBSERVERS + 1)

    def observe(i: int) -> None:
        with httpx.stream("GET", f"{base}/{light}/properties/lightState/sse", timeout=60) as r:
            ready.wait()
            for line in r.iter_lines():
                if line.startswith("data:"):
                    arrivals[i].append((time.perf_counter(), json.loads(line[5:])))
                    if len(arrivals[i]) >= CHANGES:
                        return
    threads = [threading.Thread(target=observe, args=(i,), daemon=True) for i in range(OBSERVERS)]
    for t in threads:
        t.start()
    ready.wait()
    time.sleep(0.5)
    sent = []
    with httpx.Client(timeout=10) as c:
        for k in range(CHANGES):
            sent.append(time.perf_counter())
            c.put(f"{base}/{light}/properties/lightState", json=k % 2 == 0)
            time.sleep(0.1)
    for t in threads:
        t.join(10)
    return [(got[k][0] - sent[k]) * 1000 for got in arrivals for k in range(min(len(got), CHANGES))]


def _soak(procs: list[psutil.Process], seconds: float) -> dict:
    """Whole-lab RSS (MB) and descriptors sampled 11 times over `seconds`: what a week-long run would grow."""
    samples = []
    for k in range(11):
        if k:
            time.sleep(seconds / 10)
        f = _figures(procs)
        samples.append((f["rss"] / 2**20, f["fds"], f["threads"]))
    return {"seconds": seconds, "samples": samples}


def _failure(text: str) -> str:
    lines = text.strip().splitlines() or ["exited"]
    causes = [line for line in lines if re.search(r"OS error|Too many|ZError|Unable to", line)]
    return (causes or lines)[0][-160:].replace("|", "/")


def _wait_line(log: Path, proc: subprocess.Popen, pattern: str, started: float, limit: float) -> str | None:
    """None once `pattern` is in the log; otherwise why not (the process ended, or `limit` s passed)."""
    while time.monotonic() - started < limit:
        text = log.read_text(errors="replace")
        if re.search(pattern, text):
            return None
        if proc.poll() is not None:
            return _failure(text)
        time.sleep(0.2)
    return f"not ready within {limit:.0f} s"


def measure(topology: str, n: int, tmp: Path, hosts: int = 1, soak: float = 0.0,
            limit: float = READY_LIMIT, direct: bool = False) -> dict:
    """One fleet of `n` devices; with `hosts` > 1, spread over that many network namespaces: the lab (and
    its adapter) on the first, `up fleet --join` on the others. With `soak` > 0, the lab then runs on that
    many seconds more (the sensors publishing) while its RSS and descriptors are sampled. `direct`: the
    other hosts run no router, their devices link straight to the lab's router (`--join --direct`)."""
    from contextlib import ExitStack

    from devices.things.fleet import KINDS, fleet_names

    with ExitStack() as stack:
        if hosts > 1:
            from tests import netns

            net = stack.enter_context(netns.hosts(hosts))
            lab_host = net.hosts[0]
            endpoint, address = f"tcp/{lab_host.address}:7447", f"{lab_host.address}:8080"
        else:
            endpoint, address = f"tcp/127.0.0.1:{free_port()}", f"127.0.0.1:{free_port()}"
        base = f"http://{address}"
        share = -(-n // hosts // len(KINDS)) * len(KINDS)  # devices per host, whole stations
        counts = [min(share, n - i * share) for i in range(hosts)]
        log = tmp / f"{topology}-{n}.log"
        args = [*TOPOLOGIES[topology], "up", "fleet", "--fleet", str(counts[0]), "--http", address, "--no-view"]
        started = time.monotonic()
        if hosts > 1:
            proc = net.hosts[0].popen(twinmesh_cmd(endpoint, *args), log)
        else:
            proc = subprocess.Popen(twinmesh_cmd(endpoint, *args), stdout=open(log, "wb"),
                                    stderr=subprocess.STDOUT, start_new_session=True)
            stack.callback(stop_process, proc, 30)
        roots = [proc]
        why = _wait_line(log, proc, r"ready: \d+ Things", started, limit)
        if why:
            return {"failed": why}
        devices = fleet_names(counts[0])
        joining = time.monotonic()  # the other hosts' fleets start now
        for i in range(1, hosts):
            if counts[i] <= 0:
                continue
            first = 1 + i * share // len(KINDS)
            join_log = tmp / f"{topology}-{n}-host{i}.log"
            roots.append(net.hosts[i].popen(twinmesh_cmd("tcp/127.0.0.1:7447", *TOPOLOGIES[topology], "up", "fleet",
                                                         "--fleet", str(counts[i]), "--fleet-first", str(first),
                                                         "--join", endpoint, *(["--direct"] if direct else [])),
                                             join_log))
            devices += fleet_names(counts[i], first)
        for i, root in enumerate(roots[1:], start=1):
            why = _wait_line(tmp / f"{topology}-{n}-host{i}.log", root, r"ready", started, limit)
            if why:
                return {"failed": f"host {i}: {why}"}
        while len(httpx.get(base + "/", timeout=30).json()) < len(devices) + 1:  # and tdgen
            if time.monotonic() - started > limit:
                return {"failed": f"not all listed by the adapter within {limit:.0f} s"}
            time.sleep(0.2)
        ready_s = time.monotonic() - started
        joined_s = time.monotonic() - joining
        procs = [p for root in roots for p in _lab_processes(psutil.Process(root.pid))]
        at_ready = _by_role(procs)
        figures = _figures(procs)
        idle = _idle_cpu(procs)  # the climate sensors publishing every second
        quieted = _quiet(base, devices)  # answered: each sensor now waits an hour (a reading already due may come)
        before = _by_role(procs)
        quiet = _idle_cpu(procs)  # no device publishing on its own
        after = _by_role(procs)
        roles = {role: (at_ready.get(role, (0.0, 0.0))[0], (after[role][0] - before.get(role, (0.0, 0.0))[0])
                        / IDLE_WINDOW * 100, after[role][1]) for role in after}
        with httpx.Client(timeout=30) as c:
            c.get(f"{base}/things?limit=100")
            things_ms = []
            for _ in range(10):
                t = time.perf_counter()
                assert c.get(f"{base}/things?limit=100").status_code == 200
                things_ms.append((time.perf_counter() - t) * 1000)
        http = _http_reads(base, devices)
        zen = _zenoh_reads(endpoint, devices)
        lights = [d for d in devices if d.startswith("light-")]
        fan = _fan_out(base, lights[0]) if lights else []
        drift = _soak(procs, soak) if soak > 0 else None
        return {"soak": drift, "ready": ready_s, "joined": joined_s, **figures, "idle": idle, "quiet": quiet,
                "quieted": quieted,
                "roles": roles, "things": statistics.median(things_ms),
                "http": (_pct(http, 0.5), _pct(http, 0.99)), "zenoh": (_pct(zen, 0.5), _pct(zen, 0.99)),
                "fan": (_pct(fan, 0.5), _pct(fan, 0.99), len(fan)), "hosts": hosts, "direct": direct}


def row(topology: str, n: int, r: dict) -> str:
    if "failed" in r:
        return f"| {topology} | {n:,} | fails: {r['failed']} |" + " |" * 9
    fleet = r["fleet"]
    per_rss = sum(m for m, _, _ in fleet) / 2**20
    per_fds = sum(f for _, f, _ in fleet)
    per_thr = sum(t for _, _, t in fleet)
    where = (f" ({r['hosts']} hosts{', direct' if r.get('direct') else ', a gateway each'})"
             if r.get("hosts", 1) > 1 else "")
    joined = f" ({r['joined']:.1f} s after the other hosts' fleets started)" if r.get("hosts", 1) > 1 else ""
    return (f"| {topology}{where} | {n:,} | {r['ready']:.1f} s{joined} | {per_rss:.0f} MB / {per_fds:,} / {per_thr} "
            f"({len(fleet)} proc.) | {r['rss'] / 2**20:.0f} MB, PSS {r['pss'] / 2**20:.0f} MB "
            f"({r['pss'] / 1024 / n:.0f} KiB/device) / {r['fds']:,} / "
            f"{r['threads']} | {r['idle']:.1f} % / {r['quiet']:.1f} % | "
            f"{r['things']:.1f} ms | {r['http'][0]:.2f} / {r['http'][1]:.2f} ms | "
            f"{r['zenoh'][0]:.2f} / {r['zenoh'][1]:.2f} ms | {r['fan'][0]:.1f} / {r['fan'][1]:.1f} ms ({r['fan'][2]}) |")


HEADER = ("| topology | devices | all listed by the adapter, from the lab's start | fleet processes: RSS / fds / threads "
          "| whole lab: RSS, PSS / fds / threads | "
          "idle CPU of one core: sensors publishing / none | /things first page | HTTP read p50 / p99 | "
          "Zenoh read p50 / p99 | "
          f"fan-out to {OBSERVERS} p50 / p99 (deliveries) |\n|" + "---|" * 10)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--sizes", default="10,100,1000")
    ap.add_argument("--large", action="store_true", help="also 10,000 devices")
    ap.add_argument("--only", choices=sorted(TOPOLOGIES))
    ap.add_argument("--ready-limit", type=float, default=READY_LIMIT, metavar="S",
                    help=f"seconds a fleet may take to be ready before its size counts as failed [{READY_LIMIT:g}]")
    ap.add_argument("--soak", type=float, default=0.0, metavar="S", help="after the figures, keep each lab "
                    "running S seconds more and print its RSS and descriptors over that time")
    ap.add_argument("--hosts", type=int, default=1, help="spread each fleet over this many network namespaces "
                    "(needs root): the lab on the first, `up fleet --join` on the others")
    ap.add_argument("--direct", action="store_true", help="with --hosts: the other hosts' devices link straight "
                    "to the lab's router (`up fleet --join ENDPOINT --direct`), no router on those hosts")
    ap.add_argument("--keep", metavar="DIR", help="write the labs' logs into DIR and keep them")
    args = ap.parse_args()
    sizes = [int(s) for s in args.sizes.split(",")] + ([10_000] if args.large else [])
    results: dict[str, dict[int, dict]] = {}
    with (tempfile.TemporaryDirectory() if not args.keep else contextlib.nullcontext(args.keep)) as tmp:
        for topology in [args.only] if args.only else list(TOPOLOGIES):
            results[topology] = {}
            for n in sizes:
                r = measure(topology, n, Path(tmp), args.hosts, args.soak, args.ready_limit, args.direct)
                results[topology][n] = r
                print(row(topology, n, r), flush=True)
                if "roles" in r:
                    print("  by process kind: CPU s until listed; idle % of a core (none publishing); RSS MB: " + "; ".join(
                        f"{role} {cpu:.1f} s, {idle:.1f} %, {rss:.0f} MB"
                        for role, (cpu, idle, rss) in sorted(r["roles"].items(), key=lambda kv: -kv[1][0])), flush=True)
                if r.get("soak"):
                    first, last = r["soak"]["samples"][0], r["soak"]["samples"][-1]
                    hours = r["soak"]["seconds"] / 3600
                    print(f"  soak {topology} {n:,}: {r['soak']['seconds']:.0f} s, whole-lab RSS "
                          + " ".join(f"{m:.0f}" for m, _, _ in r["soak"]["samples"])
                          + f" MB ({(last[0] - first[0]) / hours:+.1f} MB/h), descriptors {first[1]} -> {last[1]}, "
                          f"threads {first[2]} -> {last[2]}", flush=True)
                if "failed" in r:
                    break
    print(f"\nmachine: {os.cpu_count()} cores; per-device cost beyond a process's fixed cost (star, between the two "
          "largest sizes):")
    star = results.get("star", {})
    ok = [n for n in sizes if n in star and "failed" not in star[n]]
    if len(ok) >= 2:
        a, b = star[ok[-2]], star[ok[-1]]
        dn = ok[-1] - ok[-2]
        rss = (sum(m for m, _, _ in b["fleet"]) - sum(m for m, _, _ in a["fleet"])) / dn / 2**20
        fds = (sum(f for _, f, _ in b["fleet"]) - sum(f for _, f, _ in a["fleet"])) / dn
        print(f"  {rss * 1024:.0f} KiB RSS and {fds:.2f} descriptors per device ({ok[-2]:,} -> {ok[-1]:,})")
    print()
    print(HEADER)
    for topology, by_n in results.items():
        for n, r in by_n.items():
            print(row(topology, n, r))


if __name__ == "__main__":
    main()
