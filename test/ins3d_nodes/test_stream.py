"""The streaming 3-D filter (core/ins3d/stream.py) against the batch filter and input reader."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.core.gate import GateConfig
from flight_fdi.core.ins3d.filter import run_forward
from flight_fdi.core.ins3d.model import Ins3dModel
from flight_fdi.core.ins3d.stream import Boundary, Ins3dAssembler, Ins3dStream

from .streams import assert_rows_are, batch_input, flight, topic_messages


def _model(rows=2):
    return Ins3dModel.from_grade("navigation", rows=rows, latency=True,
                                 ref_markov=(0.02, 0.03, 30.0))


@pytest.fixture(scope="module")
def data():
    msgs = topic_messages(flight())
    return msgs, batch_input(msgs)


def _stream_events(msgs, wait_s=1.0):
    asm = Ins3dAssembler(wait_s=wait_s)
    events = []
    for ns, key, vals in msgs:
        got = asm.add(key, ns, *vals)
        assert not isinstance(got, str), got
        events += got
    return asm, events + asm.finish()


def test_assembler_equals_the_bag_reader(data):
    msgs, inp = data
    asm, events = _stream_events(msgs)
    bounds = [e for e in events if isinstance(e, Boundary)]
    st = inp.steps
    assert [b.k for b in bounds] == list(range(len(st) + 1))
    np.testing.assert_array_equal([b.t for b in bounds], st.t)
    for name in ("dt", "C", "f_n", "w_b", "v", "lat", "h"):
        got = np.concatenate([getattr(b.step, name) for b in bounds[1:]])
        np.testing.assert_array_equal(got, getattr(st, name), err_msg=name)
    refs = inp.refs
    assert_rows_are(events, refs)
    n_ref = sum(1 for m in msgs if m[1] == "ref_velocity")
    assert asm.late == 0 and asm.outside == n_ref - refs.t.size == 1   # the one before the IMU


@pytest.mark.parametrize("rows,action", [(2, "flag"), (3, "reject")])
def test_streaming_filter_equals_batch_bit_for_bit(data, rows, action):
    _, inp = data
    model = _model(rows)
    gate = GateConfig(action=action, probability=0.05)   # some gated samples
    st, refs = inp.steps, inp.refs
    P0 = model.p0_aligned(st.C[0], st.f_n[0], float(st.lat[0]))
    fwd = run_forward(model, st, refs, gate=gate, P0=P0)
    s = Ins3dStream(model, gate, P0=P0)
    j, xs, nus, b2s, alarms, fused = 0, [], [], [], [], []
    for k in range(len(st) + 1):
        if k:
            s.predict(st, k - 1)
        while j < refs.t.size and refs.step[j] == k:
            u = s.update(refs.z[j], refs.r[j], refs.a[j])
            nus.append(u.nu)
            b2s.append(u.beta2)
            alarms.append(u.alarm)
            fused.append(u.fused)
            j += 1
        xs.append(s.x)
        if k == len(st):
            np.testing.assert_array_equal(s.sd, fwd.sd[k])
    np.testing.assert_array_equal(np.array(xs), fwd.x)
    np.testing.assert_array_equal(np.array(nus), fwd.nu)
    np.testing.assert_array_equal(np.array(b2s), fwd.beta2)
    np.testing.assert_array_equal(np.array(alarms), fwd.alarm)
    assert fwd.exceeded.any()                             # the gate did something
    if action == "reject":
        assert not all(fused)


def test_assembler_refuses_bad_messages_and_waits_for_a_silent_reference(data):
    msgs, _ = data
    asm = Ins3dAssembler(wait_s=0.5)
    events = []
    for ns, key, vals in msgs:
        if key == "ref_velocity" and ns > msgs[0][0] + 100 * 10**9:
            continue                                      # reference lost after 100 s
        events += asm.add(key, ns, *vals)
    bounds = [e for e in events if isinstance(e, Boundary)]
    assert bounds[-1].t > 400.0                           # the filter kept stepping
    ns, key, vals = next(m for m in msgs if m[1] == "ins_imu")
    assert asm.add("ins_imu", ns, *vals) == "out_of_order"
    last_ref = [m for m in msgs if m[1] == "ref_velocity"][-1]
    bad = (last_ref[2][0] * np.nan, last_ref[2][1])
    assert asm.add("ref_velocity", last_ref[0] + 1, *bad) == "non_finite"
    assert asm.add("ref_velocity", last_ref[0] + 2, last_ref[2][0], -last_ref[2][1]) == \
        "invalid_covariance"
