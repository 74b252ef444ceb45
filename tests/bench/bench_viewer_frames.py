"""What sets the frames a second the real lab's live page draws: one factor at a time.

    python tests/bench/bench_viewer_frames.py [--configs lab full alone lab-nolog small 3d nolog noplots]
                                              [--busy] [--settle 45]

Starts `twinmesh up iot-lab --speed max` (its own view off) and, per configuration, a live view process
of its own (`mesh.recorder.view.run`, the blueprint's plots or text log left out as the configuration
says) and a page on it in headless Chromium (software WebGL): `lab` the address as a user opens it
(our page, which chooses its scale: mesh.recorder.web_viewer), `full` the same at scale 1, `alone`
Rerun's page without ours. `--busy` runs the cube workflow over and over meanwhile. Per configuration:
the seconds until the room is drawn; after `--settle` s the page's frames a second (the animation frames
eframe asks for, over 5 s: Rerun's web viewer takes in data for about 10 ms a frame it draws, so frames a
second bound what it can take in), the CPU of the browser's renderer and GPU processes over that window;
then a lamp's colour written over HTTP to the first screenshot showing it (the page's lag behind the lab).
Figures on a shared 2-core machine are noisy.
`--serve CONFIG ENDPOINT PORT GRPC_PORT` is this script's own view process.
"""
from __future__ import annotations

import argparse
import functools
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, rerun_view
sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_live_view import COLOURS, busy, put_colour, shown  # noqa: E402
from bench_viewer_capacity import cpu_seconds  # noqa: E402
from labs import free_port, start_lab, stop_process  # noqa: E402
from rerun_view import ViewerPage, room_drawn  # noqa: E402
from waiting import seconds_until  # noqa: E402

from recordings import wait_for_line  # noqa: E402

# name -> (viewport, what the blueprint shows besides the 3D view, the page's `scale`: see web_viewer)
CONFIGS = {
    "lab": ("1280x800", {"plots": True, "log": True}, "auto"),
    "full": ("1280x800", {"plots": True, "log": True}, "1"),
    "alone": ("1280x800", {"plots": True, "log": True}, None),  # Rerun's page opened alone, no frame of ours
    "lab-nolog": ("1280x800", {"plots": True, "log": False}, "auto"),
    "small": ("640x400", {"plots": True, "log": True}, "1"),
    "3d": ("1280x800", {"plots": False, "log": False}, "1"),
    "nolog": ("1280x800", {"plots": True, "log": False}, "1"),
    "noplots": ("1280x800", {"plots": False, "log": True}, "1"),
}
SHOWN_LIMIT = 120.0
# the viewer's own frames: eframe asks for an animation frame when it must paint, none when nothing changed
# (then requestAnimationFrame callbacks of our own run at the display's rate and say nothing)
COUNT_PAINTS = """window.__paints = 0; const raf = window.requestAnimationFrame.bind(window);
window.requestAnimationFrame = cb => raf(t => { window.__paints++; cb(t); });"""
PAINTS_SCRIPT = """() => new Promise(done => { const n0 = window.__paints, t0 = performance.now();
  setTimeout(() => done((window.__paints - n0) / ((performance.now() - t0) / 1000)), 5000); })"""


def viewer_frame(page):
    """The frame Rerun's viewer runs in (our page at `/` holds it: mesh.recorder.web_viewer)."""
    from mesh.recorder.web_viewer import VIEWER_PAGE

    return next((f for f in page.frames if VIEWER_PAGE in f.url), page.main_frame)


def serve(config: str, endpoint: str, port: int, grpc_port: int) -> None:
    """A live view process with the configuration's blueprint (plots and log as it says)."""
    import mesh.recorder.logger as logger
    from mesh.fabric.settings import MeshSettings
    from mesh.recorder.scene_drawer import lab_blueprint
    from mesh.recorder.view import run

    logger.lab_blueprint = functools.partial(lab_blueprint, **CONFIGS[config][1])  # type: ignore[assignment]
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    run(MeshSettings(mode="client", connect=(endpoint,)), stop, ("127.0.0.1", port), grpc_port)


