"""Redundant references in the streaming filter (core/references.py and the failed-row modes of
KalmanFilter.update): per-row failure identification, the three modes against FilterPy,
readmission, common-mode faults, the never-all-rows rule, and J = tr(D P).

Expected values come from FilterPy (the plain Kalman filter on the rows the mode says are used,
with R inflated by Gamma in known_anomaly mode), from the steady state of core/redundancy.py, from
closed forms, and from the identification rules re-stated here on FilterPy's own innovations.
"""
from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterPyKF
from scipy.stats import norm

from flight_fdi.core.errors import CoreError
from flight_fdi.core.kalman import ALARM_RAISED, GateConfig, KalmanFilter
from flight_fdi.core.models import ins_channel, model_from_dict
from flight_fdi.core.redundancy import steady_state_mode
from flight_fdi.core.references import (ReferenceConfig, ReferenceMonitor, RedundantFilter)

MODEL = ins_channel(sigma_ref=0.1)
DT = 0.1
VAR = 0.01                     # reference noise variance (sigma 0.1 m/s)
CHI2_1 = norm.isf(0.5e-3) ** 2  # one-row gate for p = 1e-3, from the normal quantile
GATE = GateConfig()             # alarm_m = 3 of alarm_n = 5


def scenario(simulate, seed, n_ref=4, bad=1, jump=2.0, onset_k=100, heal_k=250, steps=400):
    """z = V_INS - V_ref for n_ref references of one velocity error; reference ``bad`` reads
    ``jump`` m/s too much on samples [onset_k, heal_k)."""
    rng = np.random.default_rng(seed)
    t = np.arange(steps) * DT
    X = simulate(MODEL, t, rng)
    z = X[:, [0]] + rng.normal(0.0, math.sqrt(VAR), (steps, n_ref))
    z[onset_k:heal_k, bad] -= jump
    return t, z


def run_filter(t, z, config, names=None, present=None, model=MODEL):
    names = names or [f"ref{i}" for i in range(z.shape[1])]
    f = RedundantFilter(model, names, GATE, config)
    out = []
    for k in range(t.size):
        rows = None if present is None else present[k]
        zk = z[k] if rows is None else z[k, list(rows)]
        out.append((f.step(t[k], 0.0 if k == 0 else t[k] - t[k - 1], zk,
                           [VAR] * len(zk), rows),
                    f.x.copy(), f.P.copy()))
    return f, out


def filterpy_rows(t, z, rows_of, Rdiag_of, model=MODEL):
    """FilterPy over the rows ``rows_of(k)`` with variances ``Rdiag_of(k)``; also the prior
    per-row beta^2 of every row. Returns (x, P, prior_beta2)."""
    n = model.n
    kf = FilterPyKF(n, 1)
    kf.x = np.zeros((n, 1))
    kf.P = np.array(model.P0)
    h = np.array(model.H)[0]
    xs, Ps, b2 = [], [], []
    for k in range(t.size):
        if k:
            kf.F, kf.Q = model.discretize(t[k] - t[k - 1])[:2]
            kf.predict()
        S_diag = h @ kf.P @ h + VAR
        b2.append((z[k] - h @ kf.x[:, 0]) ** 2 / S_diag)
        rows = list(rows_of(k))
        if rows:
            kf.update(z[k, rows].reshape(-1, 1), R=np.diag(Rdiag_of(k)[rows]),
                      H=np.tile(h, (len(rows), 1)))
        xs.append(kf.x[:, 0].copy())
        Ps.append(kf.P.copy())
    return np.array(xs), np.array(Ps), np.array(b2)


def rel(a, b, scale):
    return float(np.max(np.abs(np.asarray(a) - np.asarray(b)) / scale))


# ------------------------------------------------------------------------------ identification

