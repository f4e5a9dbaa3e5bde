"""The security modes the benchmarks compare, as spec text, and what each needs on disk.

``none``: no authentication, no access control; ``auth``: the spec's default (user and
password from the run's secret, access control); ``tls``: mutual TLS with access control,
certificates for every node and router of the spec and the operator made in a folder
(needs the ``tls`` extra, ``cryptography``).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

MODES = {
    "none": "[security]\nauth = false\naccess_control = false\n",
    "auth": "",
    "tls": '[security]\ntls = true\ncerts = "{certs}"\n',
}
"""Mode name -> the ``[security]`` table appended to a benchmark's spec text."""

TLS_HINT = "pip install 'hera-fusion[tls]'"
"""The install that gives the ``tls`` mode what it needs."""


def measurable_modes() -> list[str]:
    """The modes of :data:`MODES` this install can run: ``tls`` needs the ``tls`` extra
    (cryptography, to make the certificates), the others nothing more."""
    has_tls = importlib.util.find_spec("cryptography") is not None
    return [m for m in MODES if m != "tls" or has_tls]


LABELS = {"none": "no security", "auth": "user/password", "tls": "mutual TLS + ACL"}
"""Mode name -> how a benchmark's table names it."""


def modes(text: str, option: str) -> list[str]:
    """The modes of a comma-separated ``text``; ValueError naming ``option`` and the unknown
    mode."""
    chosen = [m.strip() for m in text.split(",") if m.strip()]
    for m in chosen:
        if m not in MODES:
            raise ValueError(f"{option}: unknown {m!r}; use {', '.join(MODES)}")
    return chosen


def secure(text: str, mode: str, certs: str | Path) -> str:
    """The spec ``text`` with ``mode``'s ``[security]`` table; for ``tls``, the certificates
    of every identity of the spec made in ``certs`` first."""
    if mode == "tls":
        from hera.security.certs import make_certs  # the tls extra
        from hera.security.credentials import cert_hosts
        from hera.spec import parse_spec, tomllib

        spec = parse_spec(tomllib.loads(text), "benchmark spec")
        make_certs(certs, spec.name, cert_hosts(spec))
    return text + MODES[mode].format(certs=Path(certs).as_posix())
