"""One typed settings object for a peer; CLI flags and environment map onto it."""
from __future__ import annotations

import json
from typing import Literal

import msgspec

from mesh.fabric.keys import Keys

DEFAULT_ENDPOINT = "tcp/127.0.0.1:7447"
Mode = Literal["peer", "client", "router"]


# Zenoh expires a link after the lease its *other* end announced, and each end sends keep-alives every
# own lease / 4. A gateway that joins another host's lab (or a robot that joins it directly, `robot
# --join`) announces a short lease, so that the lab sees a cut cable within 1.5 s. No other process
# does: the lab's router would send each of its local clients a keep-alive every 0.375 s (a fleet's
# worth of messages at idle; the figure: docs/benchmarks.md).
JOINING_LEASE_MS = 1500
# Everything else, the lab's router and every client (a device, a service), announces a long lease:
# a link is expired only after 60 s of silence, and a keep-alive goes every 15 s. A process on the
# same host that dies closes its socket, which the other end sees at once; but a router busy with
# thousands of sessions starting may send or read a keep-alive late, and must not drop a healthy
# client for it (which then reconnects and declares everything again, as 10,000 devices did; and
# devices of other hosts linked straight to the lab's router, `up --join --direct`, with a 10 s lease).
LOCAL_LEASE_MS = 60_000
ROUTER_MAX_SESSIONS = 100_000  # Zenoh's default (1,000) would cap a host at 1,000 devices
# A host's devices all open their sessions at once. Zenoh's router (and gateway) closes a new link outright
# while 100 handshakes are pending (`accept_pending`), and a handshake that takes 10 s fails on both ends:
# under that load the devices retried, each retry another handshake, and a host of 1,000 never settled
# (thousands of sockets the gateway had not yet accepted, closed by the devices that gave up). The
# figures of Zenoh's own deployments of hundreds of nodes starting together (rmw_zenoh's router
# configuration): 10,000 pending, 60 s to open or accept.
ACCEPT_PENDING = 10_000
HANDSHAKE_MS = 60_000
# Zenoh closes a dead link's TCP socket with a 10 s linger, synchronously, on one of its 2 receive
# threads (zenoh#1101, zenoh#2718): a cut host's two links (its router, a robot joined directly) held
# both, and the lab's router forwarded nothing until the linger ended, its own devices' reads included. The
# router gets 16 receive threads: as many links can die at once before one healthy link waits.
ROUTER_RUNTIME = "(rx: (worker_threads: 16))"  # Zenoh's runtime settings (ZENOH_RUNTIME), for routers
# A part's session waits for its router at most this long per attempt, then `open_session` tries
# again: one of 10,000 devices joining a busy router hung in its handshake (an answer from the router
# left unread in its socket) and, with no bound, it waited for ever and its host never became ready.
OPEN_ATTEMPT_MS = 30_000
RETRY_MS = (250, 1000)  # a device reconnects this fast after its router came back (first, longest pause)