@pytest.mark.parametrize("mode", ["nominal", "known_anomaly", "exclude"])
def test_the_jumping_reference_is_identified_in_every_mode(simulate, mode):
    # 3 healthy references and one that jumps by 2 m/s: per-row beta^2 ~ 4 / 0.0125 ~ 320 on
    # every sample of the jump, far above the one-row gate 10.8, so the failure is declared at
    # the alarm_m-th sample (M of N = 3 of 5) -- in every mode, nominal included
    t, z = scenario(simulate, seed=11)
    f, out = run_filter(t, z, ReferenceConfig(mode=mode, anomaly_variance=4.0,
                                              readmit_after_s=1.0))
    failed = np.array([r.row_failed for r, _, _ in out])
    expected_k = 100 + GATE.alarm_m - 1
    assert not failed[:expected_k, 1].any() and failed[expected_k, 1]
    events = [(e.kind, e.name) for r, _, _ in out for e in r.events]
    assert events[0] == ("failed", "ref1")
    assert next(r for r, _, _ in out if r.events).events[0].t == pytest.approx(t[expected_k])
    for j in (0, 2, 3):  # the healthy references are never blamed
        assert not failed[:, j].any()
        assert f.monitor.refs[j].failures == 0
    assert f.monitor.refs[1].failures == 1
    excluded = np.array([r.row_excluded for r, _, _ in out])
    if mode == "nominal":
        assert not excluded.any()  # reported only
    else:
        # handled from its first wild sample (a suspect) on, while failed
        assert excluded[100:expected_k + 1, 1].all() and not excluded[:100, 1].any()
        assert excluded[:, [0, 2, 3]].sum() <= 2  # at most a stray noise sample


def test_exclude_mode_equals_filterpy_on_the_remaining_rows(simulate):
    readmit = 2.0
    t, z = scenario(simulate, seed=12)
    _, out = run_filter(t, z, ReferenceConfig(mode="exclude", readmit_after_s=readmit))
    excluded = np.array([r.row_excluded for r, _, _ in out])
    x_ref, P_ref, b2 = filterpy_rows(t, z, lambda k: np.flatnonzero(~excluded[k]),
                                     lambda k: np.full(4, VAR))
    s = MODEL.scale
    assert rel([x for _, x, _ in out], x_ref, s) < 1e-9
    assert rel([P for _, _, P in out], P_ref, np.outer(s, s)) < 1e-9
    # per-row beta^2 is the row's nu^2 / S_kk against the prediction -- also while excluded
    np.testing.assert_allclose([r.update.row_beta2 for r, _, _ in out], b2, rtol=1e-7)
    # the readmission rule on FilterPy's innovations: the first sample at which the row's own
    # gate has passed on every sample for readmit_after_s since the jump ended
    passing = b2[:, 1] <= CHI2_1
    assert passing[250:].mean() > 0.99
    start = None
    for k in range(250, t.size):
        start = (start if start is not None else k) if passing[k] else None
        if start is not None and t[k] - t[start] >= readmit - 1e-9:
            readmit_k = k
            break
    assert excluded[100:readmit_k, 1].all() and not excluded[readmit_k:, 1].any()
    assert [e.kind for r, _, _ in out for e in r.events] == ["failed", "readmitted"]
    # the rows used: beta^2 over them, with the threshold of their number
    for k in (50, 150):
        res = out[k][0]
        m_used = int((~excluded[k]).sum())
        assert res.update.threshold == pytest.approx(GATE.threshold(m_used))
        assert res.z_used.shape == (m_used,) and res.H_used.shape == (m_used, 4)
        np.testing.assert_array_equal(res.z_used, z[k, ~excluded[k]])


def test_known_anomaly_equals_filterpy_with_gamma_added_to_the_failed_row(simulate):
    gamma = 4.0
    t, z = scenario(simulate, seed=13)
    _, out = run_filter(t, z, ReferenceConfig(mode="known_anomaly", anomaly_variance=gamma,
                                              readmit_after_s=2.0))
    inflated = np.array([r.row_excluded for r, _, _ in out])
    assert inflated[100:200, 1].all()
    x_ref, P_ref, _ = filterpy_rows(t, z, lambda k: range(4),
                                    lambda k: VAR + gamma * inflated[k])
    s = MODEL.scale
    assert rel([x for _, x, _ in out], x_ref, s) < 1e-9
    assert rel([P for _, _, P in out], P_ref, np.outer(s, s)) < 1e-9
    res = out[150][0]
    np.testing.assert_allclose(np.diag(res.R_used), [VAR, VAR + gamma, VAR, VAR])
    assert res.z_used.shape == (4,)


