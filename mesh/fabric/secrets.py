"""A lab's secrets for `--secure`: its own certificate authority, a certificate per role, the HTTP token.

Zenoh then runs over TLS with mutual authentication, and the lab's router applies access control
by the certificate's common name (`access_control`): a peer without a certificate of this CA gets
no link at all. Roles:

| role | common name | may |
|---|---|---|
| router | `twinmesh-router` | everything (routers of one lab on several hosts) |
| service | `twinmesh-service` | everything (the adapter, tdgen, the recorder, the 3D view, `up` itself) |
| device `<thing>` | `twinmesh-device:<thing>` | serve, publish, be alive under `<prefix>/<thing>` only; ask anywhere |
| consumer | `twinmesh-consumer` | query (read, write, invoke), subscribe, ask liveliness; nothing that serves or announces |

Files (the directory 0700, every file 0600): `ca.pem`, `ca-key.pem`, `<role>.pem`, `<role>-key.pem`,
`devices/<thing>.pem`, `devices/<thing>-key.pem`, `http-token`. Whoever can read `ca-key.pem` can
issue any credential: it stays with the lab's account (and the hosts that join the lab).
"""
from __future__ import annotations

import datetime
import fcntl
import os
import secrets as random_secrets
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

import platformdirs

ROLES = ("router", "service", "consumer")
DEVICE = "device"
CN_PREFIX = "twinmesh-"
VALID_DAYS = 3650


def default_secrets_dir() -> Path:
    """`$TWINMESH_SECRETS`, else in the user's data directory (`$XDG_DATA_HOME/twinmesh/secrets` on Linux, by
    default `~/.local/share/twinmesh/secrets`): where commands on this account look."""
    env = os.environ.get("TWINMESH_SECRETS")
    if env:
        return Path(env)
    return platformdirs.user_data_path("twinmesh") / "secrets"


def common_name(role: str) -> str:
    """`twinmesh-router`, ..., `twinmesh-device:<thing>` for `device:<thing>`."""
    return CN_PREFIX + role


class SecretsError(Exception):
    """A lab's secrets cannot be read or made (named, for a clear CLI message)."""


