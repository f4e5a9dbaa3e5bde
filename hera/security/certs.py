"""``hera certs SPEC --out DIR``: a cluster CA and one certificate per node, router and the
operator, with the ``cryptography`` package.

What DIR holds afterwards (every private key mode 0600):

- ``ca.pem``: the cluster CA certificate (every process trusts it and nothing else);
- ``ca.key``: the CA's private key: keep it off the cluster's machines (it is needed only
  to make more certificates; :func:`make_certs` re-uses it when it is there);
- ``<identity>.pem`` / ``<identity>.key``: each node's, router's and the ``operator``'s
  certificate and key. The certificate's common name is the identity (what access control
  matches), its subject alternative names the addresses of the host it runs on (what a
  connecting side verifies), plus ``localhost`` and ``127.0.0.1``;
- ``secret``: the cluster secret for user/password authentication (:mod:`.secret`), so that
  several hosts of a cluster without TLS share one.

Copy to each host only its own identities' files, ``ca.pem`` (and ``secret``): a node that
holds its own key cannot pass for another (README "Threat model").
"""

from __future__ import annotations

import datetime
import ipaddress
import os
from collections.abc import Iterable
from pathlib import Path

from hera.security.layout import CA_CERT, CA_KEY, cert_path, key_path  # noqa: F401

try:
    from cryptography import x509
except ImportError as e:  # an extra: the default loopback cluster needs no certificate
    raise ImportError(
        "certificates need the cryptography package: pip install 'hera-fusion[tls]'"
    ) from e
from cryptography.hazmat.primitives import hashes, serialization  # noqa: E402
from cryptography.hazmat.primitives.asymmetric import ec  # noqa: E402
from cryptography.x509.oid import ExtendedKeyUsageOID, NameOID  # noqa: E402

from hera.security.secret import SECRET_FILE, make_secret

VALID_DAYS = 3650


def _write_private(path: Path, data: bytes) -> None:
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(data)
    os.chmod(path, 0o600)


def _key_bytes(key: ec.EllipticCurvePrivateKey) -> bytes:
    return key.private_bytes(
        serialization.Encoding.PEM,
        serialization.PrivateFormat.PKCS8,
        serialization.NoEncryption(),
    )


def _names(hosts: Iterable[str]) -> list[x509.GeneralName]:
    out: list[x509.GeneralName] = []
    for h in dict.fromkeys([*hosts, "127.0.0.1", "localhost"]):
        try:
            out.append(x509.IPAddress(ipaddress.ip_address(h)))
        except ValueError:
            out.append(x509.DNSName(h))
    return out


def _ca(folder: Path, cluster: str) -> tuple[ec.EllipticCurvePrivateKey, x509.Certificate]:
    """The CA of ``folder`` (made when absent); ValueError naming the file when the folder
    holds half a CA or one that cannot be read (it is never replaced: every certificate
    signed by it would stop working)."""
    key_file, cert_file = folder / CA_KEY, folder / CA_CERT
    if key_file.exists() != cert_file.exists():
        have, lost = (key_file, cert_file) if key_file.exists() else (cert_file, key_file)
        raise ValueError(
            f"{folder}: holds {have.name} but not {lost.name}: a CA needs both (put "
            f"{lost.name} back, or give a new folder for a new CA)"
        )
    if key_file.exists():
        try:
            key = serialization.load_pem_private_key(key_file.read_bytes(), None)
        except (ValueError, TypeError):
            key = None
        if not isinstance(key, ec.EllipticCurvePrivateKey):
            raise ValueError(f"{key_file}: not the CA key made by 'hera certs' (PEM, EC)")
        try:
            cert = x509.load_pem_x509_certificate(cert_file.read_bytes())
        except ValueError:
            raise ValueError(
                f"{cert_file}: not the CA certificate made by 'hera certs' (PEM)"
            ) from None
        if cert.public_key() != key.public_key():
            raise ValueError(f"{folder}: {CA_KEY} is not the key of {CA_CERT}")
        return key, cert
    key = ec.generate_private_key(ec.SECP256R1())
    name = x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, f"hera {cluster} CA")])
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(name)
        .issuer_name(name)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
        .add_extension(x509.BasicConstraints(ca=True, path_length=0), critical=True)
        .add_extension(
            x509.KeyUsage(False, False, False, False, False, True, True, False, False), True
        )
        .sign(key, hashes.SHA256())
    )
    _write_private(folder / CA_KEY, _key_bytes(key))
    (folder / CA_CERT).write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return key, cert


def make_identity(
    folder: str | os.PathLike,
    identity: str,
    hosts: Iterable[str],
    ca: tuple[ec.EllipticCurvePrivateKey, x509.Certificate],
) -> Path:
    """Write ``identity``'s key and a certificate signed by ``ca`` (CN = identity, SANs =
    ``hosts`` plus localhost); return the certificate's path."""
    folder = Path(folder)
    ca_key, ca_cert = ca
    key = ec.generate_private_key(ec.SECP256R1())
    now = datetime.datetime.now(datetime.timezone.utc)
    cert = (
        x509.CertificateBuilder()
        .subject_name(x509.Name([x509.NameAttribute(NameOID.COMMON_NAME, identity)]))
        .issuer_name(ca_cert.subject)
        .public_key(key.public_key())
        .serial_number(x509.random_serial_number())
        .not_valid_before(now - datetime.timedelta(days=1))
        .not_valid_after(now + datetime.timedelta(days=VALID_DAYS))
        .add_extension(x509.BasicConstraints(ca=False, path_length=None), critical=True)
        .add_extension(x509.SubjectAlternativeName(_names(hosts)), critical=False)
        .add_extension(
            x509.ExtendedKeyUsage(
                [ExtendedKeyUsageOID.SERVER_AUTH, ExtendedKeyUsageOID.CLIENT_AUTH]
            ),
            critical=False,
        )
        .sign(ca_key, hashes.SHA256())
    )
    _write_private(key_path(folder, identity), _key_bytes(key))
    path = cert_path(folder, identity)
    path.write_bytes(cert.public_bytes(serialization.Encoding.PEM))
    return path


def make_certs(
    folder: str | os.PathLike, cluster: str, identities: dict[str, list[str]]
) -> list[Path]:
    """Make (or re-use) the CA of ``folder`` and a certificate for each identity
    (``{identity: [host addresses]}``), and the cluster secret if absent; return the
    certificates written."""
    folder = Path(folder)
    if not folder.exists():  # a folder of the user's keeps its mode (keys are 0600 anyway)
        folder.mkdir(parents=True)
        os.chmod(folder, 0o700)
    ca = _ca(folder, cluster)
    if not (folder / SECRET_FILE).exists():
        make_secret(folder / SECRET_FILE)
    return [make_identity(folder, name, hosts, ca) for name, hosts in identities.items()]


def common_name(path: str | os.PathLike) -> str:
    """The common name of the certificate at ``path``."""
    cert = x509.load_pem_x509_certificate(Path(path).read_bytes())
    return cert.subject.get_attributes_for_oid(NameOID.COMMON_NAME)[0].value
