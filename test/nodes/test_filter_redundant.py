"""filter_node with redundant references (``reference_topics``), in-process on sim time.

Three reference topics measure the same velocity; one of them jumps by 2 m/s for a while. In each
``reference_mode`` the node must identify it, report it in Innovation (row_failed, row_excluded)
and /diagnostics, keep the estimate what the mode prescribes, and readmit the reference after it
heals. Expected values are derived independently of the node: z from ``np.interp`` over the
published INS samples, and the filter by replaying FilterPy over those z with the rows the mode
prescribes (every row, R + Gamma on the inflated row, or the rows kept).
"""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterPyKF
from scipy.stats import norm

from flight_fdi.nodes import convert
from flight_fdi.nodes import diagnostics as diag
from flight_fdi.nodes.errors import ParameterError

T0 = 1000.0
INS_HZ = 50
REF_HZ = 10
REF_OFFSET = 0.004
SIGMA_REF = 0.1
CHUNK_S = 0.5
TOPICS = ["/ref/a", "/ref/b", "/ref/c"]
GAMMA = 4.0
READMIT = 2.0
WAIT = 0.35           # reference_sync_wait_s: not a multiple of the 0.1-s reference period
CHI2_1 = norm.isf(0.5e-3) ** 2  # one-row gate, p = 1e-3
JUMP = (T0 + 5.0, T0 + 12.0, 2.0)  # /ref/b reads 2 m/s too much on x in [5 s, 12 s)


def _ns(t):
    return np.array([convert.stamp_to_s(convert.s_to_stamp(x)) for x in np.atleast_1d(t)])


def truth(t):
    t = np.asarray(t, dtype=float)
    return np.stack([50.0 + 0.5 * (t - T0), -20.0 + 0.0 * t, 1.0 + 0.0 * t], axis=-1)


def flight(seconds, seed, jump=JUMP, t0=T0):
    """INS (exact truth) and three noisy references; reference 1 jumps on x during ``jump``."""
    rng = np.random.default_rng(seed)
    t_ins = _ns(t0 + np.arange(int(round(seconds * INS_HZ))) / INS_HZ)
    t_ref = _ns(t0 + REF_OFFSET + np.arange(int(round(seconds * REF_HZ))) / REF_HZ)
    t_ref = t_ref[t_ref < t_ins[-1]]
    v_ins = truth(t_ins)
    v_ref = truth(t_ref)[None] + rng.normal(0.0, SIGMA_REF, (3, t_ref.size, 3))
    if jump is not None:
        on = (t_ref >= jump[0]) & (t_ref < jump[1])
        v_ref[1, on, 0] += jump[2]
    return t_ins, v_ins, t_ref, v_ref


def events(t_ins, v_ins, t_ref, v_ref, skip=()):
    """Publication order: by stamp, INS first, then the references in order. ``skip``: (ref,
    index) not published."""
    ev = [(t, 0, 0, "ins", (t, v)) for t, v in zip(t_ins, v_ins)]
    ev += [(t, 1, r, "ref", (r, t, v_ref[r, i], SIGMA_REF**2))
           for r in range(v_ref.shape[0]) for i, t in enumerate(t_ref) if (r, i) not in skip]
    return [(kind, payload) for *_, kind, payload in sorted(ev, key=lambda e: e[:3])]


