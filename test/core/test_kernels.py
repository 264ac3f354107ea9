"""The compiled kernels against independent implementations, on regular stamps and on stamps with
1 ms Gaussian jitter (every dt distinct): the forward filter with its gate and rejection against
FilterPy's KalmanFilter, the backward information filter and two-filter combination against
FilterPy's RTS smoother and pykalman's smoother, each to 1e-9 of the state's scale. The
baselines' Phi and Qd come from scipy.linalg.expm (Van Loan), not from the code under test."""
from __future__ import annotations

from functools import lru_cache

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterPyKF
from scipy.linalg import expm

from flight_fdi.core.kalman import GateConfig, KalmanFilter, run_forward
from flight_fdi.core.models import attitude_axis, ins_channel
from flight_fdi.core.smoother import run_backward


def scipy_discretize(model, dt):
    n = model.n
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -model.A, model.Qc, model.A.T
    E = expm(M * dt)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    return Phi, 0.5 * (Qd + Qd.T)


def stamps(kind, N):
    t = np.arange(N) * 0.1
    return t if kind == "regular" else t + np.random.default_rng(0).normal(0.0, 1e-3, N)


@lru_cache(maxsize=None)
def reference_steps(kind, N=600):
    """scipy's Phi, Qd of every step of the stamps of ``kind`` on the INS channel (computed once
    for the tests that share them: one expm per jittered step)."""
    model = ins_channel()
    done = {}
    return [done.setdefault(d, scipy_discretize(model, d) if d not in done else None)
            for d in np.diff(stamps(kind, N)).tolist()]


def filterpy_with_gate(model, kind, t, z, R, threshold, reject):
    """FilterPy's predict/update with the beta^2 gate done by hand: a gated sample is not fused
    when ``reject``. Returns x, P, beta2, fused per step."""
    n = model.n
    kf = FilterPyKF(n, 1)
    kf.x, kf.P, kf.H = np.zeros((n, 1)), np.array(model.P0), np.array(model.H)
    xs, Ps, b2, fused = [], [], [], []
    for k in range(len(t)):
        if k:
            kf.F, kf.Q = reference_steps(kind)[k - 1]
            kf.predict()
        nu = z[k] - (kf.H @ kf.x).item()
        S = (kf.H @ kf.P @ kf.H.T).item() + R[k]
        b2.append(nu * nu / S)
        fused.append(not (reject and b2[-1] > threshold))
        if fused[-1]:
            kf.update(np.array([[z[k]]]), R=np.array([[R[k]]]))
        xs.append(kf.x.ravel().copy())
        Ps.append(kf.P.copy())
    return np.array(xs), np.array(Ps), np.array(b2), np.array(fused)


def flight(model, kind, N=600, seed=2):
    rng = np.random.default_rng(seed)
    t = stamps(kind, N)
    z = rng.normal(0.0, np.sqrt(model.R[0, 0]), N) + 0.2 * np.sin(t / 20.0)
    z[200::37] += 3.0  # outliers: gated, and rejected with action "reject"
    R = model.R[0, 0] * rng.uniform(0.5, 2.0, N)
    return t, z, R


@pytest.mark.parametrize("kind", ["regular", "jittered"])
@pytest.mark.parametrize("action", ["flag", "reject"])
def test_forward_kernel_equals_filterpy_with_gate_and_rejection(kind, action):
    model = ins_channel()
    t, z, R = flight(model, kind)
    gate = GateConfig(probability=1e-3, action=action)
    fwd = run_forward(model, t, z, R.reshape(-1, 1, 1), gate=gate)
    x, P, b2, fused = filterpy_with_gate(model, kind, t, z, R, gate.threshold(1),
                                         action == "reject")
    s = model.scale
    assert np.max(np.abs(fwd.x - x) / s) < 1e-9
    assert np.max(np.abs(fwd.P - P) / np.outer(s, s)) < 1e-9
    np.testing.assert_allclose(fwd.beta2, b2, rtol=1e-8)
    np.testing.assert_array_equal(fwd.fused, fused)
    assert fwd.exceeded.sum() >= 8
    assert (~fwd.fused).sum() == (fwd.exceeded.sum() if action == "reject" else 0)
    # the node's streaming step is the same kernel: the same bits
    kf = KalmanFilter(model, gate)
    for k in range(len(t)):
        res = kf.step1(fwd.dt[k], z[k], R[k])
        assert res.beta2 == fwd.beta2[k] and res.fused == fwd.fused[k]
    assert np.array_equal(kf.x, fwd.x[-1]) and np.array_equal(kf.P, fwd.P[-1])


