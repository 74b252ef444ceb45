"""A Thing outside the mesh, driven through its own TD's http(s) forms (never by affordance names, never
its MQTT forms), with what it answers turned into the problems a mesh client understands: its own
4xx as it said it, its credentials refused as 502 naming them (never a raw 401 passed on to our
caller, whose own credentials are fine), not answering as 503."""
from __future__ import annotations

import logging
from typing import Any, Callable
from urllib.parse import urlsplit

from mesh.http.http_client import HttpClient
from mesh.wot.consumed import NOTHING, Callback, ConsumedThing, Subscription
from mesh.wot.problem import BadGateway, NotAllowed, NotFound, Problem, Unavailable

log = logging.getLogger(__name__)


class RemoteThing:
    """One remote Thing, consumed through `client` (one connection pool and one set of credentials)."""

    def __init__(self, td: dict[str, Any], client: HttpClient, source: str):
        self.source = source
        self.host = urlsplit(source).netloc or source
        self.consumed = ConsumedThing(td, [client])
        self.td = self.consumed.td
        self.title = self.td.title

    def can(self, kind: str, name: str, op: str) -> bool:
        """Whether the remote TD offers `op` on the affordance through a form this client performs."""
        affordance = self.td.affordance(kind, name)  # type: ignore[arg-type]
        return affordance is not None and next(self.consumed._candidates(affordance.forms, op), None) is not None

    def read(self, prop: str) -> Any:
        return self._relay(f"read {prop}", self.consumed.read_property, prop)

    def write(self, prop: str, value: Any) -> None:
        self._relay(f"write {prop}", self.consumed.write_property, prop, value)

    def invoke(self, action: str, input: Any = NOTHING) -> Any:
        return self._relay(action, self.consumed.invoke_action, action, input)

    def observe(self, prop: str, callback: Callback) -> Subscription:
        return self._relay(f"observe {prop}", self.consumed.observe_property, prop, callback)

    def subscribe(self, event: str, callback: Callback) -> Subscription:
        return self._relay(f"subscribe {event}", self.consumed.subscribe_event, event, callback)

    def _relay(self, what: str, call: Callable[..., Any], *args: Any) -> Any:
        try:
            return call(*args)
        except Problem as p:
            raise self.relayed(p, what) from None

    def relayed(self, p: Problem, what: str) -> Problem:
        """What the caller of a bridged affordance gets for the remote's problem `p`."""
        if p.status in (401, 403):
            return BadGateway(f"{self.title} at {self.host} refused the bridge's credentials for {what} "
                              f"(HTTP {p.status}): check the bridge's --auth", reason="remote-credentials")
        if p.reason == "tls-untrusted":
            return BadGateway(f"{self.title} at {self.host}: {p.detail} ({what})", reason="remote-tls")
        if isinstance(p, Unavailable):
            return Unavailable(f"{self.title} at {self.host} is not answering ({what}): {p.detail or p}",
                               reason="remote-unavailable")
        if isinstance(p, NotFound) and "form this consumer can use" in str(p):
            return NotAllowed(f"{self.title} offers no http(s) form for {what}: {p}")
        if p.status >= 500:
            return BadGateway(f"{self.title} at {self.host} failed ({what}): HTTP {p.status}: {p.detail or p}",
                              reason="remote-failed")
        return p  # the remote's own answer (a bad input, a refusal), as it said it