class Rig:
    """The node with redundant references, and a driver owning sim time, the inputs and
    collectors of the outputs."""

    def __init__(self, ros, **params):
        from diagnostic_msgs.msg import DiagnosticArray
        from flight_fdi_msgs.msg import FilterState, Innovation
        from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
        from harness import collect
        from rcl_interfaces.msg import Log
        from rosgraph_msgs.msg import Clock

        from flight_fdi.nodes.filter_node import FilterNode

        self.ros = ros
        self.clock_s = 1.0
        self.drv = ros.node("redundant_test_driver")
        self.pub_clock = self.drv.create_publisher(Clock, "/clock", 10)
        self._clock()
        params = {"use_sim_time": True, "diagnostics_period_s": 0.25, "channels": ["x"],
                  "input_qos": "reliable", "reference_topics": TOPICS,
                  "reference_sync_wait_s": WAIT, "readmit_after_s": READMIT,
                  "anomaly_variance": GAMMA, **params}
        self.node = ros.node(FilterNode, parameters=params)
        self.pub_ins = self.drv.create_publisher(TwistStamped, "/ins/velocity", 200)
        self.pub_ref = [self.drv.create_publisher(TwistWithCovarianceStamped, tp, 200)
                        for tp in TOPICS]
        self.innov = collect(ros, self.drv, Innovation, "fdi/innovation", 1000)
        self.states = collect(ros, self.drv, FilterState, "fdi/state", 1000)
        self.diags = collect(ros, self.drv, DiagnosticArray, "/diagnostics", 100)
        self.logs = collect(ros, self.drv, Log, "/rosout", 1000)
        subscribed = {ref.name for ref in self.node.refs}
        ros.wait_for_subscribers([self.pub_clock, self.pub_ins] + [
            p for p, tp in zip(self.pub_ref, TOPICS) if tp in subscribed])
        ros.wait_for_subscribers([self.node.pub_innovation, self.node.pub_state,
                                  self.node.diagnostics.publisher])
        self.sent = 0
        self.advance(0.0)

    def _clock(self):
        from rosgraph_msgs.msg import Clock

        self.pub_clock.publish(Clock(clock=convert.s_to_stamp(self.clock_s)))

    def advance(self, seconds):
        self.clock_s += seconds
        self._clock()
        target = int(round(self.clock_s * 1e9))
        self.ros.spin_until(lambda: self.node.get_clock().now().nanoseconds >= target,
                            what="node clock")

    def settle(self):
        c = self.node.counters
        self.ros.spin_until(lambda: c["received_ins"] + c["received_reference"] == self.sent,
                            what="inputs received")

    def feed(self, evs):
        start = None
        for kind, payload in evs:
            t = payload[0] if kind == "ins" else payload[1]
            if start is None:
                start = t
            if t - start >= CHUNK_S:
                self.settle()
                self.advance(CHUNK_S)
                start = t
            if kind == "ins":
                self.pub_ins.publish(convert.twist_stamped(*payload))
            else:
                r, tr, v, var = payload
                self.pub_ref[r].publish(convert.twist_cov_stamped(tr, v, var))
            self.sent += 1
        self.settle()
        self.advance(CHUNK_S)

    def outputs(self, n):
        self.ros.spin_until(lambda: len(self.innov) >= n and len(self.states) >= n,
                            what=f"{n} outputs")
        return self.innov[:n], self.states[:n]

    def diagnostics(self):
        n = len(self.diags)
        self.advance(0.3)
        self.ros.spin_until(lambda: len(self.diags) > n, what="diagnostics")
        return {s.name: s for s in self.diags[-1].status}


def _values(status):
    return {kv.key: kv.value for kv in status.values}


def _stamps(msgs):
    return np.array([convert.stamp_to_s(m.header.stamp) for m in msgs])


def replay(model, t, Z, rows_of, rdiag_of):
    """FilterPy over the stamps ``t``: at update k the prior innovation of every row of
    ``Z[k]`` (a dict name -> z), then the update with the rows ``rows_of(k)`` and variances
    ``rdiag_of(k, rows)``. Returns (prior nu per update (dict), x, P)."""
    kf = FilterPyKF(model.n, 1)
    kf.x = np.zeros((model.n, 1))
    kf.P = np.array(model.P0)
    h = np.array(model.H)[0]
    nus, xs, Ps = [], [], []
    for k in range(len(t)):
        if k:
            kf.F, kf.Q = model.discretize(t[k] - t[k - 1])[:2]
            kf.predict()
        nus.append({nm: z - h @ kf.x[:, 0] for nm, z in Z[k].items()})
        rows = rows_of(k)
        if rows:
            kf.update(np.array([Z[k][nm] for nm in rows]).reshape(-1, 1),
                      R=np.diag(rdiag_of(k, rows)), H=np.tile(h, (len(rows), 1)))
        xs.append(kf.x[:, 0].copy())
        Ps.append(kf.P.copy())
    return nus, np.array(xs), np.array(Ps)


