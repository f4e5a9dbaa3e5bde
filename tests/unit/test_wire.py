import math

import msgpack
import pytest

from hera.wire import MAX_PAYLOAD_BYTES, WireError, decode, encode


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
