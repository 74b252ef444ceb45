"""What makes Rerun's web viewer fall behind a live stream: a synthetic load, one factor at a time.

    python tests/bench/bench_viewer_capacity.py [--entities 8] [--rate 10] [--kind frames] [--plots 2]
        [--window 60] [--triangles 100000] [--viewport 1280x800] [--busy] [--newest] [--seconds 90]
    python tests/bench/bench_viewer_capacity.py --matrix [NAME ...]

A logger process streams to `rr.GrpcServerSink` exactly as the live view does (`mesh.recorder.view`:
the same batcher tick, server memory limit and `newest_first`), served by `mesh.recorder.web_viewer`,
and writes what the drawer writes: one `send_columns` per entity every `view.BATCH` seconds, so the
stream carries `entities / BATCH` chunks a second of `rate * BATCH` rows each. `--kind` is what the
rows are: `scalars` (plotted when `--plots` > 0), `transforms` (an entity's own pose) or `frames`
(rows naming transform frames, six per entity, like the lab's `world/poses` and robot joints). The
3D view also draws a static wall of `--triangles` triangles behind the clock. The blueprint is the
lab's layout: the 3D view beside `--plots` time-series views of the last `--window` seconds.
`--newest` sends what the live view sends since issue 50: each frame's newest row per flush.

A headless Chromium (software WebGL, as in the browser tests) opens the page and reads the logger's
clock (three boxes whose colours change every `CLOCK_STEP`) from a screenshot every `--every` seconds
for `--seconds`: how far behind the logger the page draws, over time. At the end it counts the page's
frames a second (requestAnimationFrame callbacks: the viewer takes in data for about 10 ms per frame
it draws, so frames a second bound what it can take in). `--busy` runs two CPU-bound processes beside
it, as `.ci/busy` does. Each configuration prints one table row; figures on a shared 2-core machine
are noisy (the browser's CPU in the row says what share it got).
"""
from __future__ import annotations

import argparse
import dataclasses
import itertools
import json
import subprocess
import sys
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, rerun_view

from browser import chromium  # noqa: E402
from rerun_view import ViewerPage  # noqa: E402
from waiting import seconds_until  # noqa: E402

# The logger's clock: three boxes in three of six pure colours (channels 0 or 1: the view's shading keeps
# their hue), a permutation a CLOCK_STEP; a screenshot's permutation says which moment the page shows.
COLOURS = [(255, 0, 0), (0, 255, 0), (0, 0, 255), (0, 255, 255), (255, 0, 255), (255, 255, 0)]
PERMUTATIONS = list(itertools.permutations(range(len(COLOURS)), 3))
CLOCK_STEP = 2.5  # s
CLOCK_PERIOD = CLOCK_STEP * len(PERMUTATIONS)
CLOCK_AT = [[-0.6, 0.6, 0.2], [0.0, 0.0, 0.2], [0.6, -0.6, 0.2]]  # left to right in the view
FRAMES_PER_ENTITY = 6
FPS_SCRIPT = """() => new Promise(done => {
  let n = 0; const t0 = performance.now();
  const tick = () => { n++; const dt = performance.now() - t0;
    if (dt < 5000) requestAnimationFrame(tick); else done(n / (dt / 1000)); };
  requestAnimationFrame(tick);
})"""


@dataclasses.dataclass(frozen=True)
class Load:
    """One configuration: what the stream carries and how the page shows it."""

    entities: int = 8
    rate: float = 10.0  # rows a second per entity
    kind: str = "frames"
    plots: int = 2
    window: float = 60.0  # s each plot shows
    triangles: int = 100_000
    viewport: str = "1280x800"
    busy: bool = False
    newest: bool = False  # the live view's thinning: each frame's newest row per flush (`mesh.recorder.live_rows`)
    log_rows: int = 0  # log lines of the past hour sent first, and a log view (all of it: Rerun's has no time range)
    log_rate: float = 0.0  # log lines a second

    def label(self, base: "Load") -> str:
        changed = [f"{f.name}={getattr(self, f.name)}" for f in dataclasses.fields(self)
                   if getattr(self, f.name) != getattr(base, f.name)]
        return ", ".join(changed) or "base"


BASE = Load()
MATRIX = {  # one factor at a time from BASE
    "base": [BASE],
    "scene": [Load(triangles=0), Load(triangles=1_000_000)],
    "viewport": [Load(viewport="640x400")],
    "plots": [Load(plots=0), Load(kind="scalars", window=600.0)],
    "chunks": [Load(entities=1), Load(entities=32)],
    "rows": [Load(rate=100.0)],
    "kind": [Load(kind="scalars")],
    "busy": [Load(busy=True)],
    "newest": [BASE, Load(newest=True), Load(rate=100.0, newest=True)],
    "log": [Load(newest=True, log_rate=3.0), Load(newest=True, log_rows=20_000, log_rate=3.0)],
}


