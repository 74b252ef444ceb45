"""The live view's delay behind the lab, what a late viewer needs to be current, the recorder's cost.

    python tests/bench/bench_live_view.py [--minutes 10] [--changes 20] [--no-baseline]
    python tests/bench/bench_live_view.py --count-chunks FILE.rrd ...

Starts `twinmesh up iot-lab --speed max --record FILE` with its live view and HTTP adapter, keeps it
busy (the cube workflow over and over), and measures in headless Chromium (software WebGL):

- **delay**: `changes` times the left lamp's colour written over HTTP (`PUT .../lightColor`, magenta
  and cyan in turn, colours no body of the room has): the wall time from the PUT to the end of the
  first screenshot of the 3D view that shows the new colour, p50 / p99 / max. Baseline: how long one
  screenshot takes (the figure's resolution: a frame cannot be seen sooner than the page is read).
  Measured in a viewer opened on the fresh lab and again in the late viewer;
- **late viewer**: the lamp is left magenta, the lab runs on for `minutes` (counted from the start),
  then a new page: the time from opening it until the room is drawn and until the lamp's magenta is
  shown (the current state). Baseline, same lab, same minute: a second view process with the settings
  before (16 MiB of history, the current state not logged again, every pose sent), opened the same way;
- **recorder**: CPU seconds and resident memory of the lab's `recorder` (the `.rrd` file) and `view`
  (live view) processes over the measured window, scaled to one hour, and the recording's size;
- **chunks**: the recording's chunks over time per second and its busiest entities (Rerun's web viewer
  takes in chunks at a cost each, whatever their rows). The file batches 0.25 s, the live stream 0.5 s:
  the stream sends fewer. `--count-chunks FILE.rrd` counts another recording (a run at an older commit).

Figures on a shared 2-core machine are noisy; the screenshot baseline says how noisy.
`--serve-old-view ENDPOINT HOST PORT GRPC_PORT` is this script's own baseline process.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, rerun_view

from labs import free_port, start_lab, stop_process  # noqa: E402
from rerun_view import colour_share, room_drawn, viewer_page  # noqa: E402
from waiting import seconds_until  # noqa: E402

from recordings import wait_for_line  # noqa: E402

# channels of 0 or 1 only: the view shades in linear light, which keeps their hue but not a mixed one's
COLOURS = {"magenta": ((255, 0, 255), [1, 0, 1]), "cyan": ((0, 255, 255), [0, 1, 1])}
DRAWN_LIMIT, SHOWN_LIMIT, OLD_LIMIT = 900.0, 300.0, 240.0
OLD_MEMORY = "16MiB"  # the view's history before (mesh.recorder.view.MEMORY), the current state not logged again


def shown(pixels, rgb) -> bool:
    return colour_share(pixels, rgb) * pixels.shape[0] * pixels.shape[1] >= 20


def put_colour(http: str, colour: list[float]) -> None:
    request = urllib.request.Request(f"{http}/light-left/properties/lightColor", method="PUT",
                                     data=json.dumps(colour).encode(), headers={"Content-Type": "application/json"})
    with urllib.request.urlopen(request, timeout=60) as r:
        assert r.status in (200, 204), r.status


def colour_delays(http: str, view, changes: int, start: int) -> tuple[list[float], list[float]]:
    """`changes` colour writes: (seconds from the PUT to the first view showing it, screenshot times)."""
    shots: list[float] = []

    def page():
        t = time.perf_counter()
        px = view.view_pixels()
        shots.append(time.perf_counter() - t)
        return px

    delays = []
    for k in range(start, start + changes):
        name = ("magenta", "cyan")[k % 2]
        rgb, value = COLOURS[name]
        put_colour(http, value)
        delay = seconds_until(lambda: shown(page(), rgb), SHOWN_LIMIT)
        if delay is None:  # a viewer this far behind does not catch up: the rounds end here
            shot = Path(tempfile.gettempdir()) / "bench-live-view-behind.png"
            view.save(shot)
            print(f"the lamp's {name} not in the view within {SHOWN_LIMIT:.0f} s (the page: {shot})", flush=True)
            break
        delays.append(delay)
    return delays, shots


def late_viewer(url: str, limit: float) -> tuple[float | None, float | None]:
    with viewer_page(url) as view:
        return current_after(view, limit)


def current_after(view, limit: float) -> tuple[float | None, float | None]:
    """A page just opened: (seconds until the room is drawn, until the lamp's magenta is shown), None:
    not within `limit`."""
    opened = time.perf_counter()
    drawn = seconds_until(lambda: room_drawn(view.pixels()), limit)
    current = seconds_until(lambda: shown(view.view_pixels(), COLOURS["magenta"][0]), limit)
    return drawn, None if current is None else time.perf_counter() - opened


def process_usage(session: int, title: str) -> tuple[float, int]:
    """CPU seconds and resident bytes of the lab's process titled `title` (in the lab's session)."""
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if cmdline.startswith(title) and int(stat[3]) == session:
            return pid_usage(int(pid))
    raise SystemExit(f"no process {title!r} in the lab")


def pid_usage(pid: int) -> tuple[float, int]:
    tick, page = os.sysconf("SC_CLK_TCK"), os.sysconf("SC_PAGE_SIZE")
    stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(stat[11]) + int(stat[12])) / tick, int(stat[21]) * page


def busy(lab, stop: threading.Event) -> None:
    while not stop.is_set():
        if lab.cli("workflow", "cube", timeout=900).returncode != 0:
            stop.wait(5.0)  # a refused run: not a loop of process starts


def old_view(lab, tmp: Path) -> tuple[subprocess.Popen, str]:
    """The baseline view process on the lab (see `serve_old_view`), and its URL."""
    log = tmp / "old-view.log"
    port, grpc = free_port(), free_port()
    proc = subprocess.Popen([sys.executable, __file__, "--serve-old-view", lab.endpoint, "127.0.0.1", str(port),
                             str(grpc)], stdout=open(log, "wb"), stderr=subprocess.STDOUT, start_new_session=True)
    line = wait_for_line(log, "3D view at", proc, timeout=300)
    return proc, re.search(r"3D view at (http://\S+)", line).group(1)


def serve_old_view(endpoint: str, host: str, port: int, grpc_port: int) -> None:
    from mesh.fabric.settings import MeshSettings
    from mesh.recorder.view import run

    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    run(MeshSettings(mode="client", connect=(endpoint,)), stop, (host, port), grpc_port, memory=OLD_MEMORY,
        refresh=None, batch=None, every_pose=True)


def chunk_rate(path: Path, top: int = 6) -> str:
    """Temporal chunks per second of a recording over its `time` span, and its busiest entities (one
    entity per field, joint or body counted together, as they were before they shared one)."""
    import collections
    import warnings

    from rerun.chunk import RrdReader

    warnings.filterwarnings("ignore", message=".*no footer.*")  # a lab stopped by a signal may leave none
    counts: collections.Counter[str] = collections.Counter()
    first = last = None
    for chunk in RrdReader(path).stream():
        if chunk.is_static:
            continue
        group = re.sub(r"^/(world/states|things)/([^/]+)/.*", r"/\1/\2/*", chunk.entity_path)
        group = re.sub(r"^/world/bodies/.*", "/world/bodies/*", group)
        counts[re.sub(r"/joints/[^/]+(/[^/]+)?$", "/joints/*", group)] += 1
        if "time" in chunk.timeline_names:
            times = chunk.to_record_batch().column("time").to_pylist()
            first = min(times) if first is None else min(first, *times)
            last = max(times) if last is None else max(last, *times)
    if first is None or last is None or last == first:
        return f"{path}: no chunks over time"
    span, n = (last - first).total_seconds(), sum(counts.values())
    busiest = ", ".join(f"{g} {c / span:.1f}/s" for g, c in counts.most_common(top))
    return f"{n} chunks over time in {span:.0f} s: {n / span:.1f} per second; busiest: {busiest}"


def summary(values: list[float]) -> str:
    if not values:
        return "none shown"
    q = statistics.quantiles(values, n=100, method="inclusive") if len(values) > 1 else values * 99
    return f"p50 {statistics.median(values):.2f} s, p99 {q[98]:.2f} s, max {max(values):.2f} s (n={len(values)})"


def seconds(value: float | None, limit: float) -> str:
    return f"not within {limit:.0f} s" if value is None else f"{value:.1f} s"


def main(minutes: float, changes: int, baseline: bool, keep: bool) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench-live-view-"))
    rrd = tmp / "lab.rrd"
    print(f"lab files in {tmp}" + ("" if keep else " (removed at the end; --keep keeps them)"), flush=True)
    lab = start_lab(tmp, "iot-lab", http=True, view=True, things={"world", "light-left"},
                    extra_args=("--speed", "max", "--record", str(rrd)))
    stop = threading.Event()
    old = None
    try:
        url = re.search(r"3D view (http://\S+?),? ", lab.log.read_text()).group(1).rstrip(",")
        r = lab.cli("invoke", "light-left", "switchOn", timeout=120)
        assert r.returncode == 0, r.stderr
        if baseline:
            old, old_url = old_view(lab, tmp)
        titles = ("twinmesh: recorder", "twinmesh: view")
        usage0 = {t: process_usage(lab.proc.pid, t) for t in titles}
        old0 = pid_usage(old.pid) if old else None
        started = time.monotonic()
        threading.Thread(target=busy, args=(lab, stop), daemon=True).start()
        with viewer_page(url) as view:
            first_drawn = seconds_until(lambda: room_drawn(view.pixels()), DRAWN_LIMIT)
            if first_drawn is None:
                raise SystemExit(f"the room not drawn in the first viewer within {DRAWN_LIMIT:.0f} s")
            first, first_shots = colour_delays(lab.http, view, changes, 1)
            print(f"first viewer: room drawn after {first_drawn:.1f} s; delays {summary(first)}", flush=True)
        put_colour(lab.http, COLOURS["magenta"][1])  # left alone from here on
        left_alone = time.monotonic()
        print(f"first viewer done after {(left_alone - started) / 60:.1f} min; the lamp left magenta", flush=True)
        time.sleep(max(0.0, minutes * 60 - (time.monotonic() - started)))
        old_at = (time.monotonic() - started) / 60
        old_drawn, old_current = late_viewer(old_url, OLD_LIMIT) if old else (None, None)
        print(f"baseline late viewer: drawn {old_drawn}, current {old_current}", flush=True)
        late_at = (time.monotonic() - started) / 60
        with viewer_page(url) as view:
            late_drawn, late_current = current_after(view, DRAWN_LIMIT)
            print(f"late viewer: drawn {late_drawn}, current {late_current}", flush=True)
            late, late_shots = colour_delays(lab.http, view, changes, 1)
        hours = (time.monotonic() - started) / 3600
        usage1 = {t: process_usage(lab.proc.pid, t) for t in titles}
        old1 = pid_usage(old.pid) if old else None
    finally:
        stop.set()
        if old is not None:
            stop_process(old)
        lab.stop()
    print(f"\niot-lab at --speed max, busy with the cube workflow; measured over {hours * 60:.1f} min")
    print(f"delay, viewer opened on the fresh lab (room drawn after {seconds(first_drawn, DRAWN_LIMIT)}): "
          f"{summary(first)}; "
          f"screenshot (baseline) {summary(first_shots)}")
    print(f"delay, viewer opened after {late_at:.1f} min: {summary(late)}; screenshot {summary(late_shots)}")
    print(f"late viewer after {late_at:.1f} min, lamp left alone for {(late_at * 60 - (left_alone - started)) / 60:.1f} "
          f"min: room drawn {seconds(late_drawn, DRAWN_LIMIT)}, current (lamp magenta) "
          f"{seconds(late_current, DRAWN_LIMIT)} after opening")
    if old:
        print(f"  baseline, the view before ({OLD_MEMORY} of history, state not logged again) opened after "
              f"{old_at:.1f} min: room drawn "
              f"{seconds(old_drawn, OLD_LIMIT)}, current {seconds(old_current, OLD_LIMIT)}")
    rows = [(t, usage0[t], usage1[t]) for t in titles] + ([("baseline view", old0, old1)] if old else [])
    for title, (cpu0, rss0), (cpu1, rss1) in rows:
        print(f"{title:20s} CPU {(cpu1 - cpu0) / hours:7.0f} s per hour ({(cpu1 - cpu0) / hours / 36:.1f} % of a core), "
              f"memory {rss1 / 2**20:.0f} MiB at the end ({(rss1 - rss0) / 2**20 / hours:+.0f} MiB per hour)")
    size = rrd.stat().st_size / 2**20
    print(f"recording: {size:.1f} MiB ({size / hours:.0f} MiB per hour)")
    print(f"recording's chunks: {chunk_rate(rrd)}")
    if not keep:
        shutil.rmtree(tmp, ignore_errors=True)


if __name__ == "__main__":
    if sys.argv[1:2] == ["--count-chunks"]:
        for name in sys.argv[2:]:
            print(f"{name}: {chunk_rate(Path(name))}")
        sys.exit(0)
    if sys.argv[1:2] == ["--serve-old-view"]:
        endpoint, host, port, grpc = sys.argv[2:6]
        serve_old_view(endpoint, host, int(port), int(grpc))
        sys.exit(0)
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="how long the lab runs before the late viewer")
    parser.add_argument("--changes", type=int, default=20, help="colour changes per delay measurement")
    parser.add_argument("--no-baseline", action="store_true", help="no second view with the settings before")
    parser.add_argument("--keep", action="store_true", help="keep the lab's files (logs, recording) at the end")
    args = parser.parse_args()
    main(args.minutes, args.changes, not args.no_baseline, args.keep)
