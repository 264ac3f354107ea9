"""core.refsync: grouping reference samples into filter updates, without rclpy.

The expected updates are worked out by hand from the rules in the module docstring (tolerance,
wait, late samples, INS timeout, time jumps); the INS velocity is linear in time, so its
interpolated value at any stamp is known exactly.
"""
from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.refsync import ReferenceSync


def v_ins(t):
    """INS velocity (3,) linear in t: interpolation reproduces it to rounding."""
    return np.array([0.5 + 0.01 * t, -0.2 * t, 3.0])


class Rig:
    def __init__(self, n_refs, **kw):
        self.drops = []
        self.sync = ReferenceSync(n_refs, on_drop=lambda r, d, n: self.drops.append((r, n)),
                                  **kw)
        self.updates = []

    def ins(self, t):
        self.updates += self.sync.add_ins(t, v_ins(t))

    def ref(self, k, t, value=None):
        v = np.full(3, float(k) if value is None else value)
        out = self.sync.add_reference(k, t, v, np.full(3, 0.01))
        if out is None:
            return False
        self.updates += out
        return True


def test_imports_no_rclpy():
    code = ("import sys, flight_fdi.core.refsync; "
            "assert 'rclpy' not in sys.modules, 'rclpy imported'")
    subprocess.run([sys.executable, "-c", code], check=True)


def test_single_reference_waits_for_the_ins_sample_after_its_stamp():
    rig = Rig(1, max_gap_s=0.05, buffer_s=2.0)
    for i in range(6):
        rig.ins(10.0 + 0.02 * i)           # INS at 50 Hz up to 10.10
    rig.ref(0, 10.034)
    assert [u.t for u in rig.updates] == [10.034]
    rig.ref(0, 10.134)                      # after the newest INS sample: waits
    assert len(rig.updates) == 1 and rig.sync.waiting == 1
    rig.ins(10.12)
    assert len(rig.updates) == 1            # still before 10.134
    rig.ins(10.14)
    assert [u.t for u in rig.updates] == [10.034, 10.134]
    for u in rig.updates:
        (k, v, v_ref, var), = u.rows
        assert k == 0 and u.missing == []
        np.testing.assert_allclose(v, v_ins(u.t), rtol=0, atol=1e-12)
    assert rig.drops == []


def test_single_reference_never_groups_close_stamps():
    rig = Rig(1, tolerance_s=0.05)          # tolerance only applies to several references
    rig.ref(0, 1.00)
    rig.ref(0, 1.01)
    rig.ins(0.9)
    rig.ins(1.1)
    assert [u.t for u in rig.updates] == [1.00, 1.01]


def test_redundant_rows_within_tolerance_form_one_update():
    rig = Rig(3, tolerance_s=0.01, wait_s=0.35, max_gap_s=2.0)
    rig.ins(0.0)
    rig.ref(1, 1.003)
    rig.ref(0, 1.000)                       # joins the update at 1.003 (within 0.01)
    assert rig.sync.waiting == 2 and len(rig.sync.pending) == 1
    rig.ref(2, 1.020)                       # outside the tolerance: a new update
    assert len(rig.sync.pending) == 2
    rig.ins(1.05)
    # the first update still waits for reference 2 (last sample 1.020 is within wait, but past
    # the stamp by more than the tolerance -> it will not come): it is closed
    assert [u.t for u in rig.updates] == [1.003]
    u = rig.updates[0]
    assert [r[0] for r in u.rows] == [0, 1] and u.missing == [2]
    np.testing.assert_allclose(u.rows[0][1], v_ins(1.000), atol=1e-12)  # each row at its stamp
    np.testing.assert_allclose(u.rows[1][1], v_ins(1.003), atol=1e-12)
    rig.ref(0, 1.021)
    rig.ref(1, 1.019)                       # nearest open update without reference 1
    assert [u.t for u in rig.updates] == [1.003, 1.020]
    assert [r[0] for r in rig.updates[1].rows] == [0, 1, 2] and rig.updates[1].missing == []


