"""Forward Kalman filter: agreement with FilterPy, streaming == batch, gate calibration, bad
input."""
from __future__ import annotations

import math

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterPyKF
from scipy.stats import chi2

from flight_fdi.core import kalman, multirow
from flight_fdi.core.errors import CoreError
from flight_fdi.core.kalman import (ALARM_ACTIVE, ALARM_CLEAR, ALARM_CLEARED, ALARM_RAISED,
                                    AlarmLogic, ForwardResult, GateConfig, KalmanFilter,
                                    alarm_states, run_forward)
from flight_fdi.core.models import attitude_axis, ins_channel


def filterpy_run(model, dt, z, R, u=None):
    """FilterPy's KalmanFilter with the model's own discretization; first step update only."""
    n, m = model.n, model.m
    kf = FilterPyKF(n, m, 0 if u is None else u.shape[1])
    kf.x = np.zeros((n, 1))
    kf.P = np.array(model.P0)
    kf.H = np.array(model.H)
    xs, Ps, nus, Ss = [], [], [], []
    for k in range(len(z)):
        if k:
            Phi, Qd, Bd = model.discretize(dt[k])
            kf.F, kf.Q = Phi, Qd
            if u is None:
                kf.predict()
            else:
                kf.predict(u=u[k].reshape(-1, 1), B=Bd)
        kf.update(z[k].reshape(m, 1), R=R[k])
        xs.append(kf.x.ravel().copy())
        Ps.append(kf.P.copy())
        nus.append(kf.y.ravel().copy())
        Ss.append(kf.S.copy())
    return np.array(xs), np.array(Ps), np.array(nus), np.array(Ss)


def rel(a, b, scale):
    return np.max(np.abs(a - b) / scale)


# --------------------------------------------------------------------------- gate


def test_gate_thresholds_match_closed_forms():
    for m in (1, 2, 3):
        assert GateConfig(rule="chi2", probability=0.01).threshold(m) == pytest.approx(
            chi2.ppf(0.99, m), rel=1e-10)
        assert GateConfig(rule="seed").threshold(m) == pytest.approx(m + 3 * math.sqrt(2 * m))
    assert GateConfig(rule="seed").threshold(1) == pytest.approx(5.242640687)
    assert GateConfig(rule="seed").threshold(2) == pytest.approx(8.0)


@pytest.mark.parametrize("kwargs, field", [
    ({"rule": "sigma"}, "rule"), ({"probability": 0.0}, "probability"),
    ({"probability": 1.0}, "probability"), ({"probability": float("nan")}, "probability"),
    ({"alarm_m": 0}, "alarm_m"), ({"alarm_m": 2.5}, "alarm_m"),
    ({"alarm_m": 4, "alarm_n": 3}, "alarm_n"), ({"action": "drop"}, "action"),
])
def test_gate_config_validation_names_the_field(kwargs, field):
    with pytest.raises(CoreError, match=f"GateConfig.{field}"):
        GateConfig(**kwargs)


def test_alarm_logic_m_of_n_by_hand():
    logic = AlarmLogic(3, 5)
    seq = [1, 1, 1, 0, 0, 0, 0, 1, 0, 1, 0, 1]
    # window counts after each sample: 1 2 3 3 3 2 1 1 1 2 2 3
    expected = [ALARM_CLEAR, ALARM_CLEAR, ALARM_RAISED, ALARM_ACTIVE, ALARM_ACTIVE,
                ALARM_CLEARED, ALARM_CLEAR, ALARM_CLEAR, ALARM_CLEAR, ALARM_CLEAR, ALARM_CLEAR,
                ALARM_RAISED]
    assert [logic.push(bool(e)) for e in seq] == expected
    np.testing.assert_array_equal(alarm_states(np.array(seq, bool), GateConfig()), expected)


def test_vectorised_alarm_states_equal_streaming_logic():
    rng = np.random.default_rng(3)
    for m_of, n_of in ((1, 1), (2, 3), (3, 5), (4, 10)):
        exc = rng.random(3000) < 0.3
        logic = AlarmLogic(m_of, n_of)
        stream = [logic.push(e) for e in exc]
        gate = GateConfig(alarm_m=m_of, alarm_n=n_of)
        np.testing.assert_array_equal(alarm_states(exc, gate), stream)


# --------------------------------------------------------------------------- vs FilterPy