# --- the logger process ---------------------------------------------------------------------------

def serve(load: Load, port: int, grpc_port: int) -> None:
    """Stream `load` as the live view streams the lab; log the probe in each colour named on stdin."""
    import numpy as np
    import rerun as rr
    import rerun.blueprint as rrb

    from mesh.process import install_stop_handlers
    from mesh.recorder.live_rows import NewestTransforms
    from mesh.recorder.view import BATCH, MEMORY
    from mesh.recorder.web_viewer import ViewerServer, viewer_url

    stop = install_stop_handlers()  # the bench's Ctrl-C (stop_process) ends the logger's loops below
    stream = rr.RecordingStream("viewer-capacity", batcher_config=rr.ChunkBatcherConfig(flush_tick=BATCH))
    stream.set_sinks(rr.GrpcServerSink(bind_ip="127.0.0.1", port=grpc_port, server_memory_limit=MEMORY,
                                       newest_first=True))
    sent = NewestTransforms(stream) if load.newest else stream
    viewer = ViewerServer(("127.0.0.1", port), grpc_port)
    lock = threading.Lock()
    recent = [rrb.VisibleTimeRange("time", start=rrb.TimeRangeBoundary.cursor_relative(seconds=-load.window),
                                   end=rrb.TimeRangeBoundary.cursor_relative())]
    plots = [rrb.TimeSeriesView(origin=f"/plots/{p}", time_ranges=recent) for p in range(load.plots)]
    logs = [rrb.TextLogView(origin="/", name="log")] if load.log_rows or load.log_rate else []
    side = rrb.Vertical(*plots, *logs) if plots or logs else rrb.TextLogView(origin="/log")
    eye = rrb.EyeControls3D(position=(-2.5, -2.5, 1.5), look_target=(0.0, 0.0, 0.0), eye_up=(0.0, 0.0, 1.0))
    stream.send_blueprint(rrb.Blueprint(
        rrb.Horizontal(rrb.Spatial3DView(origin="/scene", eye_controls=eye), side, column_shares=[3, 2]),
        rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
        rrb.TimePanel(timeline="time", state="collapsed", play_state="following")))
    if load.triangles:
        stream.log("/scene/wall", _wall(load.triangles), static=True)
    for i in range(load.entities):
        if load.kind == "transforms":
            stream.log(f"/scene/load/{i}", _small_box(), static=True)
        elif load.kind == "frames":
            for f in range(FRAMES_PER_ENTITY):
                stream.log(f"/scene/bodies/{i}/{f}", _small_box(), rr.CoordinateFrame(f"body_{i}_{f}"), static=True)
    if load.log_rows:
        past = time.time() - 3600 + np.arange(load.log_rows) * 3600 / load.log_rows
        stream.send_columns("/things/log", [rr.TimeColumn("time", timestamp=past)],
                            rr.TextLog.columns(text=[f"line {k}: detectColor cube-red" for k in range(load.log_rows)]))
    print(f"serving {viewer_url('127.0.0.1', port, grpc_port)}", flush=True)

    def clock() -> None:
        while not stop.is_set():
            now = time.time()
            with lock:
                stream.set_time("time", timestamp=now)
                stream.log("/scene/clock", rr.Boxes3D(centers=CLOCK_AT, half_sizes=[[0.2] * 3] * 3,
                                                      colors=clock_colours(now), fill_mode="solid"))
            stop.wait(CLOCK_STEP - now % CLOCK_STEP)  # the clock's next step, or the stop

    threading.Thread(target=clock, daemon=True).start()
    rows = max(1, round(load.rate * BATCH))
    tick = 0
    while not stop.is_set():
        started = time.time()
        times = started - BATCH + (np.arange(rows) + 1) * BATCH / rows
        with lock:
            for i in range(load.entities):
                _send(sent, load.kind, i, times, tick, load.plots)
            lines = int((tick + 1) * load.log_rate * BATCH) - int(tick * load.log_rate * BATCH)
            for k in range(lines):
                stream.set_time("time", timestamp=started)
                stream.log(f"/things/log{k % 3}", rr.TextLog(f"tick {tick}: returnCube() in 1.34 s"))
        tick += 1
        stop.wait(max(0.0, started + BATCH - time.time()))  # the next batch, or the stop
    viewer.close()