class MeshSettings(msgspec.Struct, frozen=True, kw_only=True):
    """How a process joins the mesh.

    Defaults give a closed loopback lab: every process connects to the lab's router on
    127.0.0.1:7447 (started by `twinmesh up`) and multicast scouting is off, so a test run never
    meets a neighbour's lab. `listen`/`connect` and `mode="router"` let peers on other hosts join.

    Topology: every device and service is a Zenoh *client* of its host's router (a star: one TCP
    link and one descriptor per device, whatever the number of devices), not a *peer* (peers link
    to every other peer: N²/2 links). Shared memory is off unless asked for: the mesh carries small
    JSON, and each shared-memory link costs segments and descriptors (with it, a router took
    far fewer local sessions). `wait_for_router`: a lab's parts wait (retrying every 0.25..1 s, a new
    session every 30 s) for their router, which starts beside them and may restart; one-shot commands fail at once.

    `secrets` (a directory, `mesh.fabric.secrets`): the lab is secure: TLS with mutual
    authentication on every link (`tcp/` endpoints become `tls/`), the router applies access
    control, and this process authenticates as `role` (consumer, service, router or
    `device:<thing>`: `open_session` picks it).
    """

    prefix: str = "wot"
    mode: Mode = "client"
    connect: tuple[str, ...] = (DEFAULT_ENDPOINT,)
    listen: tuple[str, ...] = ()
    multicast: bool = False
    shared_memory: bool = False
    wait_for_router: bool = True
    secrets: str | None = None
    crosses_hosts: bool = False  # its link goes to another host's router: announce the short lease
    gateway: bool = False  # a joining host's gateway: a client of the lab's router, this host's clients its south
    role: str = "consumer"
    query_timeout: float = 5.0   # reads, writes, TDs
    action_timeout: float = 300.0  # motions return when done, which can take minutes at speed 1
    overrides: tuple[tuple[str, str], ...] = ()  # (Zenoh config path, JSON value) applied last: `--config FILE`

    @property
    def keys(self) -> Keys:
        return Keys(self.prefix)

    def zenoh_config(self):  # -> zenoh.Config (import kept local: zenoh loads a native library)
        import zenoh

        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        conf.insert_json5("scouting/multicast/enabled", json.dumps(self.multicast))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps([self._secure(e) for e in self.listen]))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps([self._secure(e) for e in self.connect]))
        if self.secrets is not None:
            self._tls(conf)
        conf.insert_json5("transport/shared_memory/enabled", json.dumps(self.shared_memory))
        first, longest = RETRY_MS
        conf.insert_json5("connect/retry", json.dumps(
            {"period_init_ms": first, "period_max_ms": longest, "period_increase_factor": 2}))
        joins = self.crosses_hosts or self.mode == "router" and bool(self.connect)
        lease = JOINING_LEASE_MS if joins else LOCAL_LEASE_MS
        if self.mode != "peer":  # peers keep Zenoh's defaults: the old topology, measured as it was
            conf.insert_json5("transport/link/tx/lease", json.dumps(lease))
        if self.mode == "client" and self.wait_for_router:
            conf.insert_json5("connect/timeout_ms", json.dumps({"router": -1, "peer": -1, "client": OPEN_ATTEMPT_MS}))
            conf.insert_json5("connect/exit_on_failure", json.dumps({"router": False, "peer": False, "client": True}))
        conf.insert_json5("transport/unicast/open_timeout", json.dumps(HANDSHAKE_MS))
        if self.mode == "router" or self.gateway:
            conf.insert_json5("transport/unicast/max_sessions", json.dumps(ROUTER_MAX_SESSIONS))
            conf.insert_json5("transport/unicast/accept_pending", json.dumps(ACCEPT_PENDING))
            conf.insert_json5("transport/unicast/accept_timeout", json.dumps(HANDSHAKE_MS))
        if self.gateway:
            conf.insert_json5("gateway", json.dumps({"south": [{"filters": [{"modes": ["client", "peer"]}]}]}))
        for path, value in self.overrides:
            conf.insert_json5(path, value)
        return conf

    def as_router(self, listen: tuple[str, ...] | None = None, connect: tuple[str, ...] = ()) -> "MeshSettings":
        """The settings of the lab's router: it listens where the peers connect (and links to the
        routers at `connect`: one router per host, the routers connected)."""
        return msgspec.structs.replace(self, mode="router", listen=listen or self.connect, connect=connect,
                                       role="router")

    def as_gateway(self, listen: tuple[str, ...], lab: tuple[str, ...]) -> "MeshSettings":
        """The settings of a joining host's gateway (Zenoh's regions): one client of the lab's router at `lab`
        for the whole host, its own clients (the host's devices, at `listen`) a region south of it. The
        lab's router then holds one link per host, not one per device: a Zenoh router does work in
        proportion to the links it holds for every link that opens or closes, and routers linked to
        routers each hold every key of the others."""
        return msgspec.structs.replace(self, mode="client", listen=listen, connect=lab, role="router",
                                       crosses_hosts=True, gateway=True)

    @property
    def endpoints(self) -> tuple[str, ...]:
        """The endpoints this process connects to, as Zenoh is given them (`tls/` in a secure lab)."""
        return tuple(self._secure(e) for e in self.connect)

    def as_role(self, role: str) -> "MeshSettings":
        """These settings authenticating as `role` (without secrets: unchanged)."""
        return self if self.secrets is None else msgspec.structs.replace(self, role=role)

    def _secure(self, endpoint: str) -> str:
        return "tls/" + endpoint[4:] if self.secrets is not None and endpoint.startswith("tcp/") else endpoint

    def _tls(self, conf) -> None:
        from mesh.fabric.secrets import LabSecrets, access_control

        secrets = LabSecrets(self.secrets or "")
        cert, key = secrets.credential(self.role)
        conf.insert_json5("transport/link/tls", json.dumps({
            "root_ca_certificate": str(secrets.ca), "enable_mtls": True,
            "verify_name_on_connect": False,  # the lab's own CA is the trust: hosts are reached by any address
            "listen_certificate": str(cert), "listen_private_key": str(key),
            "connect_certificate": str(cert), "connect_private_key": str(key)}))
        if self.mode == "router" or self.gateway:
            conf.insert_json5("access_control", json.dumps(access_control(self.prefix, secrets.devices())))