def test_forward_equals_filterpy_ins_variable_dt_and_R():
    model = ins_channel()
    rng = np.random.default_rng(1)
    N = 1500
    t = np.cumsum(rng.uniform(0.05, 0.15, N))
    z = rng.normal(0, 0.1, N) + np.linspace(0, 0.5, N)
    R = rng.uniform(0.005, 0.02, N).reshape(N, 1, 1)
    fwd = run_forward(model, t, z, R)
    xs, Ps, nus, Ss = filterpy_run(model, fwd.dt, z.reshape(N, 1), R)
    s = model.scale
    assert rel(fwd.x, xs, s) < 1e-9
    assert rel(fwd.P, Ps, np.outer(s, s)) < 1e-9
    assert np.max(np.abs(fwd.nu - nus)) < 1e-9 * 0.1
    np.testing.assert_allclose(fwd.S, Ss, rtol=1e-9)
    np.testing.assert_allclose(fwd.beta2, (nus[:, 0] ** 2 / Ss[:, 0, 0]), rtol=1e-8)
    assert fwd.dt[0] == 0.0 and np.all(fwd.dt[1:] == np.diff(t))


def test_forward_equals_filterpy_two_rows_with_control():
    model = attitude_axis(sigma_rate=1e-3)
    rng = np.random.default_rng(2)
    N = 400
    t = np.arange(N) * 0.1
    z = rng.normal(0, 1e-3, (N, 2)) + np.linspace(0, 0.02, N)[:, None]
    u = rng.normal(0, 1, (N, 1))
    R = np.broadcast_to(model.R, (N, 2, 2))
    fwd = run_forward(model, t, z, u=u)
    xs, Ps, nus, Ss = filterpy_run(model, fwd.dt, z, R, u)
    s = model.scale
    assert rel(fwd.x, xs, s) < 1e-9
    assert rel(fwd.P, Ps, np.outer(s, s)) < 1e-9
    np.testing.assert_allclose(fwd.S, Ss, rtol=1e-9)
    beta2 = np.einsum("ki,kij,kj->k", nus, np.linalg.inv(Ss), nus)
    np.testing.assert_allclose(fwd.beta2, beta2, rtol=1e-8)


def test_kernel_one_row_update_equals_numpy_update():
    """The compiled m = 1 update (filter_kernel.update) and the numpy update (any m) are the
    same equations."""
    from flight_fdi.core import filter_kernel as fk

    model = ins_channel()
    sm = kalman.scaled_model(model)
    rng = np.random.default_rng(4)
    for _ in range(20):
        A = rng.normal(size=(4, 4))
        P = A @ A.T + 0.1 * np.eye(4)
        x = rng.normal(size=4)
        z, r = float(rng.normal()), float(rng.uniform(0.5, 2.0)) * 0.01
        x1, P1, K1 = np.empty(4), np.empty((4, 4)), np.empty(4)
        status, nu, S, beta2, _, fused = fk.update(x, P, np.ascontiguousarray(sm.H[0]), r, z,
                                                   10.0, False, x1, P1, K1,
                                                   np.empty((3, 4, 4)))
        out2 = multirow.update_rows(x, P, np.array([z]), np.array([[r]]), sm.H, sm.HT, sm.I, 10.0,
                              False)
        assert status == fk.OK
        np.testing.assert_allclose(x1, out2[0], rtol=1e-13, atol=1e-15)
        np.testing.assert_allclose(P1, out2[1], rtol=1e-12, atol=1e-15)
        np.testing.assert_allclose(K1, out2[4][:, 0], rtol=1e-13, atol=1e-15)
        assert beta2 == pytest.approx(out2[5], rel=1e-13) and nu == pytest.approx(out2[2][0])


# --------------------------------------------------------------------------- streaming == batch


