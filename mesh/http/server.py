"""Process entry of the WoT HTTP adapter: `run(settings, stop, address, auth)` with uvicorn.

Shutdown within ~2 s even with open SSE streams and long-polls: when `stop` is set, the registry
ends every stream first (uvicorn alone would wait for them forever), then uvicorn stops; requests
still in flight (an action waiting for a robot) get `timeout_graceful_shutdown`, then are cancelled;
closing the Zenoh session last releases the worker threads still blocked in a query.
Signals stay with `devices.lab.supervisor` (uvicorn's own handlers are turned off): `stop` is the one
way to end the adapter, in the foreground (`twinmesh adapter`) or under `twinmesh up`.
"""
from __future__ import annotations

import asyncio
import logging
import threading
from contextlib import contextmanager
from typing import Iterator

import uvicorn

from mesh.fabric.settings import MeshSettings  # the adapter process's settings: a value, not the binding
from mesh.http.app import create_asgi
from mesh.http.credentials import parse_auth
from mesh.http.gateway import Registry, open_registry

log = logging.getLogger(__name__)
GRACE = 1.0  # seconds in-flight requests get once stop is set


class _Server(uvicorn.Server):
    @contextmanager
    def capture_signals(self) -> Iterator[None]:  # the caller's stop event handles signals
        yield


async def _serve(server: _Server, registry: Registry, stop: threading.Event) -> None:
    async def watch_stop() -> None:
        while not stop.is_set() and not server.should_exit:
            await asyncio.sleep(0.1)
        registry.begin_shutdown()
        server.should_exit = True

    watcher = asyncio.create_task(watch_stop())
    try:
        await server.serve()
    finally:
        watcher.cancel()


def run(settings: MeshSettings, stop: threading.Event, address: tuple[str, int] = ("127.0.0.1", 8080),
        auth: str | None = None, view: str | None = None) -> None:
    """Serve every Thing of the mesh over HTTP at `address` until `stop` is set.

    `auth` is `bearer:TOKEN` or `basic:USER:PASS` (None: no security); `view` the URL of the live 3D
    view, which the control page links to.
    """
    security = parse_auth(auth)
    host, port = address
    with open_registry(settings) as registry:
        config = uvicorn.Config(create_asgi(registry, security, view), host=host, port=int(port), lifespan="on",
                                log_config=None, access_log=log.isEnabledFor(logging.DEBUG),
                                timeout_graceful_shutdown=GRACE,  # type: ignore[arg-type]  # a float works
                                server_header=False)
        server = _Server(config)
        # uvicorn's own loop choice (uvloop when installed, as it is with twinmesh): asyncio.run alone would
        # run the pure-Python loop whatever the config says
        with asyncio.Runner(loop_factory=config.get_loop_factory()) as runner:
            runner.run(_serve(server, registry, stop))
        log.info("adapter on %s:%s stopped", host, port)