def router_listen(listen: tuple[str, ...], connect: tuple[str, ...]) -> list[str]:
    """Where a lab's router listens: the `--listen` endpoints, and the endpoints its own processes connect
    to, unless a wildcard listen endpoint (`tcp/0.0.0.0:7447`) already covers that port."""
    def split(endpoint: str) -> tuple[str, str, str]:
        proto, _, rest = endpoint.partition("/")
        host, _, port = rest.split("#", 1)[0].rpartition(":")
        return proto, host.strip("[]"), port

    wildcard = {(proto, port) for proto, host, port in map(split, listen) if host in ("0.0.0.0", "::")}
    out = list(listen)
    for endpoint in connect:
        proto, _, port = split(endpoint)
        if endpoint not in out and (proto, port) not in wildcard:
            out.append(endpoint)
    return out


OWN_KEYS = ("mode", "connect", "listen")  # set by twinmesh's own options in every process: not from a file


class ConfigFileError(ValueError):
    """A `--config` file that cannot be applied; the message names the file and the problem."""


def config_overrides(path: str) -> tuple[tuple[str, str], ...]:
    """The settings of a Zenoh configuration file (JSON5, Zenoh's own format and key names) as
    (path, JSON value) pairs, applied over twinmesh's own settings in every process of the lab.
    Objects are merged key by key; a list or a value replaces twinmesh's."""
    import json5

    try:
        with open(path, encoding="utf-8") as f:
            document = json5.load(f)
    except OSError as e:
        raise ConfigFileError(f"cannot read the Zenoh config file {path}: {e.strerror}") from None
    except ValueError as e:
        raise ConfigFileError(f"the Zenoh config file {path} is not JSON5: {e}") from None
    if not isinstance(document, dict):
        raise ConfigFileError(f"the Zenoh config file {path} must hold an object ({{...}})")
    own = sorted(set(document) & set(OWN_KEYS))
    if own:
        raise ConfigFileError(f"the Zenoh config file {path} sets {', '.join(own)}: twinmesh sets these itself "
                              "(--mode, --connect, --listen, `up --join`)")

    def leaves(value, prefix: str):
        if isinstance(value, dict) and value:
            for key, inner in value.items():
                yield from leaves(inner, f"{prefix}/{key}" if prefix else str(key))
        else:
            yield prefix, json.dumps(value)

    overrides = tuple(leaves(document, ""))
    import zenoh

    for mode in ("client", "router"):  # tried here, not found wrong in each process of a lab
        conf = MeshSettings(mode=mode).zenoh_config()
        for key, value in overrides:
            try:
                conf.insert_json5(key, value)
            except zenoh.ZError as e:
                why = str(e).split(" at /")[0].strip('"').removeprefix('Str("').removesuffix('")')
                raise ConfigFileError(f"the Zenoh config file {path}: {key} = {value}: {why}") from None
    return overrides