@pytest.mark.parametrize("which", ["ins", "attitude_u", "attitude_2rows"])
def test_streaming_equals_batch(which):
    rng = np.random.default_rng(5)
    N = 300
    if which == "ins":
        model, u = ins_channel(), None
        z = rng.normal(0, 0.1, (N, 1))
    elif which == "attitude_u":
        model, u = attitude_axis(), rng.normal(0, 1, (N, 1))
        z = rng.normal(0, 1e-4, (N, 1))
    else:
        model, u = attitude_axis(sigma_rate=1e-3), rng.normal(0, 1, (N, 1))
        z = rng.normal(0, 1e-3, (N, 2))
    t = np.cumsum(rng.uniform(0.05, 0.2, N))
    R = np.broadcast_to(model.R, (N, model.m, model.m)) * rng.uniform(0.5, 2.0, (N, 1, 1))
    gate = GateConfig(probability=0.05, action="reject")
    fwd = run_forward(model, t, z, R, u=u, gate=gate)
    kf = KalmanFilter(model, gate)
    kf2 = KalmanFilter(model, gate)  # predict() and update() as separate calls
    for k in range(N):
        if k:
            res = kf.step(fwd.dt[k], z[k], R[k], None if u is None else u[k])
            kf2.predict(fwd.dt[k], None if u is None else u[k])
        else:
            res = kf.update(z[k], R[k])
        res2 = kf2.update(z[k], R[k])
        np.testing.assert_allclose(kf2.x, kf.x, rtol=1e-12, atol=1e-12 * model.scale.min())
        np.testing.assert_allclose(kf2.P, kf.P, rtol=1e-12, atol=0)
        assert res2.beta2 == pytest.approx(res.beta2, rel=1e-12)
        np.testing.assert_allclose(kf.x, fwd.x[k], rtol=1e-12, atol=1e-12 * model.scale.min())
        np.testing.assert_allclose(kf.P, fwd.P[k], rtol=1e-12, atol=0)
        assert res.beta2 == pytest.approx(fwd.beta2[k], rel=1e-12)
        assert res.exceeded == fwd.exceeded[k] and res.fused == fwd.fused[k]
        assert res.alarm_state == fwd.alarm_state[k]
        np.testing.assert_allclose(res.nu, fwd.nu[k], rtol=1e-12)
        np.testing.assert_allclose(res.S, fwd.S[k], rtol=1e-12)
    assert not fwd.fused.all()  # the reject path was exercised


@pytest.mark.parametrize("dt_kind", ["constant", "jittered"])
@pytest.mark.parametrize("with_u", [False, True])
def test_batch_kernel_is_bit_identical_to_the_streaming_step(dt_kind, with_u):
    """run_forward's compiled loop over the record and KalmanFilter.step (what the filter node
    calls per message) run the same kernel step: the same bits, including the rejected samples,
    on regular and on jittered stamps."""
    rng = np.random.default_rng(15)
    N = 400
    model = attitude_axis() if with_u else ins_channel()
    u = rng.normal(0, 1, (N, 1)) if with_u else None
    z = rng.normal(0, 1e-4 if with_u else 0.1, (N, 1))
    z[::37] *= 40.0  # gated samples, rejected
    t = np.arange(N) * 0.1 if dt_kind == "constant" else np.cumsum(0.1 + rng.normal(0, 1e-3, N))
    R = np.broadcast_to(model.R, (N, 1, 1)) * rng.uniform(0.5, 2.0, (N, 1, 1))
    gate = GateConfig(probability=0.01, action="reject")
    fwd = run_forward(model, t, z, R, u=u, gate=gate)
    kf = KalmanFilter(model, gate)
    for k in range(N):
        res = (kf.step(fwd.dt[k], z[k], R[k], None if u is None else u[k]) if k
               else kf.update(z[k], R[k]))
        assert np.array_equal(kf.x, fwd.x[k]) and np.array_equal(kf.P, fwd.P[k]), k
        assert res.beta2 == fwd.beta2[k] and res.fused == fwd.fused[k]
        assert np.array_equal(res.nu, fwd.nu[k]) and np.array_equal(res.S, fwd.S[k])
    assert 0 < (~fwd.fused).sum() < N
    one = run_forward(model, t[:1], z[:1], R[:1], u=None if u is None else u[:1], gate=gate)
    assert np.array_equal(one.x[0], fwd.x[0]) and one.K.shape == (1, model.n, 1)


# --------------------------------------------------------------------------- calibration


