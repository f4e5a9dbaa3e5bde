"""Messages of the sync service and their msgpack encoding (see ``sync/README.md``).

Every message is a msgpack map with short string keys, so a client in any language can
speak the protocol with Zenoh and msgpack alone. Keys, under ``hera/<cluster>/sync/<group>/``:

- ``vote`` (queryable on every host of the group): a :class:`VoteRequest` as the query
  payload; each host answers one :class:`VoteReply`;
- ``acquire`` (queryable on every host): an :class:`AcquireRequest`; only the granting
  leader answers, with a :class:`GrantReply`, when the slot is the asker's (long poll);
  the others drop the query without a reply;
- ``release`` (subscriber on every host): a :class:`Release`, sent after the sound ended;
- ``host/<node>``: liveliness token of each host of the group.

Decoding never trusts its input: anything malformed raises :class:`ProtocolError`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import msgpack

MAX_MESSAGE_BYTES = 4096


class ProtocolError(ValueError):
    """A sync message that cannot be decoded; the text says what was wrong."""


def _pack(msg: dict[str, Any]) -> bytes:
    return msgpack.packb(msg, use_bin_type=True)


def _unpack(payload: bytes, kind: str, fields: dict[str, type | tuple[type, ...]]) -> dict:
    if len(payload) > MAX_MESSAGE_BYTES:
        raise ProtocolError(f"{kind}: message too large ({len(payload)} bytes)")
    try:
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as e:  # untrusted bytes: msgpack raises several unrelated types
        raise ProtocolError(f"{kind}: not msgpack ({type(e).__name__}: {e})") from None
    if not isinstance(msg, dict):
        raise ProtocolError(f"{kind}: expected a map, got {type(msg).__name__}")
    for name, typ in fields.items():
        if name not in msg:
            raise ProtocolError(f"{kind}: missing field {name!r}")
        value = msg[name]
        if isinstance(value, bool) and bool not in (typ if isinstance(typ, tuple) else (typ,)):
            raise ProtocolError(f"{kind}: field {name!r} has the wrong type")
        if not isinstance(value, typ):
            raise ProtocolError(f"{kind}: field {name!r} has the wrong type")
        if isinstance(value, float) and not math.isfinite(value):
            raise ProtocolError(f"{kind}: field {name!r} is not finite")
    return msg


def _nonneg(kind: str, name: str, value: float) -> None:
    if value < 0:
        raise ProtocolError(f"{kind}: field {name!r} must be >= 0, got {value!r}")


@dataclass(frozen=True, slots=True)
class VoteRequest:
    """A candidate (or the leader renewing) asks a host to confirm ``(epoch, candidate)``.

    ``probe``: a pre-vote, answered with what the host would say, promising nothing.
    """

    epoch: int
    candidate: str
    probe: bool = False

    def encode(self) -> bytes:
        return _pack({"e": self.epoch, "c": self.candidate, "p": self.probe})

    @staticmethod
    def decode(payload: bytes) -> VoteRequest:
        m = _unpack(payload, "vote request", {"e": int, "c": str, "p": bool})
        _nonneg("vote request", "e", m["e"])
        return VoteRequest(m["e"], m["c"], m["p"])


@dataclass(frozen=True, slots=True)
class VoteReply:
    """A host's answer: ``ok`` or not, and the (epoch, candidate) it has promised now."""

    voter: str
    ok: bool
    epoch: int
    candidate: str

    def encode(self) -> bytes:
        return _pack({"v": self.voter, "ok": self.ok, "e": self.epoch, "c": self.candidate})

    @staticmethod
    def decode(payload: bytes) -> VoteReply:
        m = _unpack(payload, "vote reply", {"v": str, "ok": bool, "e": int, "c": str})
        _nonneg("vote reply", "e", m["e"])
        return VoteReply(m["v"], m["ok"], m["e"], m["c"])


@dataclass(frozen=True, slots=True)
class AcquireRequest:
    """A measure asks for a slot of ``duration`` s; it gives up after ``timeout`` s.

    ``known_epoch``/``known_leader``: the newest term the asker was granted under (0, ""
    if none; the leader as its term id ``<node>#<incarnation>``). A leader of a lower epoch,
    or of the same epoch under another term id (another host, or this host before a restart
    that lost its promises), steps down and is re-elected above it. Optional on the wire
    (``k``, ``kl``).
    """

    holder: str
    duration: float
    timeout: float
    known_epoch: int = 0
    known_leader: str = ""

    def encode(self) -> bytes:
        return _pack(
            {
                "h": self.holder,
                "d": float(self.duration),
                "t": float(self.timeout),
                "k": self.known_epoch,
                "kl": self.known_leader,
            }
        )

    @staticmethod
    def decode(payload: bytes) -> AcquireRequest:
        m = _unpack(payload, "acquire", {"h": str, "d": (int, float), "t": (int, float)})
        if not m["d"] > 0:
            raise ProtocolError(f"acquire: duration must be > 0, got {m['d']!r}")
        _nonneg("acquire", "t", m["t"])
        k, kl = m.get("k", 0), m.get("kl", "")
        if isinstance(k, bool) or not isinstance(k, int) or k < 0:
            raise ProtocolError(f"acquire: field 'k' must be an int >= 0, got {k!r}")
        if not isinstance(kl, str):
            raise ProtocolError("acquire: field 'kl' has the wrong type")
        return AcquireRequest(m["h"], float(m["d"]), float(m["t"]), k, kl)


@dataclass(frozen=True, slots=True)
class GrantReply:
    """The slot is the asker's: ``duration`` s counted from when the asker sent its request.

    ``duration`` = the leader-measured time the request waited + the slot asked for, so a
    lease counted by the asker from before it asked ends no later than the leader's.
    ``leader``: the term id of the granting leader, ``<node>#<incarnation>``.
    """

    epoch: int
    token: int
    duration: float
    leader: str

    def encode(self) -> bytes:
        return _pack({"e": self.epoch, "k": self.token, "d": self.duration, "l": self.leader})

    @staticmethod
    def decode(payload: bytes) -> GrantReply:
        m = _unpack(payload, "grant", {"e": int, "k": int, "d": (int, float), "l": str})
        _nonneg("grant", "e", m["e"])
        _nonneg("grant", "k", m["k"])
        _nonneg("grant", "d", m["d"])
        return GrantReply(m["e"], m["k"], float(m["d"]), m["l"])


@dataclass(frozen=True, slots=True)
class Release:
    """The holder gives slot ``(epoch, token)`` back; ``used`` says whether it fired."""

    epoch: int
    token: int
    holder: str
    used: bool

    def encode(self) -> bytes:
        return _pack({"e": self.epoch, "k": self.token, "h": self.holder, "u": self.used})

    @staticmethod
    def decode(payload: bytes) -> Release:
        m = _unpack(payload, "release", {"e": int, "k": int, "h": str, "u": bool})
        return Release(m["e"], m["k"], m["h"], m["u"])
