"""twinmesh: a digital-twin lab for the Web of Things.

The packages, each importing only those listed before it: `wot` (protocol-neutral TD model,
validation, problems), `messages` (wire Structs), `fabric` (the Zenoh binding), `http` (the WoT
HTTP binding), `robot` (URDF, kinematics, IK, collision, workspace, planning), `tdgen` (robot TD
generation), `sim` (pybullet world and device models), `things` (one binding per device kind),
`recorder` (Rerun), `apps` (cube workflow, evaluation), `lab` (processes, scenes, supervisor),
`cli` (click only). Nothing imports `lab` or `cli`.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

from twinmesh.wot.consumed import NOTHING, ConsumedThing, Consumer, Invocation
from twinmesh.wot.problem import Problem

if TYPE_CHECKING:
    from twinmesh.fabric.settings import MeshSettings

__all__ = ["NOTHING", "ConsumedThing", "Consumer", "Invocation", "Problem", "consume", "consumer"]


def consumer(*, session: Any = None, settings: MeshSettings | None = None, auth: str | None = None,
             base: str | None = None, action_timeout: float = 300.0) -> Consumer:
    """The clients for consuming Things: HTTP always (with `auth`, `bearer:TOKEN` or `basic:USER:PASS`),
    Zenoh when given an open `session`. `Consumer.thing(name)` finds a Thing by name at `{base}/{name}`
    when a base URL is given, else on the mesh."""
    from twinmesh.http.client import HttpClient

    clients: list[Any] = []
    resolve = None
    if session is not None:
        from twinmesh.fabric.client import ZenohClient

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