def test_missing_reference_waits_until_another_is_wait_s_ahead():
    rig = Rig(2, tolerance_s=0.01, wait_s=0.35, max_gap_s=5.0)
    rig.ref(1, 0.0)
    rig.ins(0.0)
    rig.ins(2.0)
    assert rig.updates == []                # reference 0 never sent yet: waited for
    rig.ref(0, 0.5)
    # 0.5 > 0.0 + wait: the update at 0.0 closes without reference 0; reference 1 (last 0.0)
    # is more than wait behind 0.5: the update at 0.5 does not wait for it
    assert [(u.t, u.missing) for u in rig.updates] == [(0.0, [0]), (0.5, [1])]
    rig.ref(1, 0.6)                         # reference 0 (last 0.5) may still send 0.6
    assert len(rig.updates) == 2
    rig.ref(0, 0.605)
    rig.ref(0, 0.7)                         # waits for reference 1 (last 0.6)
    rig.ref(0, 0.8)
    assert [(u.t, u.missing) for u in rig.updates[2:]] == [(0.6, [])]
    rig.ref(0, 1.1)                         # 1.1 > 0.7 + wait: closes 0.7 without reference 1
    assert [(u.t, u.missing) for u in rig.updates[2:]] == [(0.6, []), (0.7, [1])]
    assert rig.drops == []


def test_late_sample_is_refused_and_not_redone():
    rig = Rig(2, tolerance_s=0.01, wait_s=0.2, max_gap_s=2.0)
    rig.ins(0.0)
    rig.ins(1.0)
    rig.ref(0, 0.5)
    rig.ref(1, 0.5)
    assert [u.t for u in rig.updates] == [0.5]
    assert rig.ref(1, 0.45) is False        # its stamp is before the released update
    assert rig.ref(1, 0.5) is False         # equal: also late
    assert rig.sync.last_epoch_t == 0.5 and len(rig.updates) == 1


def test_ins_timeout_and_gap_are_dropped_and_counted():
    rig = Rig(1, max_gap_s=0.1, buffer_s=1.0)
    rig.ins(0.0)
    rig.ref(0, 0.5)                         # waits for INS after 0.5
    rig.ref(0, 1.6)                         # 1.6 - 1.0 > 0.5: the first one expires
    assert rig.drops == [("ins_timeout", 1)]
    rig.ins(1.7)                            # INS 0.0 -> 1.7 brackets 1.6 with a 1.7-s gap
    assert rig.updates == [] and rig.drops[-1] == ("ins_gap", 1)


def test_ins_error_leaves_the_state_unchanged():
    rig = Rig(1)
    rig.ins(1.0)
    with pytest.raises(CoreError):
        rig.sync.add_ins(0.5, v_ins(0.5))   # older than the buffer's newest sample
    assert rig.sync.last_ins_t == 1.0


def test_time_jumps_clear_what_waits_on_the_old_line():
    rig = Rig(2, tolerance_s=0.01, wait_s=0.3, max_gap_s=2.0)
    rig.ins(100.0)
    rig.ref(0, 100.2)
    rig.ref(1, 100.4)
    assert rig.sync.waiting == 2
    rig.sync.ins_time_jump(5.0, reset_s=1.0)   # INS restarts at 5 s: both updates are stale
    assert rig.drops == [("time_jump", 2)] and rig.sync.waiting == 0
    assert rig.sync.aligner.newest_t is None
    rig.ins(5.0)
    rig.ref(0, 200.0)
    rig.sync.reference_time_jump(6.0, reset_s=1.0)
    assert rig.drops[-1] == ("time_jump", 1)
    assert rig.sync.ref_last_t == [None, None] and rig.sync.last_epoch_t is None
    assert rig.sync.aligner.newest_t == 5.0   # the INS is on the new line already: kept
    rig.ref(0, 6.0)
    rig.ref(1, 6.0)
    rig.ins(6.1)
    assert [u.t for u in rig.updates] == [6.0]