def rts_reference(model, kind, z, R, fused):
    """FilterPy's batch_filter (z None where not fused: no update) and rts_smoother."""
    n = model.n
    disc = reference_steps(kind)
    Fs = [np.eye(n)] + [d[0] for d in disc]
    Qs = [np.zeros((n, n))] + [d[1] for d in disc]
    kf = FilterPyKF(n, 1)
    kf.x, kf.P, kf.H = np.zeros(n), np.array(model.P0), np.array(model.H)
    zs = [zk if f else None for zk, f in zip(z, fused)]
    mu, cov, _, _ = kf.batch_filter(zs, Fs=Fs, Qs=Qs, Rs=[np.array([[r]]) for r in R])
    xs, Ps, _, _ = kf.rts_smoother(mu, cov, Fs=Fs, Qs=Qs)
    return xs, Ps, Fs, Qs


@pytest.mark.parametrize("kind", ["regular", "jittered"])
@pytest.mark.parametrize("action", ["flag", "reject"])
def test_backward_kernels_equal_filterpy_rts(kind, action):
    model = ins_channel()
    t, z, R = flight(model, kind, seed=3)
    fwd = run_forward(model, t, z, R.reshape(-1, 1, 1), gate=GateConfig(action=action))
    bwd = run_backward(model, fwd)
    xs, Ps, _, _ = rts_reference(model, kind, z, R, fwd.fused)
    s = model.scale
    assert np.max(np.abs(bwd.x_s - xs) / s) < 1e-9
    assert np.max(np.abs(bwd.P_s - Ps) / np.outer(s, s)) < 1e-9
    if action == "reject":
        assert not fwd.fused.all()


@pytest.mark.parametrize("kind", ["regular", "jittered"])
def test_backward_kernels_equal_pykalman_with_control(kind):
    """pykalman's smoother with time-varying transitions and the control as a transition
    offset (Bd u), on the attitude axis (a model with B)."""
    pykalman = pytest.importorskip("pykalman")
    model = attitude_axis()
    rng = np.random.default_rng(4)
    N = 300
    t = stamps(kind, N)
    u = rng.normal(0.0, 1.0, (N, 1))
    z = rng.normal(0.0, 1e-4, N)
    fwd = run_forward(model, t, z, u=u)
    bwd = run_backward(model, fwd)
    n = model.n
    Fs, Qs, offs = [], [], []
    for k in range(1, N):
        dt = t[k] - t[k - 1]
        Phi, Qd = scipy_discretize(model, dt)
        C = np.zeros((n + 1, n + 1))
        C[:n, :n], C[:n, n:] = model.A, model.B
        Fs.append(Phi)
        Qs.append(Qd)
        offs.append(expm(C * dt)[:n, n:] @ u[k])
    pk = pykalman.KalmanFilter(transition_matrices=np.array(Fs), transition_offsets=np.array(offs),
                               transition_covariance=np.array(Qs),
                               observation_matrices=model.H, observation_covariance=model.R,
                               initial_state_mean=np.zeros(n), initial_state_covariance=model.P0)
    xs, Ps = pk.smooth(z.reshape(-1, 1))
    s = model.scale
    assert np.max(np.abs(bwd.x_s - xs) / s) < 1e-9
    assert np.max(np.abs(bwd.P_s - Ps) / np.outer(s, s)) < 1e-9
