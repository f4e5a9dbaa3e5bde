"""Zenoh key expressions of a Hera cluster.

Every key lives under one cluster prefix ``hera/<cluster>/`` so that several clusters can
share a network (ARCHITECTURE.md, part 1):

- ``hera/<cluster>/data/<name>/<node>``: measurements and estimates (see :mod:`hera.wire`);
- ``hera/<cluster>/alive/<node>[/<worker>]``: liveliness tokens;
- ``hera/<cluster>/args/<key>``: the replicated arguments store;
- ``hera/<cluster>/seq/<name>/<node>``: queryable answering the latest seq a node has seen;
- ``hera/<cluster>/ctl/<node>/<verb>``: the control plane;
- ``hera/<cluster>/launcher/<id>/<verb>``: the launchers running the cluster's processes;
- ``hera/<cluster>/sync/<group>/...``: the synchronisation service;
- ``hera/<cluster>/sim/...``: the simulated physical world.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

MAX_CHUNK = 64
"""Longest name (a key chunk) accepted anywhere: in a spec and from the bus."""
_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")


def check_chunk(value: str, what: str) -> str:
    """Return ``value`` if it is a valid single key chunk, else raise ValueError naming ``what``.

    A chunk is one non-empty path element of at most :data:`MAX_CHUNK` ASCII letters,
    digits, ``_``, ``.`` or ``-``: no ``/``, no Zenoh wildcards (``*``, ``$``), no ``?``,
    ``#``, space or other character a file name could not carry. The same rule holds for
    the names of a spec and for every name taken from the bus.
    """
    if not isinstance(value, str) or not _CHUNK.match(value):
        shown = value if not isinstance(value, str) or len(value) <= 80 else value[:80] + "..."
        raise ValueError(
            f"invalid {what} {shown!r}: use letters, digits, '_', '.', '-' (no '/', '*', '$')"
        )
    if len(value) > MAX_CHUNK:
        raise ValueError(f"invalid {what} {value[:80]!r}...: longer than {MAX_CHUNK} characters")
    return value


_GLOB = re.compile(r"^[A-Za-z0-9_.\-*]+$")


def glob_chunk(pattern: str, what: str) -> str:
    """The Zenoh key-expression chunk of a name pattern with shell-like ``*`` wildcards:
    ``*`` alone (any name) stands, a ``*`` within a name (``obs*``, ``*_1``, ``t*k``)
    becomes Zenoh's in-chunk wildcard ``$*`` (several in a row as one). ValueError naming
    ``what`` for anything else a name could not hold (``/``, ``$``, ``?``, ``#``, space)."""
    if not isinstance(pattern, str) or not _GLOB.match(pattern) or len(pattern) > MAX_CHUNK:
        shown = pattern if not isinstance(pattern, str) or len(pattern) <= 80 else pattern[:80]
        raise ValueError(
            f"invalid {what} {shown!r}: use letters, digits, '_', '.', '-' and '*' wildcards"
        )
    if "*" not in pattern or pattern.strip("*") == "":
        return "*" if "*" in pattern else pattern
    return re.sub(r"\*+", "$*", pattern)


@dataclass(frozen=True)
class Keys:
    """Key expression builders for one cluster."""

    cluster: str

    def __post_init__(self) -> None:
        check_chunk(self.cluster, "cluster name")

    @property
    def prefix(self) -> str:
        return f"hera/{self.cluster}"

    def data(self, name: str = "*", node: str = "*") -> str:
        return f"{self.prefix}/data/{name}/{node}"

    def data_read(self, name: str) -> str:
        """The data key expression of a read: ``name``, ``prefix*`` (every name starting
        with prefix) or ``name/node`` (one sender only)."""
        name, _, node = name.partition("/")
        return self.data(glob_chunk(name, "name"), node or "*")

    def parse_data(self, key: str) -> tuple[str, str]:
        """Return ``(name, node)`` of a data key; ValueError if ``key`` is not one."""
        head = f"{self.prefix}/data/"
        if not key.startswith(head):
            raise ValueError(f"not a data key of cluster {self.cluster!r}: {key!r}")
        parts = key[len(head) :].split("/")
        if len(parts) != 2 or not all(parts):
            raise ValueError(f"data key must be {head}<name>/<node>, got {key[:200]!r}")
        return check_chunk(parts[0], "name"), check_chunk(parts[1], "node")

    def alive(self, node: str = "*", worker: str | None = None) -> str:
        base = f"{self.prefix}/alive/{node}"
        return base if worker is None else f"{base}/{worker}"

    @property
    def alive_all(self) -> str:
        return f"{self.prefix}/alive/**"

    def parse_alive(self, key: str) -> tuple[str, str | None]:
        """Return ``(node, worker or None)`` of a liveliness key."""
        head = f"{self.prefix}/alive/"
        if not key.startswith(head):
            raise ValueError(f"not an alive key of cluster {self.cluster!r}: {key!r}")
        parts = key[len(head) :].split("/")
        return parts[0], (parts[1] if len(parts) > 1 else None)

    def args(self, key: str = "**") -> str:
        return f"{self.prefix}/args/{key}"

    def seq(self, name: str = "*", node: str = "*") -> str:
        return f"{self.prefix}/seq/{name}/{node}"

    def ctl(self, node: str = "*", verb: str = "*") -> str:
        return f"{self.prefix}/ctl/{node}/{verb}"

    def launcher(self, launcher: str = "*", verb: str = "*") -> str:
        """``launcher/<id>/<verb>``: a launcher's queryable (``status``, ``down``)."""
        return f"{self.prefix}/launcher/{launcher}/{verb}"

    def sync(self, group: str, rest: str = "**") -> str:
        return f"{self.prefix}/sync/{group}/{rest}"

    def sim(self, rest: str = "**") -> str:
        return f"{self.prefix}/sim/{rest}"