# ------------------------------------------------------------------------------ failing reference

@pytest.mark.parametrize("mode", ["nominal", "known_anomaly", "exclude"])
def test_a_failing_reference_in_each_mode(ros, mode):
    from flight_fdi.core.kalman import GateConfig
    from flight_fdi.core.models import ins_channel

    data = flight(18.0, seed=21)
    t_ins, v_ins, t_ref, v_ref = data
    N = t_ref.size
    rig = Rig(ros, reference_mode=mode)
    evs = events(*data)
    split = next(i for i, e in enumerate(evs) if e[0] == "ins" and e[1][0] > T0 + 9.0)
    rig.feed(evs[:split])

    # during the failure: /diagnostics names the failed reference
    st = rig.diagnostics()
    ref_b = st["filter_node: reference /ref/b"]
    vb = _values(ref_b)
    k0 = int(np.argmax(t_ref >= JUMP[0]))          # first wild sample
    kf_ = k0 + GateConfig().alarm_m - 1              # declared failed (3 of 5, all wild)
    assert ref_b.level == diag.WARN and "failed on channel x" in ref_b.message
    assert vb["x.failed"] == "true" and vb["x.failures"] == "1"
    assert vb["x.excluded"] == ("false" if mode == "nominal" else "true")
    last_t = rig.node.channels[0].last_t
    assert float(vb["x.time_since_failure_s"]) == pytest.approx(last_t - t_ref[kf_], abs=1e-6)
    for other in ("/ref/a", "/ref/c"):
        s = st[f"filter_node: reference {other}"]
        assert s.level == diag.OK and _values(s)["x.failed"] == "false"
    chx = _values(st["filter_node: channel x"])
    assert chx["failed_references"] == "/ref/b"
    assert chx["rows_used"] == ("2" if mode == "exclude" else "3")

    rig.feed(evs[split:])
    innov, states = rig.outputs(N)
    assert len(rig.innov) == len(rig.states) == N  # one update per stamp, never reordered
    np.testing.assert_array_equal(_stamps(innov), t_ref)
    for m in innov:
        assert list(m.row_names) == TOPICS

    failed = np.array([list(m.row_failed) for m in innov])
    excluded = np.array([list(m.row_excluded) for m in innov])
    assert not failed[:, [0, 2]].any() and not excluded[:, [0, 2]].any()
    assert not failed[:kf_, 1].any() and failed[kf_, 1]
    k1 = int(np.argmax(t_ref >= JUMP[1]))           # first healed sample
    if mode == "nominal":
        assert not excluded.any()
    else:
        # handled from its first wild sample (suspect), readmitted readmit_after_s after healing
        kr = int(np.argmax(t_ref >= t_ref[k1] + READMIT - 1e-6))
        rb = np.array([m.row_beta2[1] for m in innov[k1:kr + 1]])
        assert np.all(rb <= CHI2_1)  # its own gate passed all along (checked vs FilterPy below)
        assert excluded[k0:kr, 1].all() and not excluded[:k0, 1].any()
        assert not excluded[kr:, 1].any()
        assert failed[kf_:kr, 1].all() and not failed[kr:, 1].any()
        ros.spin_until(lambda: any("/ref/b readmitted" in m.msg for m in rig.logs),
                       what="an INFO log about the readmission")
    ros.spin_until(lambda: any(m.level == 30 and "/ref/b failed" in m.msg for m in rig.logs),
                   what="a WARN log about the failure")

    # the filter, replayed with FilterPy on independently computed z
    model = ins_channel(sigma_ref=SIGMA_REF)
    zs = [{TOPICS[r]: float(np.interp(t_ref[k], t_ins, v_ins[:, 0]) - v_ref[r, k, 0])
           for r in range(3)} for k in range(N)]
    if mode == "exclude":
        def rows_of(k):
            return [TOPICS[r] for r in range(3) if not excluded[k, r]]
    else:
        def rows_of(k):
            return TOPICS
    gamma = GAMMA if mode == "known_anomaly" else 0.0

    def rdiag(k, rows):
        return [SIGMA_REF**2 + gamma * excluded[k, TOPICS.index(nm)] for nm in rows]

    nus, x_ref, P_ref = replay(model, t_ref, zs, rows_of, rdiag)
    s = model.scale
    x = np.array([m.x for m in states])
    P = np.array([m.p for m in states]).reshape(N, 4, 4)
    assert np.max(np.abs(x - x_ref) / s) < 1e-7
    assert np.max(np.abs(P - P_ref) / np.outer(s, s)) < 1e-7
    nu = np.array([list(m.innovation) for m in innov])
    np.testing.assert_allclose(nu, [[n[tp] for tp in TOPICS] for n in nus], atol=1e-9)
    # FilterState: z, r, h of exactly the rows fused
    for k in (k0 - 1, k0 + 5, N - 1):
        st_k = states[k]
        rows = rows_of(k)
        np.testing.assert_allclose(st_k.z, [zs[k][nm] for nm in rows], atol=1e-9)
        np.testing.assert_allclose(np.array(st_k.r).reshape(len(rows), len(rows)),
                                   np.diag(rdiag(k, rows)), rtol=1e-12)
        np.testing.assert_array_equal(np.array(st_k.h).reshape(len(rows), 4),
                                      np.tile(model.H, (len(rows), 1)))

    # the estimate: consistent while the reference is handled; dragged in nominal mode
    beta2 = np.array([m.beta2 for m in innov])
    thr = np.array([m.gate_threshold for m in innov])
    alarms = np.array([m.alarm_state for m in innov])
    if mode == "nominal":
        assert np.sum(beta2[k0:k1] > thr[k0:k1]) > 0.5 * (k1 - k0)
        assert (alarms == 1).any()
    else:
        m_used = 2 if mode == "exclude" else 3
        np.testing.assert_allclose(thr[kf_ + 1:k1], GateConfig().threshold(m_used))
        assert 0.5 < np.mean(beta2[kf_:k1]) / m_used < 1.6
        assert np.sum(beta2 > thr) <= 2 and not (alarms == 1).any()

    # after the end: /ref/b healthy again (except in nominal mode, whose estimate was dragged)
    st = rig.diagnostics()
    vb = _values(st["filter_node: reference /ref/b"])
    if mode != "nominal":
        assert st["filter_node: reference /ref/b"].level == diag.OK
        assert vb["x.failed"] == "false" and vb["x.readmissions"] == "1"
        assert vb["x.time_since_failure_s"] == "never"
    assert vb["samples"] == str(N) and vb["missing"] == "0"
    assert float(_values(st["filter_node: channel x"])["accuracy_J"]) == pytest.approx(
        float(np.sum(np.diag(P[-1]) / s**2)), rel=1e-5)