def test_nominal_mode_equals_filterpy_on_every_row(simulate):
    t, z = scenario(simulate, seed=14, steps=200)
    _, out = run_filter(t, z, ReferenceConfig(mode="nominal"))
    x_ref, P_ref, _ = filterpy_rows(t, z, lambda k: range(4), lambda k: np.full(4, VAR))
    s = MODEL.scale
    assert rel([x for _, x, _ in out], x_ref, s) < 1e-9
    assert rel([P for _, _, P in out], P_ref, np.outer(s, s)) < 1e-9
    # the failure pulls the nominal estimate: the whole-sample gate fires, unlike in exclude mode
    assert sum(r.update.exceeded for r, _, _ in out[100:]) > 50


def test_exclude_keeps_the_whole_sample_gate_quiet(simulate):
    t, z = scenario(simulate, seed=15)
    _, out = run_filter(t, z, ReferenceConfig(mode="exclude"))
    assert sum(r.update.exceeded for r, _, _ in out) <= 2
    assert all(r.update.alarm_state != ALARM_RAISED for r, _, _ in out)


# ------------------------------------------------------------------------------ the rules

def test_common_mode_fault_blames_no_reference(simulate):
    # an INS fault (velocity ramp 0.2 m/s^2) shows in every row alike: the whole-sample alarm is
    # raised, no reference is declared failed
    t, z = scenario(simulate, seed=16, n_ref=3, jump=0.0, steps=300)
    z += 0.2 * np.clip(t - 15.0, 0.0, None)[:, None]
    f, out = run_filter(t, z, ReferenceConfig(mode="exclude"))
    assert any(r.update.alarm_state == ALARM_RAISED for r, _, _ in out)
    assert f.monitor.failed_references() == []
    assert all(ref.failures == 0 for ref in f.monitor.refs)
    # a row may stand out by noise for a sample (a suspect, excluded for that sample only)
    assert sum(int(r.row_excluded.sum()) for r, _, _ in out) <= 3


def test_two_references_disagreeing_without_a_witness_are_not_blamed(simulate):
    # +2 and -2 m/s: both rows exceed their gates, no row agrees with the prediction: the
    # failure cannot be isolated, so nothing is declared failed (never all rows)
    t, z = scenario(simulate, seed=17, n_ref=2, jump=2.0, bad=0, steps=150)
    z[100:, 1] += 2.0
    f, out = run_filter(t, z, ReferenceConfig(mode="exclude"))
    assert f.monitor.failed_references() == []
    assert not any(r.row_excluded.any() for r, _, _ in out)


def test_only_failed_rows_present_is_a_prediction_and_still_assessed(simulate):
    # ref1 fails (jump from sample 100), ref0 stays healthy but its samples stop at 200; from
    # then on every update carries ref1 alone: exclude mode predicts only; ref1 heals at 220 and
    # is readmitted after readmit_after_s of passing samples although it is alone
    readmit = 1.0
    t, z = scenario(simulate, seed=18, n_ref=2, bad=1, onset_k=100, heal_k=220, steps=300)
    present = [(0, 1) if k < 200 else (1,) for k in range(t.size)]
    f, out = run_filter(t, z, ReferenceConfig(mode="exclude", readmit_after_s=readmit),
                        present=present)
    for k in range(200, 220):
        res = out[k][0]
        assert res.present == (1,) and res.row_failed[0] and res.row_excluded[0]
        assert not res.update.fused and res.update.rows_used == ()
        assert math.isnan(res.update.threshold) and res.z_used.size == 0
    # predict-only: x, P follow the model from the last fused step
    Phi, Qd, _ = MODEL.discretize(DT)
    x, P = out[199][1], out[199][2]
    for k in range(200, 220):
        x, P = Phi @ x, Phi @ P @ Phi.T + Qd
    s = MODEL.scale
    assert rel(out[219][1], x, s) < 1e-10 and rel(out[219][2], P, np.outer(s, s)) < 1e-10
    kinds = [(e.kind, round(e.t, 6)) for r, _, _ in out for e in r.events]
    assert kinds[0] == ("failed", round(t[102], 6))
    # readmitted at the first sample >= readmit_after_s after the healing (gate passing since:
    # the predicted state is still good, the row's beta^2 is checked below)
    b2 = np.array([out[k][0].update.row_beta2[0] for k in range(220, 231)])
    assert np.all(b2 <= CHI2_1)
    assert kinds[1] == ("readmitted", round(t[230], 6))
    assert out[231][0].update.fused and out[231][0].update.rows_used is None


