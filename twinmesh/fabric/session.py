"""Opening Zenoh sessions the one way this project does it."""
from __future__ import annotations

import logging
import os
import threading
from contextlib import ExitStack, contextmanager
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

from twinmesh.fabric.settings import MeshSettings

if TYPE_CHECKING:
    import zenoh

_log_once = threading.Lock()
_log_done = False


def _init_logging() -> None:
    global _log_done
    with _log_once:
        if not _log_done:
            import zenoh

            zenoh.init_log_from_env_or(os.environ.get("TWINMESH_ZENOH_LOG", "error"))
            _log_done = True


@contextmanager
def open_session(settings: MeshSettings) -> Iterator[zenoh.Session]:
    """`with open_session(s) as session:` — the session closes (and its threads end) on exit."""
    import zenoh

    _init_logging()
    with zenoh.open(settings.zenoh_config()) as session:
        yield session


def direct(callback: Callable[[Any], None]):
    """`callback` run on Zenoh's own thread. zenoh-python otherwise gives every Python callback a thread
    of its own (4 per Thing: 2,000 for a fleet of 500). Only for callbacks that return at once (they
    hand the work to a pool or an event loop)."""
    import zenoh

    return zenoh.handlers.Callback(callback, indirect=False)


def is_connected(session) -> bool:
    """Whether the session reached at least one router or peer."""
    info = session.info
    return bool(list(info.routers_zid()) or list(info.peers_zid()))


def run_router_process(settings: MeshSettings, stop: threading.Event, listen: Sequence[str] = (),
                       connect: Sequence[str] = ()) -> None:
    """Process entry for the lab's router: it listens where the lab's peers connect, and links to the
    routers at `connect` (another host's lab, for `up --join`).

    A router that cannot listen (the port was taken after `up` checked it) logs one line and
    exits with code 1, so the supervisor stops the lab instead of leaving it without a router.
    """
    import zenoh

    with ExitStack() as stack:
        try:
            stack.enter_context(open_session(settings.as_router(tuple(listen) or None, tuple(connect))))
        except zenoh.ZError as e:
            logging.getLogger(__name__).error("the router cannot listen on %s: %s", ", ".join(listen), e)
            raise SystemExit(1) from None
        stop.wait()


@contextmanager
def one_shot_session(settings: MeshSettings, mode_given: bool = False) -> Iterator[zenoh.Session]:
    """A session for a short-lived consumer (a CLI command, a workflow).

    Client mode unless a mode was asked for: a fresh peer may query before the router's
    declarations reach it and find nobody; a client sends every query to the router.
    It does not wait for a router: raises Unavailable at once when no lab is reachable.
    """
    import msgspec
    import zenoh

    from twinmesh.wot.problem import Unavailable

    settings = msgspec.structs.replace(settings, wait_for_router=False)
    if not mode_given:
        settings = msgspec.structs.replace(settings, mode="client")
    unreachable = f"no lab reachable at {', '.join(settings.connect)} (is `twinmesh up` running?)"
    with ExitStack() as stack:
        try:
            session = stack.enter_context(open_session(settings))
        except zenoh.ZError:  # a client that reaches no router fails to open
            raise Unavailable(unreachable, reason="no-lab") from None
        if not is_connected(session) and settings.mode != "router":
            raise Unavailable(unreachable, reason="no-lab")
        yield session