def measure(lab, config: str, tmp: Path, settle: float, changes: int) -> dict:
    import psutil
    from browser import chromium

    from mesh.recorder.web_viewer import VIEWER_PAGE

    log = tmp / f"view-{config}.log"
    port, grpc = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, __file__, "--serve", config, lab.endpoint, str(port), str(grpc)],
                            stdout=open(log, "wb"), stderr=subprocess.STDOUT, start_new_session=True)
    try:
        url = re.search(r"3D view at (http://\S+)", wait_for_line(log, "3D view at", proc, timeout=300)).group(1)
        scale = CONFIGS[config][2]
        url = url.replace("/?", VIEWER_PAGE + "?") if scale is None else url + f"&scale={scale}"
        w, h = (int(x) for x in CONFIGS[config][0].split("x"))
        with chromium() as app:
            page = app.new_page(viewport={"width": w, "height": h})  # type: ignore[attr-defined]
            page.add_init_script(COUNT_PAINTS)
            view = ViewerPage(page, url)
            opened = time.perf_counter()
            drawn = seconds_until(lambda: room_drawn(view.pixels()), 300.0)
            threading.Event().wait(max(0.0, settle - (time.perf_counter() - opened)))  # the page settles
            chrome = [p for p in psutil.Process().children(recursive=True) if "chrom" in p.name()]
            gpu = [p for p in chrome if "--type=gpu-process" in " ".join(p.cmdline())]
            renderer = [p for p in chrome if "--type=renderer" in " ".join(p.cmdline())]
            cpu0 = (cpu_seconds(renderer), cpu_seconds(gpu), time.perf_counter())
            fps = viewer_frame(view.page).evaluate(PAINTS_SCRIPT)
            window = time.perf_counter() - cpu0[2]
            cpu = ((cpu_seconds(renderer) - cpu0[0]) / window, (cpu_seconds(gpu) - cpu0[1]) / window)
            shots, delays = [], []
            for k in range(changes):
                name = ("magenta", "cyan")[k % 2]
                put_colour(lab.http, COLOURS[name][1])

                def seen() -> bool:
                    t = time.perf_counter()
                    px = view.pixels()
                    shots.append(time.perf_counter() - t)
                    x1, y0, y1 = round(0.6 * px.shape[1]), round(0.1 * px.shape[0]), round(0.9 * px.shape[0])
                    return shown(px[y0:y1, :x1], COLOURS[name][0])

                delays.append(seconds_until(seen, SHOWN_LIMIT))
                if delays[-1] is None:
                    break
            fps_end = viewer_frame(view.page).evaluate(PAINTS_SCRIPT)
            load = os.getloadavg()[0]
            problems = view.rerun_problems()
            scale = view.page.evaluate("() => document.documentElement.dataset.scale || '1'")
        return {"drawn": drawn, "fps": fps, "fps_end": fps_end, "renderer": cpu[0], "gpu": cpu[1],
                "delays": delays, "shot": sorted(shots)[len(shots) // 2] if shots else None,
                "problems": problems[:2], "load": load, "scale": scale}
    finally:
        stop_process(proc)


def _s(v: float | None) -> str:
    return "-" if v is None else f"{v:.1f}"


def main(configs: list[str], busy_lab: bool, settle: float, changes: int) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench-viewer-frames-"))
    lab = start_lab(tmp, "iot-lab", http=True, view=False, things={"world", "light-left"},
                    extra_args=("--speed", "max"))
    stop = threading.Event()
    try:
        assert lab.cli("invoke", "light-left", "switchOn", timeout=120).returncode == 0
        if busy_lab:
            threading.Thread(target=busy, args=(lab, stop), daemon=True).start()
        print("| config | viewport | room drawn, s | frames/s after settling / at the end | renderer / GPU "
              "process, cores | lamp colour to screen, s | one screenshot, s | Rerun problems | load |", flush=True)
        for config in configs:
            r = measure(lab, config, tmp, settle, changes)
            delays = ", ".join(_s(d) if d is not None else f">{SHOWN_LIMIT:.0f}" for d in r["delays"])
            print(f"| {config}{' (busy lab)' if busy_lab else ''} | {CONFIGS[config][0]}, scale {r['scale']} | "
                  f"{_s(r['drawn'])} | "
                  f"{r['fps']:.1f} / {r['fps_end']:.1f} | {r['renderer']:.2f} / {r['gpu']:.2f} | {delays} | "
                  f"{_s(r['shot'])} | {len(r['problems'])} | {r['load']:.1f} |", flush=True)
    finally:
        stop.set()
        lab.stop()
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--serve"]:
        serve(sys.argv[2], sys.argv[3], int(sys.argv[4]), int(sys.argv[5]))
        sys.exit(0)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--configs", nargs="+", default=list(CONFIGS), choices=list(CONFIGS))
    parser.add_argument("--busy", action="store_true", help="the cube workflow over and over meanwhile")
    parser.add_argument("--settle", type=float, default=45.0, help="seconds after opening before frames are counted")
    parser.add_argument("--changes", type=int, default=2, help="lamp colour changes per configuration")
    args = parser.parse_args()
    main(args.configs, args.busy, args.settle, args.changes)
