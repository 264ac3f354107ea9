"""StampLine: one wild stamp is an outlier, a persistent jump is a new time line."""
from __future__ import annotations

import math

import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.timeline import (ACCEPT, DUPLICATE, HELD, NEW_LINE, OUT_OF_ORDER, OUTLIER,
                                      StampLine)


def _run(line: StampLine, stamps):
    """Feed stamps (payload = index); returns (kinds, accepted indices in use order,
    outlier indices, jumps)."""
    kinds, used, outliers, jumps = [], [], [], []
    for i, t in enumerate(stamps):
        v = line.check(t, i)
        kinds.append(v.kind)
        outliers += v.dismissed
        if v.kind == ACCEPT:
            used.append(i)
        elif v.kind == NEW_LINE:
            used += v.released
            jumps.append(v.jump)
        elif v.kind == OUTLIER:
            outliers.append(i)
    return kinds, used, outliers, jumps


def _stream(t0, n, dt=0.1):
    return [t0 + k * dt for k in range(n)]


def test_single_zero_stamp_is_an_outlier():
    stamps = _stream(1000.0, 5) + [0.0] + _stream(1000.5, 5)
    kinds, used, outliers, jumps = _run(StampLine(1.0, confirm=3), stamps)
    assert kinds[5] == HELD and kinds[6] == ACCEPT
    assert outliers == [5] and jumps == []
    assert used == [i for i in range(11) if i != 5]


def test_single_far_future_stamp_is_an_outlier():
    stamps = _stream(1000.0, 5) + [1e9] + _stream(1000.5, 5)
    kinds, used, outliers, jumps = _run(StampLine(1.0, confirm=3, forward_jump_s=60.0), stamps)
    assert outliers == [5] and jumps == [] and len(used) == 10


def test_a_burst_shorter_than_confirm_is_outliers_and_repeated_zeros_too():
    # two wild samples on a consistent new line, then three zeros, then the old line again
    stamps = _stream(1000.0, 3) + [5.0, 5.1] + _stream(1000.3, 2) + [0.0, 0.0, 0.0] + \
        _stream(1000.5, 2)
    kinds, used, outliers, jumps = _run(StampLine(1.0, confirm=3), stamps)
    assert jumps == []
    assert sorted(outliers) == [3, 4, 7, 8, 9]
    assert kinds[8] == OUTLIER and kinds[9] == OUTLIER
    assert used == [0, 1, 2, 5, 6, 10, 11]


def test_random_wild_stamps_in_a_burst_never_confirm():
    stamps = _stream(1000.0, 3) + [0.0, 500.0, -3.0, 77.0] + _stream(1000.3, 2)
    _, used, outliers, jumps = _run(StampLine(1.0, confirm=2), stamps)
    assert jumps == [] and sorted(outliers) == [3, 4, 5, 6] and used == [0, 1, 2, 7, 8]


def test_a_real_clock_reset_is_adopted_after_confirm_samples_and_loses_nothing():
    stamps = _stream(1000.0, 5) + _stream(0.0, 6)
    kinds, used, outliers, jumps = _run(StampLine(1.0, confirm=3), stamps)
    assert kinds[5:8] == [HELD, HELD, NEW_LINE] and kinds[8:] == [ACCEPT] * 3
    assert jumps == [(1000.4, 0.0)] and outliers == []
    assert used == list(range(11))


def test_confirm_one_adopts_the_first_jump():
    kinds, used, outliers, jumps = _run(StampLine(1.0, confirm=1), [10.0, 10.1, 0.0, 10.2])
    assert kinds == [ACCEPT, ACCEPT, NEW_LINE, ACCEPT]  # a forward gap (no forward limit)
    assert jumps == [(10.1, 0.0)]


def test_duplicates_and_small_steps_back_are_not_jumps():
    kinds, *_ = _run(StampLine(1.0), [5.0, 5.0, 4.5, 5.1, 4.0])
    assert kinds == [ACCEPT, DUPLICATE, OUT_OF_ORDER, ACCEPT, HELD]


def test_forward_gap_within_limit_is_accepted():
    kinds, *_ = _run(StampLine(1.0, forward_jump_s=60.0), [5.0, 64.0, 200.0])
    assert kinds == [ACCEPT, ACCEPT, HELD]


def test_reset_returns_the_held_payloads():
    line = StampLine(1.0, confirm=3)
    line.check(100.0, "a")
    line.check(1.0, "b")
    assert line.pending == 1
    assert line.reset() == ["b"] and line.last is None and line.pending == 0


@pytest.mark.parametrize("kwargs", [dict(jump_s=0.0), dict(jump_s=math.nan),
                                    dict(jump_s=1.0, confirm=0), dict(jump_s=1.0, confirm=True),
                                    dict(jump_s=1.0, forward_jump_s=0.0)])
def test_bad_configuration(kwargs):
    with pytest.raises(CoreError):
        StampLine(**kwargs)
