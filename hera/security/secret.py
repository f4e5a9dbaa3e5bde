"""The cluster secret: what user/password authentication derives every password from.

``hera up`` makes one per run in the run directory (``<run-dir>/secret``, mode 0600) unless
the spec names one (``[security] certs``: the ``secret`` file ``hera certs`` wrote, shared
by every host of the cluster). Each identity (a node, a router, ``operator``) authenticates
with its own password, ``HMAC-SHA256(secret, identity)``: a process given one identity's
password, and not the secret, can pass only for that identity.
"""

from __future__ import annotations

import hashlib
import hmac
import os
import secrets
import stat
from pathlib import Path

SECRET_FILE = "secret"
SECRET_BYTES = 32


class SecretError(ValueError):
    """A secret file that cannot be used; the message names the file and what is wrong."""


def make_secret(path: str | os.PathLike) -> Path:
    """Write a new random secret to ``path``, readable by its owner only (mode 0600)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "w") as f:
        f.write(secrets.token_hex(SECRET_BYTES) + "\n")
    return path


def read_secret(path: str | os.PathLike) -> bytes:
    """The secret in ``path``; SecretError if it is missing, empty, or readable by others
    than its owner (it would let them into the cluster)."""
    path = Path(path)
    try:
        mode = path.stat().st_mode
        text = path.read_text().strip()
    except OSError as e:
        raise SecretError(f"cannot read the cluster secret {path}: {e.strerror}") from None
    if mode & (stat.S_IRWXG | stat.S_IRWXO):
        raise SecretError(
            f"the cluster secret {path} is readable by others (mode {stat.S_IMODE(mode):o}): "
            "make it 0600"
        )
    if len(text) < 32:
        raise SecretError(f"the cluster secret {path} is too short (at least 32 characters)")
    return text.encode()


def password(secret: bytes, identity: str) -> str:
    """The password of ``identity``: hex HMAC-SHA256 of the identity under ``secret``."""
    return hmac.new(secret, identity.encode(), hashlib.sha256).hexdigest()
