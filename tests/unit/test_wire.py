import math

import msgpack
import numpy as np
import pytest

from hera import wire
from hera.wire import MAX_PAYLOAD_BYTES, MAX_VALUES, Message, WireError, decode, encode


def test_round_trip_keeps_every_field():
    m = decode(encode(12, 1763780000.25, [1, -2.5, 3e-9], grant=(4, 99)))
    assert (m.seq, m.t, m.values, m.grant) == (12, 1763780000.25, (1.0, -2.5, 3e-9), (4, 99))


def test_payload_is_a_plain_msgpack_map_any_client_can_read():
    raw = msgpack.unpackb(encode(1, 2.0, [3.0]))
    assert raw == {"v": 1, "seq": 1, "t": 2.0, "val": [3.0]}


def test_unknown_extra_keys_are_ignored():
    payload = msgpack.packb({"v": 1, "seq": 3, "t": 1.0, "val": [], "future": "x"})
    assert decode(payload).seq == 3


@pytest.mark.parametrize(
    ("payload", "message"),
    [
        (b"", "not a msgpack payload"),
        (encode(1, 1.0, [1.0, 2.0])[:-4], "not a msgpack payload"),
        (b"\x00" * (MAX_PAYLOAD_BYTES + 1), "payload too large"),
        (msgpack.packb([1, 2, 3]), "must be a msgpack map"),
        (msgpack.packb({"v": 2, "seq": 1, "t": 1.0, "val": []}), "unsupported format version 2"),
        (msgpack.packb({"v": 1, "t": 1.0}), "missing field(s): seq, val"),
        (msgpack.packb({"v": 1, "seq": 0, "t": 1.0, "val": []}), "seq must be"),
        (msgpack.packb({"v": 1, "seq": True, "t": 1.0, "val": []}), "seq must be"),
        (msgpack.packb({"v": 1, "seq": 1, "t": "now", "val": []}), "t must be"),
        (msgpack.packb({"v": 1, "seq": 1, "t": math.inf, "val": []}), "t must be"),
        (msgpack.packb({"v": 1, "seq": 1, "t": 1.0, "val": "abc"}), "val must be an array"),
        (msgpack.packb({"v": 1, "seq": 1, "t": 1.0, "val": [1, None]}), "val[1] must be a number"),
        (msgpack.packb({"v": 1, "seq": 1, "t": 1.0, "val": [math.nan]}), "val[0] is not finite"),
        (msgpack.packb({"v": 1, "seq": 1, "t": 1.0, "val": [], "grant": [1]}), "grant must be"),
    ],
)
def test_bad_payloads_raise_wire_error_naming_the_problem(payload, message):
    with pytest.raises(WireError, match=None) as e:
        decode(payload)
    assert message in str(e.value)


def test_encode_refuses_values_it_cannot_carry():
    with pytest.raises(WireError, match="not finite"):
        encode(1, 1.0, [float("nan")])
    with pytest.raises(WireError, match="seq"):
        encode(0, 1.0, [])


# The fast paths of encode and decode (the usual sample, checked in one pass) must give
# what the general paths give, to the byte and to the error message, on anything.
_ODD = [0, -1, 1, 7, 2**63 - 1, 2**63, True, False, 1.0, 2.5, -0.0, math.inf, -math.inf]
_ODD += [math.nan, 1e308, "x", None, [1], np.int64(3), np.float64(2.0), np.float32(0.5)]


def _outcome(fn, *args):
    try:
        out = fn(*args)
    except (WireError, TypeError, ValueError, OverflowError) as e:
        return ("error", type(e).__name__, str(e))
    if isinstance(out, Message):  # equal values of another type (1 and 1.0) must differ too
        return (out, [type(v) for v in out.values], type(out.t), type(out.seq), type(out.inc))
    return out


def _pick(rng, usual, p=0.6):
    return usual() if rng.random() < p else _ODD[rng.integers(len(_ODD))]


def test_encode_fast_path_gives_the_general_paths_bytes_and_errors():
    rng = np.random.default_rng(11)
    fast = 0
    for _ in range(20000):
        seq = _pick(rng, lambda: int(rng.integers(1, 2**62)))
        t = _pick(rng, lambda: float(rng.normal(1.7e9, 1e6)))
        vals = [_pick(rng, lambda: float(rng.normal()), 0.9) for _ in range(rng.integers(0, 5))]
        if rng.random() < 0.02:
            vals = [1.0] * (MAX_VALUES + int(rng.integers(0, 2)))
        grant = None if rng.random() < 0.8 else (int(rng.integers(0, 9)), int(rng.integers(9)))
        inc = 0 if rng.random() < 0.3 else _pick(rng, lambda: int(rng.integers(1, 2**62)))
        got = _outcome(encode, seq, t, vals, grant, inc)
        try:
            converted = [float(v) for v in vals]
        except (TypeError, ValueError) as e:
            assert got == ("error", type(e).__name__, str(e))
            continue
        assert got == _outcome(wire._encode_checked, seq, t, converted, grant, inc)
        fast += isinstance(got, bytes)
    assert fast > 5000  # the usual samples were there, not only errors


def test_decode_fast_path_gives_the_general_paths_message_and_errors():
    rng = np.random.default_rng(12)
    fast = 0
    for _ in range(20000):
        msg = {
            "v": _pick(rng, lambda: 1, 0.9),
            "seq": _pick(rng, lambda: int(rng.integers(1, 2**62))),
            "t": _pick(rng, lambda: float(rng.normal(1.7e9, 1e6))),
            "val": [_pick(rng, lambda: float(rng.normal()), 0.9) for _ in range(rng.integers(4))],
            "inc": _pick(rng, lambda: int(rng.integers(0, 2**62)), 0.8),
            "grant": None if rng.random() < 0.7 else [_pick(rng, lambda: 3, 0.9), 4],
            "extra": "x",
        }
        for key in list(msg):  # leave keys out, or give the value of another type
            if rng.random() < 0.05:
                del msg[key]
            elif rng.random() < 0.03:
                msg[key] = _ODD[rng.integers(len(_ODD))]
        msg = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in msg.items()}
        try:
            payload = msgpack.packb(msg)
        except (TypeError, ValueError, OverflowError):
            continue  # not a payload msgpack can write
        general = _outcome(
            wire._decode_checked, msgpack.unpackb(payload, raw=False, strict_map_key=True)
        )
        got = _outcome(decode, payload)
        assert got == general, msg
        fast += isinstance(got, tuple) and isinstance(got[0], Message)
    assert fast > 5000