def test_monitor_persistence_and_readmission_streak():
    # two references, nu scripted: row 0 always 0; row 1 wild (5 sigma-ish) or quiet
    mon = ReferenceMonitor(["a", "b"], GateConfig(alarm_m=2, alarm_n=3),
                           ReferenceConfig(mode="exclude", readmit_after_s=0.25))
    S = np.diag([0.01, 0.01])
    wild, quiet = np.array([0.0, 1.0]), np.array([0.0, 0.0])
    seq = [quiet, wild, quiet, wild, quiet, quiet, wild, quiet, quiet, quiet, quiet]
    verdicts = [mon.assess(0.1 * k, (0, 1), nu, S) for k, nu in enumerate(seq)]
    failed = [bool(v.failed[1]) for v in verdicts]
    # 2 of the last 3 attributed: declared at k = 3; readmission needs 0.25 s of passing samples:
    # k = 4, 5 pass (0.1 s), k = 6 exceeds (streak restarts), k = 7..9 pass: readmitted at k = 10
    # (0.3 s after k = 7; at k = 9, 0.2 s is not enough)
    assert failed == [False, False, False, True, True, True, True, True, True, True, False]
    assert [bool(v.handled[1]) for v in verdicts] == [False, True, False] + [True] * 7 + [False]
    assert [e.kind for v in verdicts for e in v.events] == ["failed", "readmitted"]
    assert verdicts[10].events[0].t == pytest.approx(1.0)
    ref = mon.refs[1]
    assert (ref.failures, ref.readmissions, ref.attributed) == (1, 1, 2)
    assert verdicts[1].row_beta2[1] == pytest.approx(100.0)
    with pytest.raises(CoreError, match="older"):
        mon.assess(0.5, (0, 1), quiet, S)
    mon.reset()
    assert mon.failed_references() == [] and mon.refs[1].failures == 1


def test_gamma_inflation_and_exclusion_in_the_kalman_update_match_plain_updates():
    # KalmanFilter.update with failed rows == a plain update with R inflated / rows removed
    model = MODEL
    H = np.tile(np.array(model.H), (3, 1))
    z = np.array([0.05, 1.9, -0.02])
    R = np.diag([VAR, 0.02, VAR])
    for mode in ("known_anomaly", "exclude"):
        a, b = KalmanFilter(model), KalmanFilter(model)
        a.predict(0.1)
        b.predict(0.1)
        ra = a.update(z, R, H, failed_rows=[1], mode=mode, Gamma=3.0)
        if mode == "known_anomaly":
            rb = b.update(z, R + np.diag([0.0, 3.0, 0.0]), H)
            np.testing.assert_allclose(ra.R_used, R + np.diag([0.0, 3.0, 0.0]))
            assert ra.rows_used == (0, 1, 2)
        else:
            rb = b.update(z[[0, 2]], R[np.ix_([0, 2], [0, 2])], H[[0, 2]])
            assert ra.rows_used == (0, 2)
        s = model.scale
        assert rel(a.x, b.x, s) < 1e-12 and rel(a.P, b.P, np.outer(s, s)) < 1e-12
        assert ra.beta2 == pytest.approx(rb.beta2, rel=1e-10)
        assert ra.threshold == rb.threshold
        # nu, S and row_beta2 stay the nominal ones of all rows
        c = KalmanFilter(model)
        c.predict(0.1)
        nu, S = c.innovation(z, R, H)
        np.testing.assert_allclose(ra.nu, nu, rtol=1e-12)
        np.testing.assert_allclose(ra.S, S, rtol=1e-12)
        np.testing.assert_allclose(ra.row_beta2, nu**2 / np.diag(S), rtol=1e-12)
    # no failed rows (or nominal mode): the plain update, to the bit
    a, b = KalmanFilter(model), KalmanFilter(model)
    ra = a.update(z, R, H, failed_rows=(), mode="exclude")
    rb = b.update(z, R, H, failed_rows=[1], mode="nominal")
    assert np.array_equal(a.x, b.x) and np.array_equal(a.P, b.P) and ra.beta2 == rb.beta2
    assert ra.rows_used is None and ra.R_used is None


# ------------------------------------------------------------------------------ J = tr(D P)

def _fast_model():
    """A two-state model that reaches its steady state within a few hundred 0.1-s steps."""
    return model_from_dict({
        "name": "fast", "states": [{"name": "v", "unit": "m/s"}, {"name": "a", "unit": "m/s^2"}],
        "A": [[0.0, 1.0], [0.0, -0.5]], "Qc": [[0.0, 0.0], [0.0, 0.02]],
        "H": [[1.0, 0.0]], "R": [[VAR]], "P0": [[1.0, 0.0], [0.0, 0.1]]})