# ------------------------------------------------------------------------------ synchronisation

def test_missing_and_late_samples_leave_rows_out(ros):
    # /ref/c: sample 60 is never published; samples 30..39 are held back and arrive in a burst
    # after everything up to 4 s was processed -- the updates did not wait for them (/ref/c was
    # more than reference_sync_wait_s behind), so they are late; /ref/a and /ref/b are complete
    data = flight(8.0, seed=22, jump=None)
    t_ins, v_ins, t_ref, v_ref = data
    N = t_ref.size
    rig = Rig(ros, reference_mode="exclude", channels=["x", "y"])
    held = set(range(30, 40))
    evs = events(*data, skip={(2, 60)} | {(2, i) for i in held})
    split = next(i for i, e in enumerate(evs) if e[1][0] >= T0 + 3.99)  # before sample 40
    rig.feed(evs[:split])
    burst = [("ref", (2, t_ref[i], v_ref[2, i], SIGMA_REF**2)) for i in sorted(held)]
    rig.feed(burst + evs[split:])
    innov, states = rig.outputs(2 * N)
    for name in ("x", "y"):
        inn = [m for m in innov if m.channel == name]
        np.testing.assert_array_equal(_stamps(inn), t_ref)
        rows = [list(m.row_names) for m in inn]
        short = [k for k, r in enumerate(rows) if r != TOPICS]
        assert short == list(range(30, 40)) + [60]
        assert all(rows[k] == TOPICS[:2] for k in short)
        assert not any(any(m.row_failed) or any(m.row_excluded) for m in inn)
        sts = [m for m in states if m.channel == name]
        assert [len(m.z) for m in sts] == [2 if k in short else 3 for k in range(N)]
        # each row uses the INS velocity at its own stamp
        axis = "xy".index(name)
        want = [np.interp(t_ref[k], t_ins, v_ins[:, axis]) - v_ref[r, k, axis]
                for k in (29, 30) for r in range(3 if k == 29 else 2)]
        np.testing.assert_allclose(list(sts[29].z) + list(sts[30].z), want, atol=1e-9)
    st = rig.diagnostics()
    vc = _values(st["filter_node: reference /ref/c"])
    assert vc["missing"] == "11" and vc["dropped_late"] == "10"
    assert _values(st["filter_node: inputs"])["dropped_reference_late"] == "10"
    assert _values(st["filter_node: reference /ref/a"])["missing"] == "0"


