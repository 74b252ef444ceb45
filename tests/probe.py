"""The `probe` device and the extra-device helpers: another process on a lab's mesh with one
`light` or `probe` Thing (linked files; read-only, write-only, slow and refusing affordances;
schemas without `type`), for the adapter's lab tests and the HTTP benchmark."""
from __future__ import annotations

import queue
import subprocess
import sys
import threading
import time
from dataclasses import dataclass
from pathlib import Path

from labs import REPO, Lab
from waiting import eventually

TESTS = Path(__file__).resolve().parent
STL = b"solid probe\nendsolid probe\n"
CSV = b"x,y,z,collision\n0,0,0,0\n"

# --- the probe device (runs in its own process) ---------------------------------------------


def probe_td(name: str):
    from mesh.wot.thing_description import decode_td, thing_id

    return decode_td({
        "title": name, "id": thing_id(name),
        "properties": {
            "level": {"type": "integer", "minimum": 0, "maximum": 10, "observable": True},
            "serial": {"type": "string", "readOnly": True},
            "secret": {"type": "string", "writeOnly": True},
            "slow": {"type": "number", "readOnly": True},
            "mode": {"enum": ["a", "b"]},  # no `type`: the adapter infers "string"
        },
        "actions": {
            "refuse": {"title": "Always refused by the device"},
            "hold": {"title": "Returns after `input` seconds, like a long motion",
                     "input": {"type": "number", "minimum": 0, "maximum": 120}},
            "add": {"input": {"properties": {"a": {"type": "integer"}, "b": {"type": "integer"}},  # no `type`
                              "required": ["a", "b"]},
                    "output": {"type": "integer"}},
        },
        "links": [
            {"href": "files/workspace.stl", "rel": "workspace", "type": "model/stl"},
            {"href": "files/points.csv", "rel": "dataset-points", "type": "text/csv"},
            {"href": "https://www.w3.org/TR/wot-thing-description11/", "rel": "describedby", "type": "text/html"},
        ],
    })


def _probe(session, name: str, keys):
    from mesh.fabric.server import ExposedThing
    from mesh.wot.problem import Refused

    def refuse(_):
        raise Refused("the probe refuses everything", reason="always")

    thing = ExposedThing(session, probe_td(name), name, keys)
    thing.state("level", 3).state("mode", "a").on_read("serial", lambda: "P-001")
    thing.on_read("slow", lambda: time.sleep(8) or 1.0)  # longer than the adapter's 5 s query timeout
    thing.on_write("secret", lambda v: None)
    thing.on_action("hold", lambda seconds: time.sleep(seconds))
    thing.on_action("refuse", refuse).on_action("add", lambda i: i["a"] + i["b"])
    thing.on_file("workspace.stl", lambda: STL, "model/stl").on_file("points.csv", lambda: CSV, "text/csv")
    return thing


def serve(endpoint: str, kind: str, name: str) -> None:
    """Process entry: one `light` or `probe` Thing; prints `exposed` once its liveliness token is out."""
    from devices.lab.supervisor import install_stop_handlers
    from devices.things.lights import bind_light, light_td
    from mesh.fabric.server import ExposedThing
    from mesh.fabric.session import open_session
    from mesh.fabric.settings import MeshSettings

    stop = install_stop_handlers()
    settings = MeshSettings(connect=(endpoint,))
    with open_session(settings) as session:
        if kind == "light":
            thing = ExposedThing(session, light_td(name), name, settings.keys)
            bind_light(thing)
        else:
            thing = _probe(session, name, settings.keys)
        with thing:
            print("exposed", flush=True)
            stop.wait()


# --- helpers for tests ------------------------------------------------------------------------
@dataclass
class Device:
    proc: subprocess.Popen
    exposed_at: float  # time.monotonic() when it said it was exposed

    def kill(self) -> float:
        """SIGKILL (no goodbye on the mesh); returns when it was killed."""
        self.proc.kill()
        self.proc.wait()
        return time.monotonic()


def spawn_device(lab: Lab, kind: str, name: str, timeout: float = 30) -> Device:
    code = f"import sys; sys.path.insert(0, {str(TESTS)!r}); import probe; probe.serve(*sys.argv[1:])"
    proc = subprocess.Popen([sys.executable, "-c", code, lab.endpoint, kind, name], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    lab.extra.append(proc)  # lab.stop() stops it if the test did not
    lines: queue.Queue[str] = queue.Queue()
    threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
    deadline = time.monotonic() + timeout
    seen = []
    while time.monotonic() < deadline:
        try:
            line = lines.get(timeout=0.2)
        except queue.Empty:
            if proc.poll() is not None:
                break
            continue
        if line.strip() == "exposed":
            return Device(proc, time.monotonic())
        seen.append(line)
    proc.kill()
    raise AssertionError(f"{kind} {name} did not start:\n{''.join(seen)}")


def poll(fn, timeout: float, every: float = 0.05):
    """`eventually(fn)` checked every `every` s (the seconds waited are a measure here): (value, seconds
    waited), or (the last value, None) when it did not come within `timeout`."""
    started = time.monotonic()
    try:
        value = eventually(fn, timeout=timeout, interval=every, longest=every)
    except AssertionError:
        return fn(), None
    return value, time.monotonic() - started
