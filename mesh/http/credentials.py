"""HTTP credentials as `twinmesh up --auth` takes them (`bearer:TOKEN`, `basic:USER:PASS`): parsed once,
checked by the adapter's middleware, declared in TDs, and sent by the consumer's client (`mesh.http.http_client`
makes them an httpx auth: a TD generator needs no HTTP client)."""
from __future__ import annotations

import base64
import binascii
import hmac
from dataclasses import dataclass, field
from typing import Any, Literal

Scheme = Literal["bearer", "basic"]
REALM = "twinmesh"


@dataclass(frozen=True)
class Auth:
    """The configured credentials. `secret` is the token, or `user:password` for basic."""

    scheme: Scheme
    secret: str = field(repr=False)

    def accepts(self, authorization: str | None) -> bool:
        """Whether an `Authorization` header value carries the configured credentials."""
        if not authorization:
            return False
        kind, _, value = authorization.strip().partition(" ")
        if kind.lower() != self.scheme:
            return False
        value = value.strip()
        if self.scheme == "basic":
            try:
                value = base64.b64decode(value, validate=True).decode("utf-8")
            except (binascii.Error, UnicodeDecodeError):
                return False
        return hmac.compare_digest(value.encode(), self.secret.encode())  # constant time

    def challenge(self) -> str:
        if self.scheme == "basic":
            return f'Basic realm="{REALM}", charset="UTF-8"'
        return f'Bearer realm="{REALM}"'

    def security(self) -> tuple[dict[str, dict[str, Any]], list[str]]:
        """`(securityDefinitions, security)` for the TDs."""
        if self.scheme == "basic":
            return {"basic_sc": {"scheme": "basic", "in": "header", "name": "Authorization"}}, ["basic_sc"]
        # an opaque token, not a JWT: say so rather than let the `jwt` default stand
        return {"bearer_sc": {"scheme": "bearer", "in": "header", "name": "Authorization",
                              "format": "opaque"}}, ["bearer_sc"]



def parse_auth(spec: str | None) -> Auth | None:
    """`bearer:TOKEN` or `basic:USER:PASS` (the password may contain ':'); empty means no security."""
    if not spec:
        return None
    scheme, _, rest = spec.partition(":")
    if scheme == "bearer" and rest:
        return Auth("bearer", rest)
    if scheme == "basic":
        user, sep, password = rest.partition(":")
        if user and sep and password:
            return Auth("basic", f"{user}:{password}")
    raise ValueError("auth must be bearer:TOKEN or basic:USER:PASS")

