"""The live 3D view: the recorder's stream served to a Rerun web viewer instead of written to a file.

`twinmesh up` runs it as the `view` process (unless `--no-view`): the same Recorder that writes
`.rrd` files (the room, the robots from their URDFs, cubes, belts, lights, pan-tilt heads, the UR10's
workspace, obstacles, planned paths, plots of properties) logs into a RecordingStream served over
Rerun's gRPC proxy, and `mesh.recorder.web_viewer` serves Rerun's web viewer (its files come with
rerun-sdk: no internet; the page may reach nothing but this host) pointed at that stream.

A browser that opens the URL late must be current within seconds, however long the lab has run:
the gRPC server keeps the static data (the room, the robots' models, the workspaces, the blueprint)
and only the newest `MEMORY` of the rest (oldest first out), and sends a new viewer the newest data
first (`newest_first`). `mesh.recorder.live_state.LiveState` logs an entity again once `REFRESH`
bytes have been logged behind it, so that newest part always holds the whole current state, and a
late viewer has little history to take in before it is current. The `.rrd` file of `--record` is
a separate recorder and keeps everything.

What a browser can take in is the limit of a live view. Rerun's web viewer takes in data for about
10 ms of each frame it draws, and a browser without a GPU draws a few frames a second or fewer (its
software renderer needs most of a core for a page; a bigger window, or a machine whose cores the lab
itself keeps busy, draws fewer). Of what the lab sends, transform rows (poses placing a frame) cost
it most: as many chunks of scalars kept up where those of many poses fell minutes behind; the plots
and the scene's size did not decide it (`tests/bench/bench_viewer_capacity.py`, one factor at a
time). So the stream sends each frame's newest pose per `BATCH` only (`mesh.recorder.live_rows`):
nobody sees the poses in between, and the view shows where everything is now. Plots keep every
sample. A page whose browser gets too little of the machine still falls behind a busy lab.

What sets the frames such a browser draws is the size of its window, not what the lab sends nor the
layout: once data arrives every batch the viewer draws every frame anew, and a software renderer's
frame costs the page's pixels, whichever views it shows (the 3D view alone drew no more frames than the
lab's layout with its plots and log; a window of a quarter the pixels drew several times as many and
kept up: `tests/bench/bench_viewer_frames.py`). The page cannot shrink that for the browser: eframe
sizes its canvas from the device pixels the browser lays out, not from `devicePixelRatio` (a page that
lowered it still drew every pixel), and a smaller canvas would be a smaller view. So the layout stays
the recording's, and a smaller window is the user's lever.

The stream is served on the view's own host (127.0.0.1 unless `twinmesh up --view HOST:PORT` names
another): Rerun's own default would be every interface.
"""
from __future__ import annotations

import sys
import threading
import time

from mesh.fabric.settings import MeshSettings

MEMORY = "4MiB"  # the newest part of the stream the gRPC server keeps for a late viewer (static data besides)
REFRESH = 1 << 20  # bytes: an entity with this much logged behind it is logged again (a quarter of MEMORY)
# Rerun's web viewer takes in new data for about 10 ms per frame it draws: a browser that draws slowly
# (software WebGL, a busy machine) takes in little a second. So the live stream batches longer than a file:
# joint values and poses, and what `log` gathers per entity, go out every BATCH seconds, one chunk per
# entity, and of the poses only each frame's newest (see the module's docstring).
BATCH = 0.5  # s; a change is in the stream within this


def view_url(address: tuple[str, int], grpc_port: int) -> str:
    """What a browser opens: the web viewer at `address`, told where the live stream is."""
    from mesh.recorder.web_viewer import viewer_url

    return viewer_url(address[0], address[1], grpc_port)


def grpc_url(host: str, grpc_port: int) -> str:
    return f"rerun+http://{host}:{grpc_port}/proxy"


def run(settings: MeshSettings, stop: threading.Event, address: tuple[str, int] = ("127.0.0.1", 9090),
        grpc_port: int = 9876, memory: str = MEMORY, refresh: int | None = REFRESH,
        batch: float | None = BATCH, every_pose: bool = False) -> None:
    """Process entry: serve the lab to a web viewer at `address` until `stop` is set. `memory`, `refresh`
    (None: the current state is not logged again), `batch` (None: as a recording file batches) and `every_pose`
    (True: every transform row sent, as a file keeps them) are there for the benchmark's baseline."""
    import rerun as rr

    from mesh.fabric.session import open_session
    from mesh.recorder.live_rows import NewestTransforms
    from mesh.recorder.live_state import LiveState
    from mesh.recorder.logger import Recorder
    from mesh.recorder.scene_drawer import BATCH_AGE
    from mesh.recorder.web_viewer import ViewerServer

    batcher = None if batch is None else rr.ChunkBatcherConfig(flush_tick=batch)
    stream = rr.RecordingStream("twinmesh", batcher_config=batcher)
    stream.set_sinks(rr.GrpcServerSink(bind_ip=address[0], port=grpc_port, server_memory_limit=memory,
                                       newest_first=True))
    sent = stream if every_pose else NewestTransforms(stream)
    rec = sent if refresh is None else LiveState(sent, refresh)
    viewer = ViewerServer(address, grpc_port)
    rec.send_recording_name(f"twinmesh {settings.prefix} live {time.strftime('%Y-%m-%d %H:%M:%S')}")
    with open_session(settings, service=True) as session, Recorder(session, settings, rec, batch or BATCH_AGE) as recorder:
        alive = recorder.start()
        print(f"3D view at {view_url(address, grpc_port)} ({len(alive)} things alive)", file=sys.stderr, flush=True)
        stop.wait()
    viewer.close()
