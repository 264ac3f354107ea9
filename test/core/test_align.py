"""Time alignment of the INS to the reference stamps (flight_fdi.core.align)."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.core import CoreError
from flight_fdi.core.align import StreamingAligner, align_to_reference


def test_linear_signal_is_interpolated_exactly():
    rng = np.random.default_rng(1)
    t_ins = np.cumsum(0.02 + 0.005 * rng.random(500))  # irregular 50 Hz-ish
    v_ins = 3.0 - 0.7 * t_ins
    t_ref = np.sort(rng.uniform(t_ins[0], t_ins[-1], 80))
    valid, v = align_to_reference(t_ins, v_ins, t_ref)
    assert valid.all()
    np.testing.assert_allclose(v, 3.0 - 0.7 * t_ref, rtol=0, atol=1e-12)


def test_vector_values_and_exact_stamps():
    t_ins = np.array([0.0, 0.1, 0.2, 0.3])
    v_ins = np.column_stack([t_ins * 2.0, -t_ins + 1.0, np.full(4, 5.0)])
    valid, v = align_to_reference(t_ins, v_ins, np.array([0.0, 0.15, 0.3]))
    assert valid.all() and v.shape == (3, 3)
    np.testing.assert_allclose(v, [[0.0, 1.0, 5.0], [0.3, 0.85, 5.0], [0.6, 0.7, 5.0]],
                               atol=1e-15)


def test_gaps_and_out_of_span_are_invalid():
    t_ins = np.array([0.0, 0.1, 0.2, 1.0, 1.1])  # a 0.8 s dropout between 0.2 and 1.0
    v_ins = np.arange(5.0)
    t_ref = np.array([-0.05, 0.0, 0.05, 0.25, 0.6, 1.0, 1.05, 1.1, 1.2])
    valid, v = align_to_reference(t_ins, v_ins, t_ref, max_gap_s=0.5)
    np.testing.assert_array_equal(valid, [False, True, True, False, False, True, True, True,
                                          False])
    assert np.all(np.isnan(v[~valid]))
    np.testing.assert_allclose(v[valid], [0.0, 0.5, 3.0, 3.5, 4.0])
    # the same dropout is bridged when the allowed gap is wider
    valid, v = align_to_reference(t_ins, v_ins, np.array([0.6]), max_gap_s=0.8)
    assert valid[0] and v[0] == pytest.approx(2.5)
    # a bracket exactly max_gap_s wide is still accepted
    valid, v = align_to_reference([0.0, 0.5], [0.0, 1.0], [0.25, 0.5], max_gap_s=0.5)
    assert valid.all() and v.tolist() == [0.5, 1.0]
    # no INS at all: nothing is valid
    valid, v = align_to_reference(np.zeros(0), np.zeros(0), np.array([1.0]))
    assert not valid[0] and np.isnan(v[0])


@pytest.mark.parametrize("t_ins, v_ins, t_ref, match", [
    ([0.0, 0.1, 0.1], [1, 2, 3], [0.05], "strictly increasing"),
    ([0.0, 0.2, 0.1], [1, 2, 3], [0.05], "strictly increasing"),
    ([0.0, np.nan, 0.2], [1, 2, 3], [0.05], "t_ins contains NaN"),
    ([0.0, 0.1, 0.2], [1, np.inf, 3], [0.05], "v_ins contains NaN"),
    ([0.0, 0.1, 0.2], [1, 2, 3], [np.nan], "t_ref contains NaN"),
    ([0.0, 0.1, 0.2], [1, 2], [0.05], "v_ins must have shape"),
    ([[0.0, 0.1]], [1, 2], [0.05], "t_ins must be 1-D"),
])
def test_bad_input_raises(t_ins, v_ins, t_ref, match):
    with pytest.raises(CoreError, match=match):
        align_to_reference(np.array(t_ins), np.array(v_ins, dtype=float), np.array(t_ref))


@pytest.mark.parametrize("gap", [0.0, -1.0, float("inf"), float("nan"), True, "0.5"])
def test_bad_max_gap_raises(gap):
    with pytest.raises(CoreError, match="max_gap_s"):
        align_to_reference([0.0, 1.0], [0.0, 1.0], [0.5], max_gap_s=gap)
    with pytest.raises(CoreError, match="max_gap_s"):
        StreamingAligner(max_gap_s=gap)


@pytest.mark.parametrize("vector", [True, False])
def test_streaming_equals_batch(vector):
    rng = np.random.default_rng(7)
    t_ins = np.cumsum(0.02 + 0.002 * rng.standard_normal(3000).clip(-5, 5))
    t_ins = np.delete(t_ins, np.r_[400:450, 1500:1530])  # two dropouts (1.0 s and 0.6 s)
    v_ins = np.column_stack([np.sin(t_ins), np.cos(0.3 * t_ins)]) if vector else np.sin(t_ins)
    t_ref = np.arange(t_ins[0] - 0.2, t_ins[-1] + 0.3, 0.1)
    valid, v_batch = align_to_reference(t_ins, v_ins, t_ref, max_gap_s=0.5)
    assert (~valid).sum() >= 10  # the dropouts and the ends

    aligner = StreamingAligner(max_gap_s=0.5, buffer_s=2.0)
    pending = list(t_ref)
    got = {}
    reasons = {}
    for ti, vi in zip(t_ins, v_ins):
        aligner.add_ins(ti, vi if vector else float(vi))
        # a node answers a reference stamp as soon as it can (value, or a final "gap")
        while pending:
            value = aligner.at(pending[0])
            if value is None and aligner.last_reason == "waiting":
                break
            got[pending[0]] = value
            reasons[pending[0]] = aligner.last_reason
            pending.pop(0)
    for tr in pending:  # the flight ended: the last stamps never get a later INS sample
        got[tr] = aligner.at(tr)
        reasons[tr] = aligner.last_reason
        assert got[tr] is None and reasons[tr] in ("waiting", "gap")
    for tr, ok, vb in zip(t_ref, valid, v_batch):
        if ok:
            assert reasons[tr] == "ok"
            np.testing.assert_array_equal(got[tr], vb)  # bit for bit
            assert isinstance(got[tr], np.ndarray if vector else float)
        else:
            assert got[tr] is None
            assert reasons[tr] in ("gap", "too_old", "waiting")
    assert reasons[t_ref[0]] == "too_old"  # before the first INS sample
    assert sum(r == "gap" for r in reasons.values()) >= 8  # inside the dropouts


def test_streaming_reasons():
    al = StreamingAligner(max_gap_s=0.5, buffer_s=2.0)
    assert al.at(1.0) is None and al.last_reason == "empty"
    al.add_ins(1.0, 10.0)
    assert al.at(1.0) == 10.0 and al.last_reason == "ok"
    assert al.at(1.2) is None and al.last_reason == "waiting"  # next sample may still come
    assert al.at(1.6) is None and al.last_reason == "gap"  # no later sample can bracket it
    assert al.at(0.9) is None and al.last_reason == "too_old"
    al.add_ins(1.4, 14.0)
    assert al.at(1.2) == pytest.approx(12.0) and al.last_reason == "ok"
    al.add_ins(2.4, 24.0)  # 1.0 s dropout
    assert al.at(1.9) is None and al.last_reason == "gap"
    assert al.at(2.4) == 24.0


def test_streaming_buffer_is_bounded():
    al = StreamingAligner(max_gap_s=0.5, buffer_s=2.0)
    rate = 50.0
    for k in range(20_000):
        al.add_ins(k / rate, float(k))
        assert len(al) <= 2.0 * rate + 2
    newest = al.newest_t
    assert al.oldest_t <= newest - 2.0 < al.oldest_t + 1.0 / rate + 1e-9
    # stamps inside the horizon are still answered, older ones are not
    assert al.at(newest - 1.99) == pytest.approx((newest - 1.99) * rate)
    assert al.at(newest - 2.5) is None and al.last_reason == "too_old"
    # a hard cap on the count holds whatever the rate
    capped = StreamingAligner(buffer_s=2.0, max_samples=10)
    for k in range(1000):
        capped.add_ins(k * 1e-3, float(k))
        assert len(capped) <= 10


def test_streaming_rejects_bad_samples_and_keeps_state():
    al = StreamingAligner()
    al.add_ins(1.0, [1.0, 2.0])
    al.add_ins(1.1, [2.0, 3.0])
    for t, v, match in [(1.1, [0.0, 0.0], "strictly increasing"),
                        (1.05, [0.0, 0.0], "strictly increasing"),
                        (float("nan"), [0.0, 0.0], "finite"),
                        (1.2, [np.nan, 0.0], "finite"),
                        (1.2, [1.0, 2.0, 3.0], "shape"),
                        (1.2, [[1.0, 2.0]], "finite number or vector")]:
        with pytest.raises(CoreError, match=match):
            al.add_ins(t, v)
    assert len(al) == 2 and al.newest_t == 1.1
    np.testing.assert_allclose(al.at(1.05), [1.5, 2.5])
    with pytest.raises(CoreError, match="finite"):
        al.at(float("inf"))
    with pytest.raises(CoreError, match="buffer_s"):
        StreamingAligner(buffer_s=0.0)
    with pytest.raises(CoreError, match="max_samples"):
        StreamingAligner(max_samples=1)