def _send(stream, kind: str, i: int, times, tick: int, plots: int) -> None:
    import numpy as np
    import rerun as rr

    n = len(times)
    phase = tick * n + np.arange(n)
    if kind == "scalars":
        stream.send_columns(f"/plots/{i % max(plots, 1)}/{i}", [rr.TimeColumn("time", timestamp=times)],
                            rr.Scalars.columns(scalars=np.sin(phase * 0.05 + i)))
        return
    xyz = np.stack([0.8 * np.cos(phase * 0.02 + i), 0.8 * np.sin(phase * 0.02 + i), np.full(n, 0.5)], axis=1)
    if kind == "transforms":
        stream.send_columns(f"/scene/load/{i}", [rr.TimeColumn("time", timestamp=times)],
                            rr.Transform3D.columns(translation=xyz))
        return
    frames = [f"body_{i}_{f}" for f in range(FRAMES_PER_ENTITY)]
    stream.send_columns(f"/scene/poses_{i}", [rr.TimeColumn("time", timestamp=np.repeat(times, len(frames)))],
                        rr.Transform3D.columns(translation=np.repeat(xyz, len(frames), axis=0)
                                               + np.tile(np.arange(len(frames))[:, None] * 0.1, (n, 1)),
                                               child_frame=frames * n, parent_frame=["tf#/scene"] * (n * len(frames))))


def _small_box():
    import rerun as rr

    return rr.Boxes3D(half_sizes=[[0.03] * 3], colors=[[90, 90, 90]], fill_mode="solid")


def clock_colours(t: float) -> list[tuple[int, int, int]]:
    return [COLOURS[c] for c in PERMUTATIONS[int(t // CLOCK_STEP) % len(PERMUTATIONS)]]


def read_clock(pixels) -> float | None:
    """The clock's time shown in `pixels` (mid-step, modulo CLOCK_PERIOD); None: not three of its colours."""
    import numpy as np

    found = []
    for c, rgb in enumerate(COLOURS):
        mask = colour_mask(pixels, rgb)
        if mask.sum() >= 30:
            found.append((float(np.nonzero(mask)[1].mean()), int(mask.sum()), c))
    if len(found) != 3:
        return None
    order = tuple(c for _, _, c in sorted(found))
    return (PERMUTATIONS.index(order) + 0.5) * CLOCK_STEP


def colour_mask(pixels, rgb, tolerance: float = 0.12):
    px = pixels.astype(float) / 255.0
    brightness = px.max(axis=2, keepdims=True)
    target = [v / 255.0 for v in rgb]
    close = abs(px / (brightness + 1e-6) - target).max(axis=2) < tolerance
    return close & (brightness[..., 0] > 0.2)


def _wall(triangles: int):
    """A bumpy grey wall behind the probe, about `triangles` triangles."""
    import numpy as np
    import rerun as rr

    side = max(2, int((triangles / 2) ** 0.5) + 1)
    u, v = np.meshgrid(np.linspace(-2.0, 2.0, side), np.linspace(-1.0, 2.0, side))
    rng = np.random.default_rng(0)
    vertices = np.stack([u.ravel(), 1.5 + 0.02 * rng.standard_normal(u.size), v.ravel()], axis=1)
    k = np.arange(side * side).reshape(side, side)[:-1, :-1].ravel()
    faces = np.concatenate([np.stack([k, k + 1, k + side], 1), np.stack([k + 1, k + side + 1, k + side], 1)])
    return rr.Mesh3D(vertex_positions=vertices, triangle_indices=faces, albedo_factor=[150, 150, 150, 255])


# --- the measuring side ----------------------------------------------------------------------------

def measure(load: Load, seconds: float, every: float) -> dict:
    """Open the page on a fresh stream of `load`; its lag behind the logger every `every` s for `seconds`."""
    import psutil
    from labs import free_port, stop_process

    port, grpc = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, __file__, "--serve", json.dumps(dataclasses.asdict(load)), str(port),
                             str(grpc)], stdout=subprocess.PIPE, text=True, start_new_session=True)
    hogs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2 if load.busy else 0)]
    try:
        url = proc.stdout.readline().split()[-1]  # type: ignore[union-attr]
        w, h = (int(x) for x in load.viewport.split("x"))
        with chromium() as browser_app:
            view = ViewerPage(browser_app.new_page(viewport={"width": w, "height": h}), url)  # type: ignore[attr-defined]
            opened = time.perf_counter()
            first = seconds_until(lambda: lag(view) is not None, 300.0)
            browser = [p for p in psutil.Process().children(recursive=True) if "chrom" in p.name()]
            cpu0, logger0 = cpu_seconds(browser), cpu_seconds([psutil.Process(proc.pid)])
            lags: list[tuple[float, float | None]] = []
            ended = threading.Event()  # the logger gone: no sample would mean anything
            threading.Thread(target=lambda: (proc.wait(), ended.set()), daemon=True).start()
            while time.perf_counter() - opened < seconds:
                if ended.wait(max(0.0, every - (time.perf_counter() - opened) % every)):
                    raise RuntimeError(f"the logger exited ({proc.returncode}) while the page was sampled")
                lags.append((time.perf_counter() - opened, lag(view)))
            fps = view.page.evaluate(FPS_SCRIPT)
            window = time.perf_counter() - opened - (first or 0.0)
            cpu, logger = cpu_seconds(browser) - cpu0, cpu_seconds([psutil.Process(proc.pid)]) - logger0
            problems = view.rerun_problems()
        return {"first": first, "fps": fps, "lags": unwrap(lags), "browser_cpu": cpu / window,
                "logger_cpu": logger / window, "problems": problems[:3]}
    finally:
        for hog in hogs:
            hog.kill()
            hog.wait()
        stop_process(proc)


