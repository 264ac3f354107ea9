"""filter_node in-process (launch-free): a seeded synthetic flight is published from a driver node
on sim time, and the node's innovations, states, model info, diagnostics and logs are checked.

Expected values are derived independently of the node: V_INS(t_ref) by ``np.interp`` over the
published INS samples, the chi-square(1) gate from the normal quantile, and the filter outputs
by running the core's batch ``run_forward`` over the z and R the test computed itself.
"""
from __future__ import annotations

import math
import os
import subprocess
import sys

import numpy as np
import pytest
from rclpy.serialization import serialize_message
from scipy.stats import norm

from flight_fdi.nodes import convert
from flight_fdi.nodes import diagnostics as diag
from flight_fdi.nodes.errors import ParameterError

T0 = 1000.0          # first stamp of a flight [s]
INS_HZ = 50
REF_HZ = 10
REF_OFFSET = 0.004   # reference stamps fall between INS samples: the node must interpolate
SIGMA_REF = 0.1      # reference noise std [m/s]; the messages carry SIGMA_REF**2
CHUNK_S = 0.5        # published between two spins (60 messages < input_queue_depth)


# ------------------------------------------------------------------------------ synthetic data

def truth(t: np.ndarray) -> np.ndarray:
    """True velocity: accelerating along x, constant along y (linear in t, so interpolation
    between INS samples is exact)."""
    t = np.asarray(t, dtype=float)
    return np.stack([50.0 + 0.5 * (t - T0), -20.0 + 0.0 * t, 1.0 + 0.0 * t], axis=-1)


def flight(seconds: float, seed: int, t0: float = T0, ramp_onset: float | None = None,
           ramp_slope: float = 0.0):
    """INS samples (exact truth, plus an x velocity ramp from ``ramp_onset``) and noisy
    reference samples. Returns (t_ins, v_ins, t_ref, v_ref, var_ref) with stamps rounded to ns."""
    rng = np.random.default_rng(seed)
    t_ins = _ns(t0 + np.arange(int(round(seconds * INS_HZ))) / INS_HZ)
    t_ref = _ns(t0 + REF_OFFSET + np.arange(int(round(seconds * REF_HZ))) / REF_HZ)
    t_ref = t_ref[t_ref < t_ins[-1]]  # every reference sample has an INS sample after it
    v_ins = truth(t_ins)
    if ramp_onset is not None:
        v_ins[:, 0] += ramp_slope * np.clip(t_ins - ramp_onset, 0.0, None)
    v_ref = truth(t_ref) + rng.normal(0.0, SIGMA_REF, (t_ref.size, 3))
    var_ref = np.full((t_ref.size, 3), SIGMA_REF**2)
    return t_ins, v_ins, t_ref, v_ref, var_ref


def _ns(t: np.ndarray) -> np.ndarray:
    """Round to the nanosecond and back as the node reads a stamp (sec + nanosec * 1e-9)."""
    return np.array([convert.stamp_to_s(convert.s_to_stamp(x)) for x in np.atleast_1d(t)])


def events(t_ins, v_ins, t_ref, v_ref, var_ref):
    """Publication order: by stamp, INS before reference at equal stamps."""
    ev = [(t, 0, "ins", (t, v)) for t, v in zip(t_ins, v_ins)]
    ev += [(t, 1, "ref", (t, v, r)) for t, v, r in zip(t_ref, v_ref, var_ref)]
    return [(kind, payload) for _, _, kind, payload in sorted(ev, key=lambda e: (e[0], e[1]))]


# ------------------------------------------------------------------------------ the rig

