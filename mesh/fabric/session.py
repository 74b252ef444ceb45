"""Opening Zenoh sessions the one way this project does it."""
from __future__ import annotations

import logging
import os
import threading
from contextlib import ExitStack, contextmanager
from typing import TYPE_CHECKING, Any, Callable, Iterator, Sequence

from mesh.fabric.settings import OPEN_ATTEMPT_MS, ROUTER_RUNTIME, MeshSettings
from mesh.process import end_now

if TYPE_CHECKING:
    import zenoh

log = logging.getLogger(__name__)
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
def open_session(settings: MeshSettings, thing: str | None = None, service: bool = False
                 ) -> Iterator[zenoh.Session]:
    """`with open_session(s) as session:` — the session closes (and its threads end) on exit.

    In a secure lab the session authenticates as the device `thing` (a Thing's own session: it may
    serve only that Thing's keys), as a service (the adapter, tdgen, the recorder), or else as the
    settings' role (a consumer)."""

    _init_logging()
    if thing is not None:
        settings = settings.as_role(f"device:{thing}")
    elif service:
        settings = settings.as_role("service")
    with _open_until_connected(settings, thing or ("a service" if service else settings.role)) as session:
        yield session


def _open_until_connected(settings: MeshSettings, who: str) -> "zenoh.Session":
    """`zenoh.open`, tried again while a part that waits for its router gets no session within an
    attempt (`OPEN_ATTEMPT_MS`): the router is not up yet, or a handshake hung."""
    import zenoh

    attempts = 0
    while True:
        try:
            return zenoh.open(settings.zenoh_config())
        except zenoh.ZError as e:
            if not (settings.mode == "client" and settings.wait_for_router):
                raise
            attempts += 1
            log.warning("%s: no session with the router at %s after %d attempt(s) of %d s (%s); trying again",
                        who, ", ".join(settings.connect), attempts, OPEN_ATTEMPT_MS // 1000, e)


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
                       connect: Sequence[str] = (), gateway: bool = False) -> None:
    """Process entry for the lab's router: it listens where the lab's peers connect, and links to the
    routers at `connect` (another host's lab, for `up --join`). `gateway`: this host's gateway instead,
    a client of the lab's router at `connect` whose own clients are its south region (`as_gateway`).

    A router that cannot listen (the port was taken after `up` checked it) logs one line and
    exits with code 1, so the supervisor stops the lab instead of leaving it without a router. Once
    `stop` is set, the process ends at once (`mesh.process.end_now`): its links close together.
    """
    os.environ.setdefault("ZENOH_RUNTIME", ROUTER_RUNTIME)  # read once, when Zenoh's runtime starts
    import zenoh

    router = (settings.as_gateway(tuple(listen), tuple(connect)) if gateway
              else settings.as_router(tuple(listen) or None, tuple(connect)))
    while True:
        devices = _devices(router)
        with ExitStack() as stack:
            try:
                stack.enter_context(open_session(router))
            except zenoh.ZError as e:
                logging.getLogger(__name__).error("the router cannot listen on %s: %s", ", ".join(listen), e)
                raise SystemExit(1) from None
            while not stop.wait(ACL_RELOAD_EVERY if devices is not None else None):
                if _devices(router) != devices:  # a device got its credential: the access rules must know it
                    logging.getLogger(__name__).warning("new device credentials: the router restarts with "
                                                        "their access rules (links reconnect)")
                    break
            else:
                end_now()


def _own_secrets(settings: MeshSettings) -> MeshSettings | None:
    """`settings` with this account's lab secrets, when they were not given and exist."""
    import msgspec

    from mesh.fabric.secrets import default_secrets_dir

    folder = default_secrets_dir()
    if settings.secrets is not None or not (folder / "ca.pem").exists():
        return None
    return msgspec.structs.replace(settings, secrets=str(folder))


ACL_RELOAD_EVERY = 1.0  # s between two looks for new device credentials (secure labs)


def _devices(settings: MeshSettings) -> list[str] | None:
    if settings.secrets is None:
        return None
    from mesh.fabric.secrets import LabSecrets

    return LabSecrets(settings.secrets).devices()


@contextmanager
def one_shot_session(settings: MeshSettings, mode_given: bool = False, service: bool = False
                     ) -> Iterator[zenoh.Session]:
    """A session for a short-lived consumer (a CLI command, a workflow).

    Client mode unless a mode was asked for: a fresh peer may query before the router's
    declarations reach it and find nobody; a client sends every query to the router.
    It does not wait for a router: raises Unavailable at once when no lab is reachable. Without
    `--secure`, a lab that only a secure session reaches is tried with this account's secrets
    (`default_secrets_dir`), if there are any: commands find a secure lab by themselves.
    """
    import msgspec
    import zenoh

    from mesh.fabric.secrets import SecretsError
    from mesh.wot.problem import Unavailable

    settings = msgspec.structs.replace(settings, wait_for_router=False)
    if not mode_given:
        settings = msgspec.structs.replace(settings, mode="client")
    unreachable = (f"no lab reachable at {', '.join(settings.connect)} (is `twinmesh up` running? a lab started "
                   "with --secure needs --secure here too)" if settings.secrets is None else
                   f"no secure lab reachable at {', '.join(settings.connect)} with the credentials in "
                   f"{settings.secrets} (is `twinmesh --secure up` running there, with these secrets?)")
    with ExitStack() as stack:
        try:
            session = stack.enter_context(open_session(settings, service=service))
        except SecretsError as e:  # a secure lab's secrets are not (yet) there
            raise Unavailable(str(e), reason="no-lab") from None
        except zenoh.ZError:  # a client that reaches no router fails to open
            secure = _own_secrets(settings)
            if secure is None:
                raise Unavailable(unreachable, reason="no-lab") from None
            try:
                session = stack.enter_context(open_session(secure, service=service))
            except (zenoh.ZError, SecretsError):
                raise Unavailable(unreachable, reason="no-lab") from None
            settings = secure
        if not is_connected(session) and settings.mode != "router":
            raise Unavailable(unreachable, reason="no-lab")
        yield session
