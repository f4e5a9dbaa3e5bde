"""The Zenoh configuration a hera process opens its session with (hera.bus.BusConfig)."""

from __future__ import annotations

import json

from hera.bus import BusConfig


def test_shared_memory_is_off_unless_the_overrides_turn_it_on():
    cfg = BusConfig(connect=("tcp/127.0.0.1:7447",)).to_zenoh()
    assert json.loads(cfg.get_json("transport/shared_memory/enabled")) is False
    on = BusConfig(extra={"transport/shared_memory/enabled": True}).to_zenoh()
    assert json.loads(on.get_json("transport/shared_memory/enabled")) is True