def test_accuracy_converges_to_the_steady_state_of_each_mode():
    # one reference (row 1) wild from sample 50 to the end: the streaming filter's P converges
    # to the steady state of core/redundancy.py for that mode, and J_nominal < J_KF2 < J_AF
    model = _fast_model()
    D = np.diag([1.0, 4.0])
    gamma = 4.0
    t = np.arange(600) * DT
    rng = np.random.default_rng(19)
    z = rng.normal(0.0, math.sqrt(VAR), (t.size, 3))
    z[50:, 1] += 3.0
    Phi, Qd, _ = model.discretize(DT)
    H3, R3 = np.tile(model.H, (3, 1)), np.eye(3) * VAR
    J = {}
    for mode, ss_mode in (("known_anomaly", "kf2"), ("exclude", "af")):
        f, out = run_filter(t, z, ReferenceConfig(mode=mode, anomaly_variance=gamma),
                            model=model)
        assert all(r.row_excluded[1] for r, _, _ in out[50:])
        ss = steady_state_mode(Phi, Qd, H3, R3, ss_mode, [1], [gamma] * 3, model.scale)
        np.testing.assert_allclose(f.P, ss.P, rtol=1e-9)
        J[mode] = f.accuracy(D)
        assert J[mode] == pytest.approx(np.trace(D @ ss.P), rel=1e-9)
    ss0 = steady_state_mode(Phi, Qd, H3, R3, "af", [], None, model.scale)
    J0 = float(np.trace(D @ ss0.P))
    assert J0 < J["known_anomaly"] < J["exclude"]
    # D defaults to the identity on the scaled states: J = sum P_ii / scale_i^2
    kf = KalmanFilter(MODEL)
    assert kf.accuracy() == pytest.approx(float(np.sum(np.diag(MODEL.P0) / MODEL.scale**2)))


# ------------------------------------------------------------------------------ bad input

def test_bad_configuration_and_input_raise_core_errors():
    with pytest.raises(CoreError, match="mode"):
        ReferenceConfig(mode="vote")
    with pytest.raises(CoreError, match="anomaly_variance"):
        ReferenceConfig(anomaly_variance=0.0)
    with pytest.raises(CoreError, match="readmit_after_s"):
        ReferenceConfig(readmit_after_s=-1.0)
    with pytest.raises(CoreError, match="unique"):
        ReferenceMonitor(["a", "a"])
    with pytest.raises(CoreError, match="one measurement row|m = 1"):
        RedundantFilter(model_from_dict({
            "name": "two", "states": [{"name": "v"}], "A": [[0.0]], "Qc": [[1.0]],
            "H": [[1.0], [1.0]], "R": [[1.0, 0.0], [0.0, 1.0]], "P0": [[1.0]]}), ["a"])
    f = RedundantFilter(MODEL, ["a", "b"])
    x, P = f.x, f.P
    for args, match in [((0.0, 0.1, [0.0, 0.0], [VAR, VAR], (1, 0)), "increasing"),
                        ((0.0, 0.1, [0.0, 0.0], [VAR, VAR], (0, 2)), "increasing"),
                        ((0.0, 0.1, [0.0, math.nan], [VAR, VAR], None), "NaN"),
                        ((0.0, 0.1, [0.0], [VAR], None), "2 values"),
                        ((0.0, -0.1, [0.0, 0.0], [VAR, VAR], None), "dt")]:
        with pytest.raises(CoreError, match=match):
            f.step(*args)
        assert np.array_equal(f.x, x) and np.array_equal(f.P, P)  # unchanged
    kf = KalmanFilter(MODEL)
    H = np.tile(np.array(MODEL.H), (2, 1))
    with pytest.raises(CoreError, match="row index"):
        kf.update([0.0, 0.0], np.eye(2) * VAR, H, failed_rows=[2], mode="exclude")
    with pytest.raises(CoreError, match="Gamma"):
        kf.update([0.0, 0.0], np.eye(2) * VAR, H, failed_rows=[1], mode="known_anomaly")
    with pytest.raises(CoreError, match="update mode"):
        kf.update([0.0, 0.0], np.eye(2) * VAR, H, failed_rows=[1], mode="af")