def test_beta2_calibrated_on_nominal_data(simulate):
    """On data from the model itself beta^2 ~ chi2(1): mean 1 and gate exceedances binomial."""
    model = ins_channel()
    rng = np.random.default_rng(11)
    N = 20000
    t = np.arange(N) * 0.1
    X = simulate(model, t, rng)
    z = X[:, 0] + rng.normal(0, 0.1, N)
    p = 0.01
    fwd = run_forward(model, t, z, gate=GateConfig(probability=p))
    assert abs(fwd.beta2.mean() - 1.0) < 4 * math.sqrt(2.0 / N)
    count = int(fwd.exceeded.sum())
    assert abs(count - p * N) < 4 * math.sqrt(N * p * (1 - p))
    assert np.all(fwd.threshold == pytest.approx(chi2.isf(p, 1)))
    # covariance stays symmetric and positive semidefinite in scaled coordinates
    Ps = fwd.P / np.outer(model.scale, model.scale)
    assert np.array_equal(Ps, np.swapaxes(Ps, 1, 2))
    assert np.linalg.eigvalsh(Ps).min() > -1e-12


# --------------------------------------------------------------------------- gate actions, alarms


def test_reject_action_does_not_fuse_a_gated_sample():
    model = ins_channel()
    rng = np.random.default_rng(6)
    N = 200
    t = np.arange(N) * 0.1
    z = rng.normal(0, 0.1, N)
    z[120] = 5.0  # 50 sigma
    flag = run_forward(model, t, z)
    rej = run_forward(model, t, z, gate=GateConfig(action="reject"))
    assert flag.fused.all() and flag.exceeded[120]
    assert not rej.fused[120] and rej.fused.sum() == N - 1
    np.testing.assert_array_equal(rej.x[120], rej.x_prior[120])
    np.testing.assert_array_equal(rej.P[120], rej.P_prior[120])
    assert np.all(rej.K[120] == 0)
    # the flagged sample moved x by K nu
    np.testing.assert_allclose(flag.x[120] - flag.x_prior[120], flag.K[120] @ flag.nu[120],
                               rtol=1e-10)
    assert abs(flag.x[120, 0] - flag.x_prior[120, 0]) > 0.05


def test_alarms_start_and_end_at_the_raising_and_clearing_updates():
    model = ins_channel()
    rng = np.random.default_rng(7)
    N = 300
    t = 1000.0 + np.arange(N) * 0.1
    z = rng.normal(0, 0.1, N)
    z[100:110] += 3.0  # ten 30-sigma samples
    fwd = run_forward(model, t, z, gate=GateConfig(alarm_m=3, alarm_n=5))
    alarms = fwd.alarms()
    assert len(alarms) >= 1
    first = alarms[0]
    raised = int(np.flatnonzero(fwd.alarm_state == ALARM_RAISED)[0])
    cleared = int(np.flatnonzero(fwd.alarm_state == ALARM_CLEARED)[0])
    assert first["start_s"] == t[raised] and first["end_s"] == t[cleared]
    assert raised == 102  # third exceeding sample
    assert first["peak_beta2"] == pytest.approx(fwd.beta2[raised:cleared + 1].max())


# --------------------------------------------------------------------------- from_record


