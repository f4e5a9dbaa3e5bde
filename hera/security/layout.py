"""The files of a credentials folder made by ``hera certs`` (no cryptography needed to find
them): the cluster CA, one certificate and key per identity, the cluster secret."""

from __future__ import annotations

import os
from pathlib import Path

CA_CERT = "ca.pem"
CA_KEY = "ca.key"


def cert_path(folder: str | os.PathLike, identity: str) -> Path:
    """Where ``identity``'s certificate is in ``folder``."""
    return Path(folder) / f"{identity}.pem"


def key_path(folder: str | os.PathLike, identity: str) -> Path:
    """Where ``identity``'s private key is in ``folder``."""
    return Path(folder) / f"{identity}.key"
