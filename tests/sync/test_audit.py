"""The audit of the live tests (``check_firings`` on the harness logs) must see what it
exists to see: an overlap, a stale grant fired, a sound outliving its lease."""

from __future__ import annotations

from hera.sync.harness import Firing, check_firings, read_logs


def _f(start: float, end: float, token: int, deadline: float = 99.0, node: str = "s1") -> Firing:
    return Firing(start, end, deadline, f"{node}/m", token >> 32, token, node, start)


def test_check_firings_sees_an_overlap_a_stale_grant_and_a_late_sound():
    ok = [_f(0.0, 1.0, 1 << 32 | 1), _f(1.0, 2.0, 1 << 32 | 2), _f(2.5, 3.0, 2 << 32 | 1)]
    assert check_firings(ok).ok
    inner = _f(0.2, 0.4, 1 << 32 | 3)  # inside an earlier, longer sound
    c = check_firings([_f(0.0, 1.0, 1 << 32 | 1), _f(0.9, 1.5, 1 << 32 | 2), inner])
    assert len(c.overlaps) == 2 and not c.ok
    c = check_firings([_f(0.0, 1.0, 2 << 32 | 1), _f(1.5, 2.0, 1 << 32 | 9)])
    assert c.out_of_order and not c.overlaps
    c = check_firings([_f(0.0, 1.0, 1, deadline=0.99)])
    assert c.past_deadline and not c.overlaps


def test_a_sound_may_outlive_its_lease_by_the_tolerated_trigger_pause_only():
    """Condition C: checked at 0.93 with a 0.05 s slot (fits the lease ending at 0.99), the
    trigger 0.03 s later: the sound ends 0.02 s past the lease, within a 0.04 s pause."""
    late = Firing(0.96, 1.01, 0.99, "s1/m", 1, 1 << 32 | 1, "s1", 0.93)
    assert check_firings([late], pause=0.04).ok
    assert check_firings([late], pause=0.005).past_deadline == [late]  # beyond the pause
    assert check_firings([late]).past_deadline == [late]  # strict by default
    wrong = Firing(0.96, 1.01, 0.99, "s1/m", 1, 1 << 32 | 1, "s1", 0.95)  # 0.95 + 0.05 > 0.99
    assert check_firings([wrong], pause=0.04).past_deadline == [wrong]  # the check was wrong


def test_the_logged_trigger_time_is_what_the_audit_checks(tmp_path):
    """A firing whose trigger came 120 ms after its check (the check passed at 1.00) is
    audited at its trigger: it overlaps the next holder's sound and outlives its lease."""
    log = tmp_path / "s1.log"
    log.write_text(
        "F 1.120 1.180 1.070 s1/m 1 4294967297 1.000\nF 1.080 1.140 1.150 s2/m 1 4294967298 1.080\n"
    )
    logs = read_logs({"s1": log})
    assert [f.checked for f in logs.firings] == [1.08, 1.0]
    c = check_firings(logs.firings)
    assert len(c.overlaps) == 1 and [f.holder for f in c.past_deadline] == ["s1/m"]
