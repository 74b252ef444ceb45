"""mesh: a Zenoh peer's and a mesh client's world, and its public surface: `consume()`, `Problem`,
`MeshSettings`.

Its parts, each importing only those listed before it: `wot` (protocol-neutral TD/TM model,
validation, problems, exposed and consumed Things), `messages` (wire Structs), `urdf_resources`
(where a URDF's files are), `process` (a part's stop event and name), `fabric` (the Zenoh binding),
`http` (the WoT HTTP binding), `recorder` (Rerun), `cli` (its commands). It imports nothing of
`tdgen` or `devices`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from mesh.fabric.settings import MeshSettings
    from mesh.wot.consumed import NOTHING, ConsumedThing, Consumer, Invocation
    from mesh.wot.problem import Problem

__all__ = ["NOTHING", "ConsumedThing", "Consumer", "Invocation", "MeshSettings", "Problem", "consume", "consumer"]


def __getattr__(name: str) -> Any:
    """The public names, loaded when first asked for: `import mesh.<part>` (a `twinmesh tdgen` run) loads
    neither Zenoh nor the WoT client and its schema validators."""
    if name == "MeshSettings":
        from mesh.fabric.settings import MeshSettings

        return MeshSettings
    if name == "Problem":
        from mesh.wot.problem import Problem

        return Problem
    if name in ("NOTHING", "ConsumedThing", "Consumer", "Invocation"):
        from mesh.wot import consumed

        return getattr(consumed, name)
    raise AttributeError(f"module 'mesh' has no attribute {name!r}")


def consumer(*, session: Any = None, settings: MeshSettings | None = None, auth: str | None = None,
             base: str | None = None, action_timeout: float = 300.0) -> Consumer:
    """The clients for consuming Things: HTTP always (with `auth`, `bearer:TOKEN` or `basic:USER:PASS`),
    Zenoh when given an open `session`. `Consumer.thing(name)` finds a Thing by name at `{base}/{name}`
    when a base URL is given, else on the mesh."""
    from mesh.http.http_client import HttpClient
    from mesh.wot.consumed import Consumer

    clients: list[Any] = []
    resolve = None
    if session is not None:
        from mesh.fabric.mesh_client import ZenohClient

        zenoh = ZenohClient(session, settings)
        clients.append(zenoh)
        resolve = lambda name: f"zenoh:{zenoh.mesh.keys.td(name)}"  # noqa: E731
    clients.append(HttpClient(auth, action_timeout=action_timeout))
    if base:
        resolve = lambda name: f"{base.rstrip('/')}/{name}"  # noqa: E731
    return Consumer(clients, resolve)


def consume(td: dict[str, Any] | str, *, session: Any = None, settings: MeshSettings | None = None,
            auth: str | None = None) -> ConsumedThing:
    """A Thing from its TD (a dict), its TD's URL, or its name on the mesh of `session`; it is driven by
    its TD's forms (the first one a client speaks: http(s), or zenoh with a session).

    >>> light = consume("http://127.0.0.1:8080/light-left")  # doctest: +SKIP
    >>> light.write_property("lightState", True)              # doctest: +SKIP
    """
    clients = consumer(session=session, settings=settings, auth=auth)
    thing = clients.thing(td) if isinstance(td, str) and ":" not in td else clients.consume(td)
    thing.owns(clients)
    return thing