def test_from_record_rebuilds_the_forward_result():
    model = attitude_axis()
    rng = np.random.default_rng(8)
    N = 200
    t = np.cumsum(rng.uniform(0.05, 0.2, N))
    u = rng.normal(0, 1, (N, 1))
    z = rng.normal(0, 1e-4, (N, 1))
    z[50] += 0.01
    gate = GateConfig(action="reject")
    fwd = run_forward(model, t, z, u=u, gate=gate)
    rec = ForwardResult.from_record(model, fwd.t, fwd.dt, fwd.z, fwd.R, fwd.H, fwd.fused, fwd.u,
                                    fwd.x, fwd.P, gate=gate)
    s = model.scale
    assert rel(rec.x_prior, fwd.x_prior, s) < 1e-10
    assert rel(rec.P_prior, fwd.P_prior, np.outer(s, s)) < 1e-10
    np.testing.assert_allclose(rec.nu, fwd.nu, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rec.S, fwd.S, rtol=1e-10)
    np.testing.assert_allclose(rec.K, fwd.K, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(rec.beta2, fwd.beta2, rtol=1e-7)
    np.testing.assert_array_equal(rec.alarm_state, fwd.alarm_state)


# --------------------------------------------------------------------------- bad input


def test_batch_bad_input_raises():
    model = ins_channel()
    t = np.arange(10) * 0.1
    z = np.zeros(10)
    zn = z.copy()
    zn[3] = np.nan
    with pytest.raises(CoreError, match="z contains NaN"):
        run_forward(model, t, zn)
    with pytest.raises(CoreError, match="strictly increasing"):
        run_forward(model, np.r_[t[:5], t[4], t[6:]], z)
    with pytest.raises(CoreError, match="t contains NaN"):
        run_forward(model, np.r_[t[:9], np.nan], z)
    R = np.full((10, 1, 1), 0.01)
    R[2] = -0.01
    with pytest.raises(CoreError, match="negative"):
        run_forward(model, t, z, R)
    R[2] = np.nan
    with pytest.raises(CoreError, match="R contains NaN"):
        run_forward(model, t, z, R)
    with pytest.raises(CoreError, match="shape"):
        run_forward(model, t, np.zeros(9))
    with pytest.raises(CoreError, match="no input matrix B"):
        run_forward(model, t, z, u=np.zeros((10, 1)))
    two = attitude_axis(sigma_rate=1e-3)
    Rb = np.broadcast_to(np.array([[1.0, 2.0], [2.0, 1.0]]), (10, 2, 2))  # eigenvalue -1
    with pytest.raises(CoreError, match="positive semidefinite"):
        run_forward(two, t, np.zeros((10, 2)), Rb)


def test_streaming_bad_input_raises_and_leaves_the_filter_unchanged():
    model = ins_channel()
    kf = KalmanFilter(model)
    kf.update(0.05)
    kf.step(0.1, 0.02)
    x, P, steps = kf.x, kf.P, kf.steps
    for call in (lambda: kf.update(float("nan")), lambda: kf.update(0.1, R=float("inf")),
                 lambda: kf.update(0.1, R=-1.0), lambda: kf.predict(-0.1),
                 lambda: kf.predict(float("nan")), lambda: kf.step(float("inf"), 0.1),
                 lambda: kf.step(0.1, float("nan")), lambda: kf.update([0.1, 0.2]),
                 lambda: kf.predict(0.1, u=[1.0])):
        with pytest.raises(CoreError):
            call()
        np.testing.assert_array_equal(kf.x, x)
        np.testing.assert_array_equal(kf.P, P)
        assert kf.steps == steps
    kf.reset()
    np.testing.assert_array_equal(kf.P, model.P0)
    assert not kf.alarm_active


def test_step1_on_plain_numbers_equals_step_and_validates():
    from flight_fdi.core.errors import CoreError
    from flight_fdi.core.kalman import GateConfig, KalmanFilter
    from flight_fdi.core.models import attitude_axis, ins_channel

    rng = np.random.default_rng(21)
    model = ins_channel()
    gate = GateConfig(action="reject")
    a, b = KalmanFilter(model, gate), KalmanFilter(model, gate)
    for k in range(300):
        dt = 0.0 if k == 0 else float(rng.uniform(0.05, 0.15))
        z = float(rng.normal(0.0, 0.1)) + (5.0 if k % 50 == 49 else 0.0)  # some gated
        r = float(rng.uniform(0.005, 0.02))
        ra, rb = a.step(dt, [z], [[r]]), b.step1(dt, z, r)
        assert (ra.beta2, ra.exceeded, ra.fused, ra.alarm_state) == \
            (rb.beta2, rb.exceeded, rb.fused, rb.alarm_state)
        np.testing.assert_array_equal(ra.nu, rb.nu)
        np.testing.assert_array_equal(ra.S, rb.S)
    np.testing.assert_array_equal(a.x, b.x)
    np.testing.assert_array_equal(a.P, b.P)
    xl, Pl = b.state_lists()  # the node's plain-list view: the same numbers
    assert xl == b.x.tolist() and Pl == b.P.ravel().tolist()
    x_before = b.x
    for args, match in [((0.1, float("nan"), 0.01), "NaN or Inf"),
                        ((0.1, 0.0, float("inf")), "NaN or Inf"),
                        ((0.1, 0.0, -1.0), "negative"), ((-0.1, 0.0, 0.01), "dt must be >= 0"),
                        ((0.1, "a", 0.01), "must be numbers")]:
        with pytest.raises(CoreError, match=match):
            b.step1(*args)
    np.testing.assert_array_equal(b.x, x_before)
    two_rows = attitude_axis(sigma_rate=1e-3)
    assert two_rows.m == 2
    with pytest.raises(CoreError, match="one-row model"):
        KalmanFilter(two_rows).step1(0.1, 0.0, 0.01)
