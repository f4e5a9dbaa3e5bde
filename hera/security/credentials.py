"""Who a process is on the bus, and the Zenoh settings that prove it.

A :class:`Credentials` names one identity (a node, a router, or ``operator`` for tools and
launchers) and how it authenticates:

- **user/password** (the default, even on loopback): the password of the identity is
  derived from the cluster secret (:mod:`hera.security.secret`); each process checks the
  others against every identity's password;
- **mutual TLS** (``[security] tls = true``): the identity's certificate and key from the
  ``hera certs`` folder, the cluster CA as the only root; every endpoint is ``tls/``, plain
  TCP is refused.

:meth:`Credentials.secure` turns a :class:`hera.bus.BusConfig` into the secured one, with
the spec's access control (:mod:`hera.security.access`) when asked.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any

from hera.bus import BusConfig
from hera.security.access import OPERATOR, access_control
from hera.security.layout import CA_CERT, cert_path, key_path
from hera.security.secret import SECRET_FILE, SecretError, password, read_secret
from hera.spec import ClusterSpec


class CredentialsError(ValueError):
    """Credentials that cannot be used; the message says which file or setting and why."""


@dataclass(frozen=True)
class Credentials:
    """One identity and what proves it (see the module docstring)."""

    identity: str
    secret: bytes | None = None
    tls_dir: Path | None = None
    known: tuple[str, ...] = ()
    """The identities whose passwords this process checks links against."""

    def secure(self, bus: BusConfig, acl: dict[str, Any] | None = None) -> BusConfig:
        """``bus`` with this identity's authentication (and ``acl`` as access control)."""
        extra = dict(bus.extra)
        listen, connect, dictionary = bus.listen, bus.connect, None
        if self.tls_dir is not None:
            d = self.tls_dir
            key, cert = str(key_path(d, self.identity)), str(cert_path(d, self.identity))
            extra["transport/link/tls"] = {
                "root_ca_certificate": str(d / CA_CERT),
                "enable_mtls": True,
                "listen_private_key": key,
                "listen_certificate": cert,
                "connect_private_key": key,
                "connect_certificate": cert,
                "verify_name_on_connect": True,
            }
            extra["transport/link/protocols"] = ["tls"]
            listen, connect = tuple(map(as_tls, listen)), tuple(map(as_tls, connect))
        elif self.secret is not None:
            extra["transport/auth/usrpwd"] = {
                "user": self.identity,
                "password": password(self.secret, self.identity),
            }
            if self.known:
                dictionary = "".join(f"{who}:{password(self.secret, who)}\n" for who in self.known)
        if acl is not None:
            extra["access_control"] = acl
        return replace(bus, listen=listen, connect=connect, extra=extra, dictionary=dictionary)


def as_tls(endpoint: str) -> str:
    """``tcp/host:port`` as ``tls/host:port`` (other endpoints unchanged)."""
    return "tls/" + endpoint[4:] if endpoint.startswith("tcp/") else endpoint


def identities(spec: ClusterSpec) -> list[str]:
    """Every identity of the cluster: its nodes, its routers and the operator."""
    return [*(n.name for n in spec.nodes), *(r.name for r in spec.routers), OPERATOR]


def cluster_acl(spec: ClusterSpec) -> dict[str, Any] | None:
    """The access control of the spec's cluster, or None when it is off or the links are
    not TLS. Measured (tests/unit/test_security.py): user/password authentication names
    only the side that opened a link to the side that accepted it, so in a mesh where both
    sides run access control the opener's messages from the acceptor match no subject and
    are all denied; mutual TLS names both ends (the certificates' common names)."""
    if not spec.access_control or not spec.tls:
        return None
    trusted = [r.name for r in spec.routers] + [OPERATOR]
    return access_control(spec.name, [n.name for n in spec.nodes], trusted, spec.tls)


def _check_tls_dir(folder: Path, identity: str) -> Path:
    missing = [
        str(p)
        for p in (folder / CA_CERT, cert_path(folder, identity), key_path(folder, identity))
        if not p.exists()
    ]
    if missing:
        raise CredentialsError(
            f"no TLS credentials for {identity!r}: missing {', '.join(missing)} (make them "
            f"with 'hera certs SPEC --out {folder}' and copy them to this host)"
        )
    return folder


def for_spec(spec: ClusterSpec, identity: str) -> Credentials | None:
    """The credentials of ``identity`` in a resolved spec (None: authentication is off)."""
    if spec.tls:
        if not spec.certs:
            raise CredentialsError(
                f"{spec.source}: [security] tls = true needs the certificates: certs = DIR "
                "(or --cert DIR), a folder made by 'hera certs SPEC --out DIR'"
            )
        return Credentials(identity, tls_dir=_check_tls_dir(Path(spec.certs), identity))
    if not spec.auth:
        return None
    path = spec.secret or (str(Path(spec.certs) / SECRET_FILE) if spec.certs else None)
    if path is None:
        raise CredentialsError(
            f"{spec.source}: the cluster has no secret: start it with 'hera up' (which makes "
            "one), or give [security] certs = DIR made by 'hera certs'"
        )
    try:
        secret = read_secret(path)
    except SecretError as e:
        raise CredentialsError(str(e)) from None
    return Credentials(identity, secret=secret, known=tuple(identities(spec)))


def for_operator(cert_dir: str | Path, endpoints: list[str]) -> Credentials:
    """A tool's credentials from a ``hera certs`` folder: its TLS certificate when it
    connects to ``tls/`` endpoints, else the cluster secret there."""
    folder = Path(cert_dir)
    if any(e.startswith("tls/") for e in endpoints):
        return Credentials(OPERATOR, tls_dir=_check_tls_dir(folder, OPERATOR))
    try:
        return Credentials(OPERATOR, secret=read_secret(folder / SECRET_FILE))
    except SecretError as e:
        raise CredentialsError(str(e)) from None


def secured(spec: ClusterSpec, identity: str, bus: BusConfig) -> BusConfig:
    """``bus`` secured for ``identity`` of ``spec``: its credentials and the cluster's
    access control."""
    creds = for_spec(spec, identity)
    return bus if creds is None else creds.secure(bus, cluster_acl(spec))


def cert_hosts(spec: ClusterSpec) -> dict[str, list[str]]:
    """Every identity of the spec with the host addresses its certificate names: a node's
    or router's host and the hosts of its listen endpoints; none for the operator."""
    from hera.topology import host_of

    out: dict[str, list[str]] = {}
    for part in (*spec.nodes, *spec.routers):
        hosts = [host_of(spec, part)]
        for ep in part.listen or ():
            hosts.append(ep.split("/", 1)[1].rsplit(":", 1)[0].strip("[]"))
        out[part.name] = list(dict.fromkeys(hosts))
    out[OPERATOR] = []
    return out