class Rig:
    """The node under test plus a driver node that owns the sim clock, the input publishers and
    collectors of everything the node publishes."""

    def __init__(self, ros, **params):
        from diagnostic_msgs.msg import DiagnosticArray
        from flight_fdi_msgs.msg import FilterState, Innovation
        from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
        from harness import collect
        from rcl_interfaces.msg import Log
        from rosgraph_msgs.msg import Clock

        from flight_fdi.nodes.filter_node import FilterNode

        self.ros = ros
        self.clock_s = 1.0  # sim time, independent of the message stamps
        self.drv = ros.node("filter_test_driver")
        self.pub_clock = self.drv.create_publisher(Clock, "/clock", 10)
        self._publish_clock()
        params = {"use_sim_time": True, "diagnostics_period_s": 0.25, **params}
        self.node = ros.node(FilterNode, parameters=params)
        self.pub_ins = self.drv.create_publisher(TwistStamped, "/ins/velocity", 100)
        self.pub_ref = self.drv.create_publisher(TwistWithCovarianceStamped,
                                                 "/reference/velocity", 100)
        self.innov = collect(ros, self.drv, Innovation, "fdi/innovation", 1000)
        self.states = collect(ros, self.drv, FilterState, "fdi/state", 1000)
        self.diags = collect(ros, self.drv, DiagnosticArray, "/diagnostics", 100)
        self.logs = collect(ros, self.drv, Log, "/rosout", 1000)
        ros.wait_for_subscribers([self.pub_clock, self.pub_ins, self.pub_ref])
        ros.wait_for_subscribers([self.node.pub_innovation, self.node.pub_state,
                                  self.node.diagnostics.publisher])
        self.sent_ins = 0
        self.sent_ref = 0
        self.advance(0.0)

    # -- time
    def _publish_clock(self):
        from rosgraph_msgs.msg import Clock

        self.pub_clock.publish(Clock(clock=convert.s_to_stamp(self.clock_s)))

    def advance(self, seconds: float):
        """Advance sim time and spin until the node's clock has it."""
        self.clock_s += seconds
        self._publish_clock()
        target = int(round(self.clock_s * 1e9))
        self.ros.spin_until(lambda: self.node.get_clock().now().nanoseconds >= target,
                            what="node clock")

    # -- inputs
    def ins(self, t, v):
        self.pub_ins.publish(convert.twist_stamped(t, v))
        self.sent_ins += 1

    def ref(self, t, v, var):
        self.pub_ref.publish(convert.twist_cov_stamped(t, v, var))
        self.sent_ref += 1

    def settle(self):
        c = self.node.counters
        self.ros.spin_until(lambda: c["received_ins"] == self.sent_ins
                            and c["received_reference"] == self.sent_ref, what="inputs received")

    def feed(self, evs, chunk_s: float = CHUNK_S):
        """Publish events in chunks of ``chunk_s`` of stamp time; sim time advances alongside."""
        start = None
        for kind, payload in evs:
            t = payload[0]
            if start is None:
                start = t
            if t - start >= chunk_s:
                self.settle()
                self.advance(chunk_s)
                start = t
            (self.ins if kind == "ins" else self.ref)(*payload)
        self.settle()
        self.advance(chunk_s)

    # -- outputs
    def channel(self, msgs, name):
        return [m for m in msgs if m.channel == name]

    def next_diagnostics(self, advance_s: float = 0.3):
        """Advance sim time past a diagnostics period; return {status name: status}."""
        n = len(self.diags)
        self.advance(advance_s)
        self.ros.spin_until(lambda: len(self.diags) > n, what="diagnostics")
        return {s.name: s for s in self.diags[-1].status}


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _stamps(msgs) -> np.ndarray:
    return np.array([convert.stamp_to_s(m.header.stamp) for m in msgs])


def _expected_z(t_ins, v_ins, t_ref, v_ref, axis):
    return np.interp(t_ref, t_ins, v_ins[:, axis]) - v_ref[:, axis]


# ------------------------------------------------------------------------------ nominal flight

