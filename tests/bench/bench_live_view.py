"""The live view's delay behind the lab, what a late viewer needs to be current, the recorder's cost.

    python tests/bench/bench_live_view.py [--minutes 10] [--rounds 5]

Starts `twinmesh up iot-lab --speed max --record FILE` with its live view, and keeps it busy (the cube
workflow over and over). Three figures, each printed beside its baseline from the same run:

- **delay**: a viewer opened on the fresh lab (headless Chromium, software WebGL), `rounds` times the
  left lamp's colour changed (magenta / green in turn): the wall time from the action's reply to the
  first screenshot of the page that shows the new colour. Baseline: how long one screenshot takes
  (the resolution of the figure: a change cannot be seen faster than the page is read);
- **late viewer**: after `minutes` of the busy lab, a new page: the time until the room is drawn and
  then the same colour delay. Baseline: the same two figures for the viewer opened at the start;
- **recorder**: the `twinmesh: recorder` process's CPU seconds and resident memory over the run,
  scaled to one hour, and the recording's size per hour. Baseline: the same for the world process.

Figures on a shared 2-core machine are noisy; the screenshot baseline says how noisy.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import statistics
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/: labs, rerun_view

from labs import start_lab  # noqa: E402
from rerun_view import colour_share, room_drawn, viewer_page  # noqa: E402

COLOURS = {"magenta": ((255, 0, 255), {"r": 1, "g": 0, "b": 1}), "green": ((0, 255, 0), {"r": 0, "g": 1, "b": 0})}
DRAWN_LIMIT, SHOWN_LIMIT = 900.0, 300.0


def shown(pixels, rgb) -> bool:
    return colour_share(pixels, rgb) * pixels.shape[0] * pixels.shape[1] >= 20


def until(check, limit: float, what: str) -> float:
    started = time.perf_counter()
    while not check():
        if time.perf_counter() - started > limit:
            raise SystemExit(f"{what}: not within {limit:.0f} s")
    return time.perf_counter() - started


def colour_delays(lab, view, rounds: int) -> tuple[list[float], list[float]]:
    """`rounds` colour changes: (delay from the reply to the first page showing it, screenshot times)."""
    shots: list[float] = []

    def page():
        t = time.perf_counter()
        px = view.pixels()
        shots.append(time.perf_counter() - t)
        return px

    delays = []
    for k in range(rounds):
        name = ("magenta", "green")[k % 2]
        rgb, value = COLOURS[name]
        r = lab.cli("invoke", "light-left", "setColor", json.dumps(value), timeout=120)
        assert r.returncode == 0, r.stderr
        delays.append(until(lambda: shown(page(), rgb), SHOWN_LIMIT, f"the lamp's {name} in the view"))
    return delays, shots


def process_usage(session: int, title: str) -> tuple[float, int]:
    """CPU seconds and resident bytes of the lab's process titled `title` (in the lab's session)."""
    tick, page = os.sysconf("SC_CLK_TCK"), os.sysconf("SC_PAGE_SIZE")
    for pid in filter(str.isdigit, os.listdir("/proc")):
        try:
            cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode(errors="replace")
            stat = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if cmdline.startswith(title) and int(stat[3]) == session:
            return (int(stat[11]) + int(stat[12])) / tick, int(stat[21]) * page
    raise SystemExit(f"no process {title!r} in the lab")


def busy(lab, stop: threading.Event) -> None:
    while not stop.is_set():
        lab.cli("workflow", "cube", timeout=900)


def summary(values: list[float]) -> str:
    return f"median {statistics.median(values):.2f} s, max {max(values):.2f} s (n={len(values)})"


def main(minutes: float, rounds: int) -> None:
    tmp = Path(tempfile.mkdtemp(prefix="bench-live-view-"))
    rrd = tmp / "lab.rrd"
    lab = start_lab(tmp, "iot-lab", http=False, view=True, things={"world", "light-left"},
                    extra_args=("--speed", "max", "--record", str(rrd)))
    stop = threading.Event()
    try:
        url = re.search(r"3D view (http://\S+?),? ", lab.log.read_text()).group(1).rstrip(",")
        session = lab.proc.pid
        r = lab.cli("invoke", "light-left", "switchOn", timeout=120)
        assert r.returncode == 0, r.stderr
        usage0 = {t: process_usage(session, t) for t in ("twinmesh: recorder", "twinmesh: world")}
        started = time.monotonic()
        threading.Thread(target=busy, args=(lab, stop), daemon=True).start()
        with viewer_page(url) as view:
            first_drawn = until(lambda: room_drawn(view.pixels()), DRAWN_LIMIT, "the room in the first viewer")
            first, first_shots = colour_delays(lab, view, rounds)
        time.sleep(max(0.0, minutes * 60 - (time.monotonic() - started)))
        with viewer_page(url) as view:
            late_drawn = until(lambda: room_drawn(view.pixels()), DRAWN_LIMIT, "the room in the late viewer")
            late, late_shots = colour_delays(lab, view, rounds)
        hours = (time.monotonic() - started) / 3600
        usage1 = {t: process_usage(session, t) for t in usage0}
    finally:
        stop.set()
        lab.stop()
    print(f"iot-lab at --speed max, busy with the cube workflow, {hours * 60:.1f} min; {rounds} colour changes per viewer")
    print(f"delay, viewer opened at the start:      {summary(first)}; screenshot (baseline) {summary(first_shots)}")
    print(f"late viewer, opened after {minutes:g} min:    drawn after {late_drawn:.1f} s (first viewer: "
          f"{first_drawn:.1f} s); delay {summary(late)}; screenshot {summary(late_shots)}")
    for title, (cpu0, rss0) in usage0.items():
        cpu1, rss1 = usage1[title]
        print(f"{title:20s} CPU {(cpu1 - cpu0) / hours:7.0f} s per hour ({(cpu1 - cpu0) / hours / 36:.1f} % of a core), "
              f"memory {rss1 / 2**20:.0f} MiB at the end ({(rss1 - rss0) / 2**20 / hours:+.0f} MiB per hour)")
    print(f"recording: {rrd.stat().st_size / 2**20 / hours:.1f} MiB per hour ({rrd.stat().st_size / 2**20:.1f} MiB)")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--minutes", type=float, default=10.0, help="how long the lab runs before the late viewer")
    parser.add_argument("--rounds", type=int, default=5, help="colour changes per viewer")
    args = parser.parse_args()
    main(args.minutes, args.rounds)
