"""`twinmesh replay FILE.rrd`: a recording in Rerun's viewer, in a browser (any host) or on the desktop."""
from __future__ import annotations

import signal
import subprocess
import sys
import threading

import click


@click.command()
@click.argument("path", type=click.Path(dir_okay=True))
@click.option("--port", type=click.IntRange(1, 65535), default=9090, show_default=True,
              help="The web viewer's HTTP port.")
@click.option("--grpc-port", type=click.IntRange(1, 65535), help="The port the recording is streamed from "
              "[default: PORT+1].")
@click.option("--bind", default="127.0.0.1", show_default=True, help="The address both listen on (0.0.0.0: "
              "every interface, for a browser on another machine).")
@click.option("--desktop", is_flag=True, help="Open Rerun's desktop viewer instead (needs a display).")
def replay(path: str, port: int, grpc_port: int | None, bind: str, desktop: bool) -> None:
    """Replay a recording (twinmesh record, up --record) in Rerun's viewer: served to a browser, with the
    URL to open printed, until Ctrl-C; or with --desktop in the desktop viewer. Rerun's analytics are off."""
    from mesh.cli.exits import usage_exit
    from mesh.process import install_stop_handlers
    from mesh.recorder.repair import RepairError
    from mesh.recorder.replay import ReplayError, WebReplay, check_recording, desktop_command, rerun_env, stop_group

    try:
        rrd = check_recording(path)
        if desktop:
            sys.exit(subprocess.run(desktop_command(rrd), env=rerun_env()).returncode)
        # Ctrl-C and a service manager's stop (SIGTERM, SIGHUP) end the viewer; SIGUSR1 prints where it is stuck.
        # Taken before the URL is printed: a script that reads the URL and stops it at once (its SIGINT ignored,
        # as for `cmd &`) would otherwise lose the signal
        stop = install_stop_handlers((signal.SIGINT, signal.SIGTERM, signal.SIGHUP))
        web = WebReplay(rrd, bind, port, grpc_port or port + 1)
        proc, viewer = web.start()
    except (ReplayError, RepairError) as e:
        raise usage_exit(str(e)) from None
    click.echo(f"replaying {rrd} at {web.url}  (Ctrl-C to stop)")
    threading.Thread(target=_set_when_ended, args=(proc, stop), name="rerun-ended", daemon=True).start()
    try:
        stop.wait()
    finally:
        try:
            stop_group(proc)
        finally:
            viewer.close()


def _set_when_ended(proc: subprocess.Popen, stop: threading.Event) -> None:
    """A viewer whose server ended by itself stops too."""
    proc.wait()
    stop.set()