class LabSecrets:
    """The secrets directory of a lab: made on first use, read by every process of the lab."""

    def __init__(self, directory: str | os.PathLike[str]):
        self.dir = Path(directory)

    # --- paths ---------------------------------------------------------------------------------
    @property
    def ca(self) -> Path:
        return self.dir / "ca.pem"

    def files(self, role: str) -> tuple[Path, Path]:
        """(certificate, key) of `role`: router, service, consumer or `device:<thing>`."""
        if role.startswith(f"{DEVICE}:"):
            thing = role.split(":", 1)[1]
            return self.dir / "devices" / f"{thing}.pem", self.dir / "devices" / f"{thing}-key.pem"
        if role not in ROLES:
            raise SecretsError(f"no such role {role!r}; roles: {', '.join(ROLES)}, device:<thing>")
        return self.dir / f"{role}.pem", self.dir / f"{role}-key.pem"

    def devices(self) -> list[str]:
        """The Things that hold a device credential."""
        folder = self.dir / "devices"
        return sorted(p.name[:-4] for p in folder.glob("*.pem") if not p.name.endswith("-key.pem")) \
            if folder.is_dir() else []

    # --- making them -------------------------------------------------------------------------
    def ensure(self) -> "LabSecrets":
        """Create the directory, the CA, the three role credentials and the HTTP token where missing."""
        with self._lock():
            self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
            os.chmod(self.dir, 0o700)
            if not self.ca.exists():
                self._make_ca()
            for role in ROLES:
                if not self.files(role)[0].exists():
                    self._issue(role)
            token = self.dir / "http-token"
            if not token.exists():
                _write(token, random_secrets.token_urlsafe(32).encode())
        return self

    def credential(self, role: str) -> tuple[Path, Path]:
        """(certificate, key) of `role`, issued now by the lab's CA if missing (needs `ca-key.pem`)."""
        cert, key = self.files(role)
        if cert.exists() and key.exists():
            return cert, key
        if not self.ca.exists():
            raise SecretsError(f"no lab secrets in {self.dir} (no ca.pem): start the lab with "
                               f"`twinmesh --secure up` (or give --secrets DIR)")
        with self._lock():
            if not (cert.exists() and key.exists()):
                self._issue(role)
        return cert, key

    def http_token(self) -> str:
        path = self.dir / "http-token"
        try:
            return path.read_text().strip()
        except OSError as e:
            raise SecretsError(f"cannot read the lab's HTTP token {path}: {e.strerror}") from None

    def _make_ca(self) -> None:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import NameOID

        key = ec.generate_private_key(ec.SECP256R1())
        name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, "twinmesh lab CA")])
        now = datetime.datetime.now(datetime.timezone.utc)
        cert = (x509.CertificateBuilder().subject_name(name).issuer_name(name).public_key(key.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(days=1))
                .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
                .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
                .add_extension(x509.KeyUsage(digital_signature=True, key_cert_sign=True, crl_sign=True,
                                             content_commitment=False, key_encipherment=False,
                                             data_encipherment=False, key_agreement=False, encipher_only=False,
                                             decipher_only=False), critical=True)
                .sign(key, hashes.SHA256()))
        _write(self.dir / "ca-key.pem", _key_pem(key))
        _write(self.ca, _cert_pem(cert))

    def _issue(self, role: str) -> None:
        from cryptography import x509
        from cryptography.hazmat.primitives import hashes, serialization
        from cryptography.hazmat.primitives.asymmetric import ec
        from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID

        try:
            ca_key = serialization.load_pem_private_key((self.dir / "ca-key.pem").read_bytes(), None)
            ca_cert = x509.load_pem_x509_certificate(self.ca.read_bytes())
        except OSError as e:
            raise SecretsError(f"cannot issue a {role} credential: {e.filename}: {e.strerror}") from None
        key = ec.generate_private_key(ec.SECP256R1())
        now = datetime.datetime.now(datetime.timezone.utc)
        cert = (x509.CertificateBuilder()
                .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, common_name(role))]))
                .issuer_name(ca_cert.subject).public_key(key.public_key())
                .serial_number(x509.random_serial_number()).not_valid_before(now - datetime.timedelta(days=1))
                .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
                # zenoh checks no host name (verify_name_on_connect is off: the lab's CA is the trust), but
                # TLS libraries want a subject alternative name on a server certificate
                .add_extension(x509.SubjectAlternativeName([x509.DNSName("twinmesh")]), critical=False)
                .add_extension(x509.ExtendedKeyUsage([ExtendedKeyUsageOID.SERVER_AUTH,
                                                      ExtendedKeyUsageOID.CLIENT_AUTH]), critical=False)
                .sign(ca_key, hashes.SHA256()))  # type: ignore[arg-type]
        cert_path, key_path = self.files(role)
        cert_path.parent.mkdir(parents=True, exist_ok=True, mode=0o700)
        _write(key_path, _key_pem(key))
        _write(cert_path, _cert_pem(cert))

    @contextmanager
    def _lock(self) -> Iterator[None]:
        """One process at a time makes files (many device processes start at once)."""
        self.dir.mkdir(parents=True, exist_ok=True, mode=0o700)
        fd = os.open(self.dir / ".lock", os.O_WRONLY | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            yield
        finally:
            os.close(fd)  # and the lock with it


def _write(path: Path, data: bytes) -> None:
    """Owner-only, atomically (a reader never sees half a key)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.replace(tmp, path)


def _key_pem(key) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return key.private_bytes(serialization.Encoding.PEM, serialization.PrivateFormat.PKCS8,
                             serialization.NoEncryption())


def _cert_pem(cert) -> bytes:
    from cryptography.hazmat.primitives import serialization

    return cert.public_bytes(serialization.Encoding.PEM)


def access_control(prefix: str, devices: list[str]) -> dict:
    """The router's access control: deny by default; routers and services all; each device its own keys;
    consumers ask and listen only."""
    everything = ["**"]
    asks = ["query", "declare_subscriber", "liveliness_query", "declare_liveliness_subscriber"]
    serves = ["declare_queryable", "reply", "put", "delete", "liveliness_token"]
    rules = [
        {"id": "all", "messages": [*asks, *serves], "flows": ["ingress", "egress"], "permission": "allow",
         "key_exprs": everything},
        {"id": "ask", "messages": asks, "flows": ["ingress"], "permission": "allow", "key_exprs": everything},
        {"id": "hear", "messages": [*asks, *serves], "flows": ["egress"], "permission": "allow",
         "key_exprs": everything},
    ]
    subjects = [{"id": "router", "cert_common_names": [common_name("router")]},
                {"id": "service", "cert_common_names": [common_name("service")]},
                {"id": "consumer", "cert_common_names": [common_name("consumer")]}]
    policies = [{"id": "router", "rules": ["all"], "subjects": ["router"]},
                {"id": "service", "rules": ["all"], "subjects": ["service"]},
                {"id": "consumer", "rules": ["ask", "hear"], "subjects": ["consumer"]}]
    for i, thing in enumerate(devices):
        rules.append({"id": f"own-{i}", "messages": serves, "flows": ["ingress"], "permission": "allow",
                      "key_exprs": [f"{prefix}/{thing}", f"{prefix}/{thing}/**"]})
        subjects.append({"id": f"device-{i}", "cert_common_names": [common_name(f"{DEVICE}:{thing}")]})
        policies.append({"id": f"device-{i}", "rules": ["ask", "hear", f"own-{i}"], "subjects": [f"device-{i}"]})
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}