def lag(view) -> float | None:
    """How far behind the logger the page draws, modulo CLOCK_PERIOD (None: no clock in view)."""
    px = view.pixels()
    now = time.time()
    h, w, _ = px.shape
    shown = read_clock(px[round(0.1 * h): round(0.9 * h), : round(0.6 * w)])  # the 3D view: no plot colours
    return None if shown is None else (now - shown) % CLOCK_PERIOD


def unwrap(lags: list[tuple[float, float | None]]) -> list[tuple[float, float | None]]:
    """Lags read modulo CLOCK_PERIOD, made continuous (a lag moves less than half a period between reads)."""
    out: list[tuple[float, float | None]] = []
    last = None
    for t, value in lags:
        if value is not None and last is not None:
            value += CLOCK_PERIOD * round((last - value) / CLOCK_PERIOD)
        out.append((t, value))
        last = value if value is not None else last
    return out




def cpu_seconds(processes) -> float:
    """User + system CPU of `processes` (psutil), those that ended left out."""
    total = 0.0
    for p in processes:
        try:
            t = p.cpu_times()
            total += t.user + t.system
        except Exception:  # a renderer that ended
            pass
    return total


def row(load: Load, result: dict) -> str:
    lags = result["lags"]
    shown = " ".join(f"{t:.0f}:{'-' if v is None else f'{v:.0f}'}" for t, v in lags)
    known = [(t, v) for t, v in lags if v is not None]
    half = [(t, v) for t, v in known if t >= known[-1][0] / 2] if known else []
    slope = (half[-1][1] - half[0][1]) / (half[-1][0] - half[0][0]) if len(half) > 1 else float("nan")
    first = "never" if result["first"] is None else f"{result['first']:.0f}"
    return (f"| {load.label(BASE)} | {load.entities / 0.5:.0f} | {max(1, round(load.rate * 0.5))} | {first} | "
            f"{result['fps']:.1f} | {known[-1][1] if known else float('nan'):.1f} | {slope:+.2f} | {shown} | "
            f"{result['browser_cpu']:.2f} | {result['logger_cpu']:.2f} |"
            + (f" {result['problems']}" if result["problems"] else ""))


HEADER = ("| configuration (from base: {base}) | chunks/s | rows/chunk | clock first read, s | page frames/s | "
          "lag at the end, s | lag growth (s/s, 2nd half) | lag over time (s since opened: lag s) | "
          "browser CPU (cores) | logger CPU |\n|---|---|---|---|---|---|---|---|---|---|")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    for f in dataclasses.fields(Load):
        if f.type == "bool" or isinstance(f.default, bool):
            parser.add_argument(f"--{f.name}", action="store_true")
        else:
            parser.add_argument(f"--{f.name}", type=type(f.default), default=f.default)
    parser.add_argument("--seconds", type=float, default=90.0, help="how long each page is watched")
    parser.add_argument("--every", type=float, default=10.0, help="seconds between two reads of its lag")
    parser.add_argument("--matrix", nargs="*", help=f"run the preset rows: {', '.join(MATRIX)} (none named: all)")
    args = parser.parse_args()
    if args.matrix is not None:
        loads = [load for name in (args.matrix or MATRIX) for load in MATRIX[name]]
    else:
        loads = [Load(**{f.name: getattr(args, f.name) for f in dataclasses.fields(Load)})]
    print(HEADER.format(base=BASE), flush=True)
    for load in loads:
        print(row(load, measure(load, args.seconds, args.every)), flush=True)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--serve"]:
        serve(Load(**json.loads(sys.argv[2])), int(sys.argv[3]), int(sys.argv[4]))
        sys.exit(0)
    main()