def test_nominal_flight(ros):
    from flight_fdi.core.kalman import run_forward
    from flight_fdi.core.models import ins_channel

    data = flight(30.0, seed=1)
    t_ins, v_ins, t_ref, v_ref, var_ref = data
    rig = Rig(ros)  # default parameters: sensor_data QoS, channels x and y
    rig.feed(events(*data))
    N = t_ref.size
    assert N == 300
    rig.ros.spin_until(lambda: len(rig.innov) == 2 * N and len(rig.states) == 2 * N,
                       what="all outputs")
    model = ins_channel(sigma_ref=SIGMA_REF)
    chi2_1 = norm.isf(0.5e-3) ** 2  # chi-square(1) quantile for p = 1e-3, from the normal
    for name, axis in (("x", 0), ("y", 1)):
        inn, st = rig.channel(rig.innov, name), rig.channel(rig.states, name)
        assert len(inn) == len(st) == N
        np.testing.assert_array_equal(_stamps(inn), t_ref)   # header stamp = reference stamp
        np.testing.assert_array_equal(_stamps(st), t_ref)
        assert {m.header.frame_id for m in inn + st} == {"nav"}  # the frame_id parameter
        for m in inn:
            assert len(m.innovation) == 1 and len(m.innovation_covariance) == 1
            assert list(m.row_names) == ["/reference/velocity"]
            assert math.isclose(m.gate_threshold, chi2_1, rel_tol=1e-9)
            assert m.row_beta2[0] == pytest.approx(m.beta2, rel=1e-12)
            assert m.alarm_state == 0 and list(m.row_excluded) == [False]
        for m in st:
            assert list(m.state_names) == list(model.state_names)
            assert (len(m.x), len(m.p), len(m.z), len(m.r), len(m.h)) == (4, 16, 1, 1, 4)
            assert list(m.h) == [1.0, 0.0, 0.0, 0.0] and m.r[0] == pytest.approx(SIGMA_REF**2)
            assert m.fused and not m.u
        assert [m.reset for m in st] == [True] + [False] * (N - 1)
        dts = np.array([m.dt for m in st])
        np.testing.assert_allclose(dts, np.concatenate([[0.0], np.diff(t_ref)]), atol=1e-12)

        z = np.array([m.z[0] for m in st])
        np.testing.assert_allclose(z, _expected_z(*data[:4], axis), atol=1e-9)
        ref = run_forward(model, t_ref, z, R=var_ref[:, axis].reshape(-1, 1, 1))
        np.testing.assert_allclose([m.beta2 for m in inn], ref.beta2, rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose([m.innovation[0] for m in inn], ref.nu[:, 0], atol=1e-9)
        np.testing.assert_allclose(np.array([m.x for m in st]), ref.x, rtol=1e-7, atol=1e-12)
        np.testing.assert_allclose(np.array([m.p for m in st]).reshape(N, 4, 4), ref.P,
                                   rtol=1e-7, atol=1e-20)
        beta2 = np.array([m.beta2 for m in inn])
        # z = -reference noise: beta2 ~ chi-square(1) (a little smaller while P0 is shrinking)
        assert 0.6 < beta2.mean() < 1.4, beta2.mean()
        assert np.sum(beta2 > chi2_1) <= 2

    # diagnostics: keys and levels
    st = rig.next_diagnostics()
    inputs, chx = st["filter_node: inputs"], st["filter_node: channel x"]
    assert inputs.level == diag.OK and chx.level == diag.OK, (inputs.message, chx.message)
    v = _values(inputs)
    for key in ("/ins/velocity rate_hz", "/ins/velocity age_s", "/reference/velocity rate_hz",
                "/reference/velocity age_s", "received_ins", "received_reference"):
        assert key in v, key
    assert v["received_reference"] == str(N) and v["received_ins"] == str(t_ins.size)
    assert v["published"] == str(2 * N)  # steps published: one per channel and reference sample
    assert 40.0 <= float(v["/ins/velocity rate_hz"]) <= 62.0
    assert 8.0 <= float(v["/reference/velocity rate_hz"]) <= 12.5
    vx = _values(chx)
    for key in ("beta2", "gate_threshold", "alarm_state", "fused", "gated", "rejected",
                "covariance_invalid", "x.velocity_error", "x.accel_bias"):
        assert key in vx, key
    assert vx["fused"] == str(N) and vx["rejected"] == "0" and vx["alarm_state"] == "clear"
    assert float(vx["gate_threshold"]) == pytest.approx(chi2_1, rel=1e-5)
    assert float(vx["beta2"]) == pytest.approx(rig.channel(rig.innov, "x")[-1].beta2, rel=1e-5)


def test_model_info_reaches_a_late_subscriber(ros):
    from flight_fdi_msgs.msg import ModelInfo
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from flight_fdi.core.models import ins_channel

    rig = Rig(ros, channels=["y", "x"], gate_rule="seed", alarm_m=2, alarm_n=4,
              gate_action="reject", reference_variance=0.04)
    rig.feed(events(*flight(1.0, seed=2)))  # the node has been running before we subscribe
    late = ros.node("late_subscriber")
    got: list = []
    qos = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    late.create_subscription(ModelInfo, "fdi/model", got.append, qos)
    ros.spin_until(lambda: len(got) >= 2, what="ModelInfo for both channels")
    assert sorted(m.channel for m in got) == ["x", "y"]
    model = ins_channel(sigma_ref=0.2)
    for m in got:
        assert m.model_name == "ins_channel" and (m.n, m.m, m.p) == (4, 1, 0)
        assert list(m.state_names) == list(model.state_names)
        np.testing.assert_allclose(m.a, model.A.ravel())
        np.testing.assert_allclose(m.qc, model.Qc.ravel())
        np.testing.assert_allclose(m.r, [0.04])
        assert (m.gate_rule, m.alarm_m, m.alarm_n, m.gate_action) == ("seed", 2, 4, "reject")
        assert dict(zip(m.param_names, m.param_values))["tau_a"] == 3600.0


# ------------------------------------------------------------------------------ bad input

def test_bad_input_is_dropped_counted_and_survived(ros):
    rig = Rig(ros, input_qos="reliable", reference_variance=0.04, max_gap_s=0.3)
    t_ins, v_ins, t_ref, v_ref, var_ref = flight(6.0, seed=3)
    var_ref = var_ref.copy()
    v_ref = v_ref.copy()
    v_ins = v_ins.copy()
    # reference faults (by index of the reference sample)
    v_ref[3, 0] = np.nan          # x non-finite, y fine
    v_ref[4, :2] = np.inf         # both channels non-finite
    var_ref[6] = 0.0              # covariance zero / negative / NaN -> reference_variance
    var_ref[7] = -1.0
    var_ref[8] = np.nan
    v_ins[60] = np.nan            # an INS sample with NaN: dropped, interpolation bridges it
    # an INS gap > max_gap_s around t_ref[30..33]: remove INS samples in (t_ref[30]-0.1, +0.5)
    gap = (t_ins > t_ref[30] - 0.1) & (t_ins < t_ref[30] + 0.4)
    evs = events(t_ins[~gap], v_ins[~gap], t_ref, v_ref, var_ref)
    # duplicate and out-of-order stamps right after reference sample 12 and INS sample 100
    k = next(i for i, e in enumerate(evs) if e[0] == "ref" and e[1][0] == t_ref[12])
    evs[k + 1:k + 1] = [("ref", (t_ref[12], v_ref[12], var_ref[12])),
                        ("ref", (t_ref[11], v_ref[11], var_ref[11]))]
    k = next(i for i, e in enumerate(evs) if e[0] == "ins" and e[1][0] == t_ins[100])
    evs[k + 1:k + 1] = [("ins", (t_ins[100], v_ins[100])), ("ins", (t_ins[99], v_ins[99]))]
    rig.feed(evs)

    n_gap = int(np.sum((t_ref > t_ins[~gap][t_ins[~gap] < t_ref[30]][-1])
                       & (t_ref < t_ins[~gap][t_ins[~gap] > t_ref[30]][0])))
    assert n_gap >= 4
    c = rig.node.counters
    assert c["dropped_ins_nonfinite"] == 1
    assert c["dropped_reference_duplicate"] == 1 and c["dropped_reference_out_of_order"] == 1
    assert c["dropped_ins_duplicate"] == 1 and c["dropped_ins_out_of_order"] == 1
    assert c["dropped_ins_gap"] == n_gap
    chx, chy = rig.node.channels
    assert chx.counters["dropped_reference_nonfinite"] == 2
    assert chy.counters["dropped_reference_nonfinite"] == 1
    assert chx.counters["covariance_invalid"] == chy.counters["covariance_invalid"] == 3

    N = t_ref.size
    sx, sy = rig.channel(rig.states, "x"), rig.channel(rig.states, "y")
    assert len(sx) == N - 2 - n_gap and len(sy) == N - 1 - n_gap
    for s in (sx, sy):
        stamps = _stamps(s)
        assert np.all(np.diff(stamps) > 0)  # never reordered, no duplicates
        by_t = {round(convert.stamp_to_s(m.header.stamp), 6): m for m in s}
        for i in (6, 7, 8):
            assert by_t[round(t_ref[i], 6)].r[0] == pytest.approx(0.04)
        assert by_t[round(t_ref[9], 6)].r[0] == pytest.approx(SIGMA_REF**2)
    # z where the NaN INS sample was dropped: interpolated over the remaining samples
    keep = np.ones(t_ins.size, dtype=bool)
    keep[60] = False
    keep &= ~gap
    want = _expected_z(t_ins[keep], v_ins[keep], t_ref, v_ref, 1)
    got = {round(convert.stamp_to_s(m.header.stamp), 6): m.z[0] for m in sy}
    for i in range(N):
        if round(t_ref[i], 6) in got:
            assert got[round(t_ref[i], 6)] == pytest.approx(want[i], abs=1e-9)

    # everything is reported in /diagnostics, and the node keeps filtering
    st = rig.next_diagnostics()
    v = _values(st["filter_node: inputs"])
    assert v["dropped_reference_duplicate"] == "1" and v["dropped_ins_gap"] == str(n_gap)
    assert _values(st["filter_node: channel x"])["dropped_reference_nonfinite"] == "2"
    n_before = len(rig.states)
    rig.feed(events(*flight(1.0, seed=4, t0=T0 + 10.0)))
    ros.spin_until(lambda: len(rig.states) >= n_before + 18, what="filtering after bad input")

    # bytes that are not the message type (only a broken publisher sends them; the node reads
    # the raw CDR): dropped, counted, reported, survived
    good_ins = bytes(serialize_message(convert.twist_stamped(T0 + 20.0, [1.0, 2.0, 3.0])))
    good_ref = bytes(serialize_message(convert.twist_cov_stamped(T0 + 20.0, [1.0, 2.0, 3.0],
                                                                 0.01)))
    for data in (good_ins[:30], b"\x07\x01\x00\x00" + good_ins[4:]):
        rig.pub_ins.publish(data)
    rig.pub_ref.publish(good_ref[:60])
    rig.sent_ins += 2
    rig.sent_ref += 1
    ros.spin_until(lambda: c["dropped_ins_malformed"] == 2
                   and c["dropped_reference_malformed"] == 1, what="malformed bytes counted")
    for _ in range(5):  # (a diagnostics message already on its way may predate them)
        v = _values(rig.next_diagnostics()["filter_node: inputs"])
        if "dropped_ins_malformed" in v:
            break
    assert v["dropped_ins_malformed"] == "2" and v["dropped_reference_malformed"] == "1"
    n_before = len(rig.states)
    rig.feed(events(*flight(1.0, seed=5, t0=T0 + 30.0)))
    ros.spin_until(lambda: len(rig.states) >= n_before + 8, what="filtering after bad bytes")


def test_reference_dropout_warns_then_recovers(ros):
    rig = Rig(ros, input_qos="reliable")
    t_ins, v_ins, t_ref, v_ref, var_ref = flight(20.0, seed=5)
    out = (t_ref > T0 + 5.0) & (t_ref < T0 + 15.0)  # a 10-s reference dropout
    evs = events(t_ins, v_ins, t_ref[~out], v_ref[~out], var_ref[~out])
    split = next(i for i, e in enumerate(evs) if e[1][0] > T0 + 5.0)
    rig.feed(evs[:split])
    st = rig.next_diagnostics()
    assert st["filter_node: inputs"].level == diag.OK, st["filter_node: inputs"].message
    # INS keeps coming for 10 s of sim time, the reference does not
    resume = next(i for i, e in enumerate(evs) if e[0] == "ref" and e[1][0] > T0 + 15.0)
    rig.feed(evs[split:resume])
    st = rig.next_diagnostics()
    inputs, chx = st["filter_node: inputs"], st["filter_node: channel x"]
    assert inputs.level == diag.WARN and "/reference/velocity stale for" in inputs.message
    assert "/ins/velocity" not in inputs.message
    assert float(_values(inputs)["/reference/velocity age_s"]) > 9.0
    assert chx.level == diag.WARN and "no filter update for" in chx.message
    n_before = len(rig.channel(rig.states, "x"))
    rig.feed(evs[resume:])
    st = rig.next_diagnostics()
    assert st["filter_node: inputs"].level == diag.OK, st["filter_node: inputs"].message
    assert st["filter_node: channel x"].level == diag.OK
    sx = rig.channel(rig.states, "x")
    ix = rig.channel(rig.innov, "x")
    first = sx[n_before]  # the first step after the dropout predicts across it
    t_last, t_next = t_ref[~out][t_ref[~out] < T0 + 5.0][-1], t_ref[out.argmax() + out.sum()]
    assert first.dt == pytest.approx(t_next - t_last, abs=1e-9) and first.dt > 10.0
    assert not first.reset and first.fused
    # the prediction across 10 s made the innovation covariance grow
    assert ix[n_before].innovation_covariance[0] > ix[n_before - 1].innovation_covariance[0]


def test_gap_longer_than_reset_after_gap_restarts(ros):
    rig = Rig(ros, input_qos="reliable", reset_after_gap_s=5.0, channels=["x"])
    t_ins, v_ins, t_ref, v_ref, var_ref = flight(10.0, seed=6)
    out = (t_ref > T0 + 2.0) & (t_ref < T0 + 9.0)
    rig.feed(events(t_ins, v_ins, t_ref[~out], v_ref[~out], var_ref[~out]))
    s = rig.states
    k = int(np.argmax(_stamps(s) > T0 + 9.0))
    assert [m.reset for m in s].count(True) == 2 and s[k].reset and s[k].dt == 0.0
    assert rig.node.channels[0].counters["resets"] == 1


def test_time_jump_backwards_resets_the_filter(ros):
    rig = Rig(ros, input_qos="reliable", channels=["x"])
    rig.feed(events(*flight(3.0, seed=7, t0=T0)))
    n1 = len(rig.states)
    rig.feed(events(*flight(3.0, seed=8, t0=T0 - 500.0)))  # a bag loop / clock reset
    s = rig.states[n1:]
    assert len(s) == 30 and s[0].reset and s[0].dt == 0.0 and not any(m.reset for m in s[1:])
    assert _stamps(s)[0] == pytest.approx(T0 - 500.0 + REF_OFFSET)
    assert rig.node.counters["time_jump_resets"] == 1
    assert rig.node.counters.total() == 0  # the samples held until the jump was confirmed: used
    ros.spin_until(lambda: any(m.level == 30 and "time jumped from" in m.msg for m in rig.logs),
                   what="a WARN log about the time jump")
    st = rig.next_diagnostics()
    assert _values(st["filter_node: inputs"])["time_jump_resets"] == "1"
    ch = st["filter_node: channel x"]
    assert ch.level == diag.WARN and "filter reset" in ch.message
    assert "reference time jumped from 1002.904 s to 500.004 s" in ch.message
    assert "reference time jumped" in _values(ch)["last_reset"]


def _with_wild(evs, wild):
    """``evs`` with the (kind, payload) events of ``wild`` inserted after the first half."""
    k = len(evs) // 2
    return evs[:k] + wild + evs[k:]


@pytest.mark.parametrize("stamp", [0.0, T0 + 1e6])
def test_a_single_wild_reference_stamp_is_an_outlier_not_a_reset(ros, stamp):
    rig = Rig(ros, input_qos="reliable", channels=["x"])
    t_ins, v_ins, t_ref, v_ref, var_ref = data = flight(4.0, seed=17)
    rig.feed(_with_wild(events(*data), [("ref", (stamp, v_ref[0], var_ref[0]))]))
    assert len(rig.states) == t_ref.size and not any(m.reset for m in rig.states[1:])
    c = rig.node.counters
    assert c["dropped_reference_stamp_outlier"] == 1 and c["time_jump_resets"] == 0
    assert c.total() == 1 and rig.node.channels[0].counters["resets"] == 0
    st = rig.next_diagnostics()
    assert _values(st["filter_node: inputs"])["dropped_reference_stamp_outlier"] == "1"
    assert st["filter_node: channel x"].level == diag.OK


def test_a_burst_of_wild_stamps_on_both_inputs_is_outliers(ros):
    rig = Rig(ros, input_qos="reliable", channels=["x"])
    t_ins, v_ins, t_ref, v_ref, var_ref = data = flight(4.0, seed=18)
    wild = [("ins", (0.0, v_ins[0])), ("ref", (0.0, v_ref[0], var_ref[0])),
            ("ref", (0.0, v_ref[0], var_ref[0])), ("ins", (0.02, v_ins[1])),
            ("ref", (0.1, v_ref[1], var_ref[1]))]  # 2 samples of a new line: < confirm (3)
    rig.feed(_with_wild(events(*data), wild))
    c = rig.node.counters
    assert c["dropped_ins_stamp_outlier"] == 2 and c["dropped_reference_stamp_outlier"] == 3
    assert c["time_jump_resets"] == 0 and c.total() == 5
    assert len(rig.states) == t_ref.size and not any(m.reset for m in rig.states[1:])


def test_time_jump_confirm_1_resets_at_the_first_wild_stamp(ros):
    rig = Rig(ros, input_qos="reliable", channels=["x"], time_jump_confirm=1)
    t_ins, v_ins, t_ref, v_ref, var_ref = data = flight(4.0, seed=17)
    rig.feed(_with_wild(events(*data), [("ref", (0.0, v_ref[0], var_ref[0]))]))
    assert rig.node.counters["time_jump_resets"] == 2  # to 0 and back
    assert rig.node.channels[0].counters["resets"] == 2


def test_topic_that_never_arrives_is_reported(ros):
    rig = Rig(ros)
    st = rig.next_diagnostics()
    inputs = st["filter_node: inputs"]
    assert inputs.level == diag.WARN
    assert "no messages on /reference/velocity yet" in inputs.message
    assert "no messages on /ins/velocity yet" in inputs.message
    assert _values(inputs)["/reference/velocity age_s"] == "never"
    assert st["filter_node: channel y"].level == diag.WARN
    assert st["filter_node: channel y"].message == "no filter update yet"
    t_ins, v_ins, *_ = flight(1.0, seed=9)
    rig.feed(events(t_ins, v_ins, [], [], []))
    st = rig.next_diagnostics()
    assert st["filter_node: inputs"].message == "no messages on /reference/velocity yet"


# ------------------------------------------------------------------------------ detection

@pytest.mark.parametrize("action", ["flag", "reject"])
def test_velocity_ramp_raises_the_alarm(ros, action):
    # an accelerometer bias step of 0.2 m/s^2 on x: the INS velocity error ramps up; the model
    # expects biases of ~1e-3 m/s^2, so the ramp goes mostly into the innovation: |nu| passes the
    # gate sqrt(10.8 S) ~ 0.33 m/s after ~2 s, and 3 of 5 samples later the alarm is raised
    onset = T0 + 12.0
    rig = Rig(ros, input_qos="reliable", gate_action=action)
    rig.feed(events(*flight(18.0, seed=10, ramp_onset=onset, ramp_slope=0.2)))
    ix, iy = rig.channel(rig.innov, "x"), rig.channel(rig.innov, "y")
    tx = _stamps(ix)
    alarm = np.array([m.alarm_state for m in ix])
    raised = tx[alarm == 1]
    assert raised.size >= 1 and onset + 1.0 < raised[0] < onset + 4.0, raised
    assert np.all(alarm[tx < onset] == 0)
    assert all(m.alarm_state == 0 for m in iy)  # the y channel has no fault
    chx = rig.node.channels[0].counters
    if action == "flag":
        assert chx["rejected"] == 0 and chx["fused"] == len(ix)
    else:
        assert chx["rejected"] == chx["gated"] > 0 and chx["fused"] == len(ix) - chx["gated"]
        assert all(not s.fused for s in rig.channel(rig.states, "x") if s.gated)
    st = rig.next_diagnostics()
    assert st["filter_node: channel x"].level == diag.ERROR
    assert "INS fault alarm" in st["filter_node: channel x"].message
    assert st["filter_node: channel y"].level == diag.OK
    ros.spin_until(lambda: any(m.level == 30 and "alarm raised" in m.msg for m in rig.logs),
                   what="a WARN log about the alarm")


# ------------------------------------------------------------------------------ parameters

@pytest.mark.parametrize("overrides, name", [
    ({"alarm_m": 6, "alarm_n": 5}, "alarm_m"),
    ({"gate_rule": "bogus"}, "gate_rule"),
    ({"gate_probability": 0.0}, "gate_probability"),
    ({"max_gap_s": -1.0}, "max_gap_s"),
    ({"max_gap_s": 1}, "max_gap_s"),
    ({"buffer_s": 0.4}, "buffer_s"),
    ({"channels": ["z"]}, "channels"),
    ({"model": "no_such_model"}, "model"),
    ({"model": "attitude_axis", "attitude_measure": "rate"}, "attitude_measure"),
    ({"reference_variance": 0.0}, "reference_variance"),
    ({"input_qos": "best"}, "input_qos"),
    ({"ins_topic": "bad topic!"}, "ins_topic"),
    ({"ins_topic": "/a//b"}, "ins_topic"),
    ({"reference_topic": "ins/velocity", "ins_topic": "/ins/velocity"}, "reference_topic"),
    ({"stale_after_s": math.nan}, "stale_after_s"),
])
def test_invalid_parameter_stops_the_node_naming_it(ros, overrides, name):
    from flight_fdi.nodes.filter_node import FilterNode

    with pytest.raises(ParameterError) as err:
        ros.node(FilterNode, parameters=overrides)
    assert f"'{name}'" in str(err.value), str(err.value)
    assert repr(overrides[name]) in str(err.value)


def test_model_file_and_its_overrides(ros, tmp_path):
    from flight_fdi.nodes.filter_node import FilterNode

    path = tmp_path / "model.yaml"
    path.write_text("name: vel_only\nstates: [{name: velocity_error, unit: m/s}]\n"
                    "A: [[-0.01]]\nQc: [[1.0e-4]]\nH: [[1.0]]\nR: [[0.5]]\nP0: [[0.01]]\n")
    node = ros.node(FilterNode, parameters={"model": str(path), "channels": ["x"]})
    assert node.model.name == "vel_only" and node.model.R[0, 0] == 0.01  # reference_variance
    with pytest.raises(ParameterError, match="'tau_a'.*ins_channel"):
        ros.node(FilterNode, parameters={"model": str(path), "tau_a": 100.0})


def test_params_file_is_accepted(ros, repo_root):
    from flight_fdi.nodes.filter_node import FILTER_PARAMS, FilterNode

    node = ros.node(FilterNode, cli_args=["--ros-args", "--params-file",
                                          str(repo_root / "config" / "filter.yaml")])
    assert node.p == {s.name: s.default for s in FILTER_PARAMS}


def test_main_exits_non_zero_on_an_invalid_parameter(repo_root):
    env = dict(os.environ, PYTHONPATH=str(repo_root))
    proc = subprocess.run(
        [sys.executable, "-m", "flight_fdi.nodes.filter_node", "--ros-args",
         "-p", "alarm_m:=9"], capture_output=True, text=True, timeout=60, env=env,
        cwd=repo_root)
    assert proc.returncode == 1, proc.stderr
    assert "FATAL" in proc.stderr and "'alarm_m'" in proc.stderr and "alarm_n" in proc.stderr


# ------------------------------------------------------------------------------ helpers

def test_rate_meter_and_input_monitor():
    now = [0.0]
    mon = diag.InputMonitor(lambda: now[0], ["a", "b"], window_s=2.0, stale_after_s=0.5)
    assert math.isnan(mon.age("a")) and mon.never_seen("a") and mon.rate("a") == 0.0
    for k in range(31):  # 10 Hz for 3 s
        now[0] = k * 0.1
        mon.seen("a")
    assert mon.rate("a") == pytest.approx(10.5, abs=0.6)  # 21 events in the 2-s window
    assert mon.age("a") == 0.0 and not mon.is_stale("a")
    now[0] = 3.7
    assert mon.age("a") == pytest.approx(0.7) and mon.is_stale("a")
    assert mon.problems() == ["a stale for 0.7 s", "no messages on b yet"]
    now[0] = 10.0
    assert mon.rate("a") == 0.0
    kv = dict(mon.key_values())
    assert kv["b age_s"] == "never" and kv["a count"] == "31"
    fresh = diag.RateMeter(5.0)
    for k in range(3):
        fresh.tick(k * 0.1)
    assert fresh.rate(0.25) == pytest.approx(10.0)  # short history: no ramp-up bias


def test_counters_levels_and_status():
    c = diag.Counters(["fused"])
    c.inc("dropped_gap")
    c.inc("dropped_gap", 2)
    c.inc("dropped_nan")
    assert c["fused"] == 0 and c["dropped_gap"] == 3 and c.total("dropped_") == 4
    assert c.key_values() == [("fused", "0"), ("dropped_gap", "3"), ("dropped_nan", "1")]
    assert diag.worst([diag.OK, diag.STALE, diag.WARN]) == diag.WARN
    assert diag.worst([]) == diag.OK and diag.worst([diag.ERROR, diag.WARN]) == diag.ERROR
    s = diag.make_status("n", diag.WARN, "msg", {"a": 1.5, "b": None, "c": math.nan, "d": True})
    assert s.level == diag.WARN and [(kv.key, kv.value) for kv in s.values] == [
        ("a", "1.5"), ("b", "never"), ("c", "nan"), ("d", "true")]


@pytest.mark.parametrize("sigint_at_start", ["default", "ignored"])
@pytest.mark.parametrize("executor", ["single", "events"])
def test_main_runs_on_the_chosen_executor_until_sigint(repo_root, executor, sigint_at_start):
    """SIGINT right after the node logs its configuration (before or after the first spin) ends
    it cleanly -- also when the process started with SIGINT ignored (a background job of a
    non-interactive shell, as in CI), where only rclpy's handler sees the signal."""
    import signal

    def ignore_sigint():
        signal.signal(signal.SIGINT, signal.SIG_IGN)

    env = dict(os.environ, PYTHONPATH=str(repo_root), ROS_AUTOMATIC_DISCOVERY_RANGE="OFF")
    proc = subprocess.Popen(
        [sys.executable, "-u", "-m", "flight_fdi.nodes.filter_node", "--executor", executor,
         "--ros-args", "-p", "diagnostics_period_s:=0.2"], stderr=subprocess.PIPE, text=True,
        env=env, cwd=repo_root, preexec_fn=ignore_sigint if sigint_at_start == "ignored" else None)
    try:
        for line in proc.stderr:  # the node logs its configuration at the end of its constructor
            if "filtering channels" in line:
                break
        proc.send_signal(signal.SIGINT)
        rest = proc.stderr.read()
        assert proc.wait(timeout=30) == 0, rest
        assert "Traceback" not in rest and "Exception ignored" not in rest, rest
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()


def test_main_refuses_an_unknown_executor(repo_root):
    env = dict(os.environ, PYTHONPATH=str(repo_root))
    proc = subprocess.run([sys.executable, "-m", "flight_fdi.nodes.filter_node", "--executor",
                           "threads"], capture_output=True, text=True, timeout=60, env=env,
                          cwd=repo_root)
    assert proc.returncode == 2
    assert "invalid choice: 'threads'" in proc.stderr and "Traceback" not in proc.stderr
