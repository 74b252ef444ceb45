"""What each kind of lab process runs: `entry(settings, stop, **kwargs)`, returning once `stop` is set.

A `ProcessSpec` holds one of these functions itself (never a `module:function` string: a typo fails at
import and in mypy, not after a spawn). Each imports its part inside, so that `twinmesh up`, which
only starts and watches processes, does not load pybullet, Rerun or Starlette itself (a second and
tens of MB); spawn pickles the function by reference and the child imports this light module.
"""
from __future__ import annotations

import threading
from typing import Any

from mesh.fabric.settings import MeshSettings


def router(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from mesh.fabric.session import run_router_process

    run_router_process(settings, stop, **kwargs)


def adapter(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from mesh.http.server import run

    run(settings, stop, **kwargs)


def recorder(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from mesh.recorder.logger import run

    run(settings, stop, **kwargs)


def view(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from mesh.recorder.view import run

    run(settings, stop, **kwargs)


def tdgen(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from tdgen.service import run

    run(settings, stop, **kwargs)


def lights(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from devices.lab.lights_process import run

    run(settings, stop, **kwargs)


def robot(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from devices.lab.robot_process import run

    run(settings, stop, **kwargs)


def fleet(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from devices.lab.fleet_process import run

    run(settings, stop, **kwargs)


def iot_platform(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from devices.lab.iot_platform import run

    run(settings, stop, **kwargs)


def iot_lab(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from devices.lab.iot_lab import run

    run(settings, stop, **kwargs)


def virtual(settings: MeshSettings, stop: threading.Event, **kwargs: Any) -> None:
    from devices.things.virtual import run

    run(settings, stop, **kwargs)
