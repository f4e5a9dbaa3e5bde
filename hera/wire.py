"""The wire format of Hera data samples (format version 1).

A sample published on ``hera/<cluster>/data/<name>/<node>`` is a msgpack **map** with
string keys, so that a client in any language can read it with Zenoh and msgpack alone:

=========  ==========================  ================================================
key        msgpack type                meaning
=========  ==========================  ================================================
``v``      positive int                format version, always 1 for this layout
``seq``    positive int (< 2**63)      sequence number of (name, node), starts at 1
``t``      float                       measurement time, producer's clock, epoch seconds
``val``    array of float/int          the values, in the measure's documented units
``grant``  array [int, int], optional  (epoch, token) of the sync grant it was taken under
``inc``    int in [0, 2**63), optional  producer's incarnation: a random id drawn at each
                                       start of its process (absent: 0)
=========  ==========================  ================================================

Unknown extra keys are ignored (forward compatible). Anything else is rejected with a
:class:`WireError` that says what was wrong. A store orders the samples of one source
(name, node) by seq within an incarnation and takes a new incarnation as a restart, so
neither a restart nor a forged huge seq can freeze a source (:mod:`hera.store`).
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import msgpack

FORMAT_VERSION = 1
MAX_PAYLOAD_BYTES = 16 * 1024
MAX_VALUES = 256
MAX_SEQ = 2**63 - 1
_MAX_SEQ = MAX_SEQ
_local = threading.local()


class WireError(ValueError):
    """A payload that is not a valid Hera sample; the message says what was wrong."""


@dataclass(frozen=True, slots=True)
class Message:
    """A decoded data sample, as it travelled on the bus."""

    seq: int
    t: float
    values: tuple[float, ...]
    grant: tuple[int, int] | None = None
    inc: int = 0


def encode(
    seq: int, t: float, values: list[float] | tuple[float, ...], grant=None, inc: int = 0
) -> bytes:
    """Encode one sample as a version-1 payload; raises WireError on values it cannot carry."""
    vals = [float(v) for v in values]
    if (  # the usual sample, checked in one pass: the bytes of the general path (tested)
        grant is None
        and type(seq) is int
        and 0 < seq <= _MAX_SEQ
        and type(t) is float
        and t - t == 0.0  # finite
        and type(inc) is int
        and 0 <= inc <= _MAX_SEQ
        and len(vals) <= MAX_VALUES
        and _all_finite(vals)
    ):
        msg = {"v": FORMAT_VERSION, "seq": seq, "t": t, "val": vals}
        if inc:
            msg["inc"] = inc
        return _packer().pack(msg)
    return _encode_checked(seq, t, vals, grant, inc)


def _encode_checked(seq, t, vals: list[float], grant, inc) -> bytes:
    """:func:`encode`'s general path: converts, checks every field (WireError naming it)."""
    msg = {"v": FORMAT_VERSION, "seq": int(seq), "t": float(t), "val": vals}
    if grant is not None:
        msg["grant"] = [int(grant[0]), int(grant[1])]
    if inc:
        msg["inc"] = int(inc)
    _check(msg["seq"], msg["t"], vals)
    _check_inc(msg.get("inc", 0))
    return _packer().pack(msg)


def _packer() -> msgpack.Packer:
    """This thread's msgpack packer (one per thread: a packer keeps a buffer; reusing it
    halves the cost of ``msgpack.packb``, which makes a new one per call)."""
    try:
        return _local.packer
    except AttributeError:
        p = _local.packer = msgpack.Packer(use_bin_type=True)
        return p


def _all_finite(vals: list) -> bool:
    """Whether every value is a finite float (inf - inf and nan - nan are nan)."""
    for v in vals:  # noqa: SIM110 - a loop: all() over a generator costs more for a few
        if type(v) is not float or v - v != 0.0:
            return False
    return True


def _check(seq, t, vals) -> None:
    if not isinstance(seq, int) or isinstance(seq, bool) or not 1 <= seq <= _MAX_SEQ:
        raise WireError(f"seq must be an integer in [1, 2**63), got {seq!r}")
    if not isinstance(t, (int, float)) or isinstance(t, bool) or not math.isfinite(t):
        raise WireError(f"t must be a finite number of epoch seconds, got {t!r}")
    if len(vals) > MAX_VALUES:
        raise WireError(f"too many values: {len(vals)} > {MAX_VALUES}")
    for i, v in enumerate(vals):
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise WireError(f"val[{i}] must be a number, got {type(v).__name__}")
        if not math.isfinite(v):
            raise WireError(f"val[{i}] is not finite: {v!r}")


def _check_inc(inc) -> None:
    if not isinstance(inc, int) or isinstance(inc, bool) or not 0 <= inc <= _MAX_SEQ:
        raise WireError(f"inc must be an integer in [0, 2**63), got {inc!r}")


def decode(payload: bytes) -> Message:
    """Decode and validate a version-1 payload; raises WireError naming what was wrong."""
    if len(payload) > MAX_PAYLOAD_BYTES:
        raise WireError(f"payload too large: {len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
    try:
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=True, max_array_len=MAX_VALUES)
    except Exception as e:  # untrusted bytes: msgpack raises several unrelated types
        raise WireError(f"not a msgpack payload ({type(e).__name__}: {e})") from None
    if type(msg) is dict:  # the usual sample, checked in one pass: the general path's result
        seq, t, vals, inc = msg.get("seq"), msg.get("t"), msg.get("val"), msg.get("inc", 0)
        if (
            type(seq) is int
            and 0 < seq <= _MAX_SEQ
            and type(t) is float
            and t - t == 0.0
            and type(vals) is list
            and type(inc) is int
            and 0 <= inc <= _MAX_SEQ
            and msg.get("grant") is None
            and msg.get("v") == FORMAT_VERSION
            and len(vals) <= MAX_VALUES
            and _all_finite(vals)
        ):
            return Message(seq, t, tuple(vals), None, inc)
    return _decode_checked(msg)


def _decode_checked(msg: object) -> Message:
    """:func:`decode`'s general path on an unpacked payload: every check, in order."""
    if not isinstance(msg, dict):
        raise WireError(f"payload must be a msgpack map, got {type(msg).__name__}")
    version = msg.get("v")
    if version != FORMAT_VERSION:
        raise WireError(f"unsupported format version {version!r} (expected {FORMAT_VERSION})")
    missing = [k for k in ("seq", "t", "val") if k not in msg]
    if missing:
        raise WireError(f"missing field(s): {', '.join(missing)}")
    vals = msg["val"]
    if not isinstance(vals, list):
        raise WireError(f"val must be an array, got {type(vals).__name__}")
    _check(msg["seq"], msg["t"], vals)
    grant = msg.get("grant")
    if grant is not None:
        if (
            not isinstance(grant, list)
            or len(grant) != 2
            or not all(isinstance(g, int) and not isinstance(g, bool) for g in grant)
        ):
            raise WireError(f"grant must be [epoch, token] integers, got {grant!r}")
        grant = (grant[0], grant[1])
    inc = msg.get("inc", 0)
    _check_inc(inc)
    return Message(msg["seq"], float(msg["t"]), tuple(float(v) for v in vals), grant, inc)