def test_time_jump_back_resets_once_for_all_references(ros):
    rig = Rig(ros)
    rig.feed(events(*flight(3.0, seed=24, jump=None)))
    n1 = len(rig.states)
    rig.feed(events(*flight(3.0, seed=25, jump=None, t0=T0 - 500.0)))  # a bag loop
    rig.outputs(n1 + 30)
    s = rig.states[n1:]
    assert len(s) == 30 and s[0].reset and not any(m.reset for m in s[1:])
    assert all(len(m.z) == 3 for m in s)  # every reference is on the new time line at once
    assert rig.node.counters["time_jump_resets"] == 1
    assert _stamps(s)[0] == pytest.approx(T0 - 500.0 + REF_OFFSET)


def test_one_topic_in_reference_topics_is_the_single_reference_filter(ros):
    from flight_fdi.core.kalman import run_forward
    from flight_fdi.core.models import ins_channel

    data = flight(4.0, seed=23, jump=None)
    t_ins, v_ins, t_ref, v_ref = data
    N = t_ref.size
    rig = Rig(ros, reference_topics=["/ref/a"])
    assert not rig.node.redundant and rig.node.ref_name == "/ref/a"
    rig.feed(events(t_ins, v_ins, t_ref, v_ref[:1]))
    innov, states = rig.outputs(N)
    z = np.interp(t_ref, t_ins, v_ins[:, 0]) - v_ref[0, :, 0]
    ref = run_forward(ins_channel(sigma_ref=SIGMA_REF), t_ref, z,
                      R=np.full((N, 1, 1), SIGMA_REF**2))
    np.testing.assert_allclose([m.beta2 for m in innov], ref.beta2, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(np.array([m.x for m in states]), ref.x, rtol=1e-7, atol=1e-12)
    for m in innov:
        assert list(m.row_names) == ["/ref/a"]
        assert list(m.row_failed) == [False] and list(m.row_excluded) == [False]
    st = rig.diagnostics()
    assert not any(name.startswith("filter_node: reference") for name in st)
    assert "accuracy_J" in _values(st["filter_node: channel x"])


@pytest.mark.parametrize("overrides, name", [
    ({"reference_topics": ["/ref/a", "/ins/velocity"]}, "reference_topics"),
    ({"reference_topics": ["/ref/a", "ref/a"]}, "reference_topics"),
    ({"reference_topics": ["/ref/a", "bad topic!"]}, "reference_topics"),
    ({"reference_mode": "vote"}, "reference_mode"),
    ({"anomaly_variance": 0.0}, "anomaly_variance"),
    ({"readmit_after_s": -1.0}, "readmit_after_s"),
    ({"reference_sync_wait_s": 2.0}, "reference_sync_wait_s"),
])
def test_invalid_reference_parameters_stop_the_node(ros, overrides, name):
    from flight_fdi.nodes.filter_node import FilterNode

    with pytest.raises(ParameterError) as err:
        ros.node(FilterNode, parameters=overrides)
    assert f"'{name}'" in str(err.value), str(err.value)
    assert repr(overrides[name]) in str(err.value)
