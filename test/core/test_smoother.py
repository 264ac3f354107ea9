"""Backward information filter and two-filter smoother: RTS / brute-force agreement, the
information-form J, singular backward information, priors and records."""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter as FilterPyKF

from flight_fdi.core.errors import CoreError
from flight_fdi.core.kalman import ForwardResult, run_forward
from flight_fdi.core.models import attitude_axis, ins_channel
from flight_fdi.core.smoother import run_backward, seed_threshold


def rel(a, b, scale):
    return np.max(np.abs(a - b) / scale)


def test_two_filter_smoother_equals_filterpy_rts():
    model = ins_channel()
    rng = np.random.default_rng(1)
    N = 1200
    t = np.cumsum(rng.uniform(0.08, 0.12, N))
    z = rng.normal(0, 0.1, N) + 0.3 * np.sin(t / 30.0)
    R = rng.uniform(0.005, 0.02, N).reshape(N, 1, 1)
    fwd = run_forward(model, t, z, R)
    bwd = run_backward(model, fwd)
    Fs = [np.eye(4)] + [model.discretize(d)[0] for d in fwd.dt[1:]]
    Qs = [np.zeros((4, 4))] + [model.discretize(d)[1] for d in fwd.dt[1:]]
    kf = FilterPyKF(4, 1)
    kf.x, kf.P, kf.H = np.zeros(4), np.array(model.P0), np.array(model.H)
    mu, cov, _, _ = kf.batch_filter(z, Fs=Fs, Qs=Qs, Rs=list(R))
    xs, Ps, _, _ = kf.rts_smoother(mu, cov, Fs=Fs, Qs=Qs)
    s = model.scale
    assert rel(mu, fwd.x, s) < 1e-9
    # relative to the smoothed standard deviation of each state and step
    sd = np.sqrt(np.einsum("kii->ki", Ps))
    assert np.max(np.abs(xs - bwd.x_s) / sd) < 1e-8
    assert rel(bwd.P_s, Ps, np.sqrt(np.einsum("ki,kj->kij", sd ** 2, sd ** 2))) < 1e-8
    # at the last step the smoother is the filter
    np.testing.assert_allclose(bwd.x_s[-1], fwd.x[-1], rtol=1e-13)
    assert bwd.dof[-1] == 0 and bwd.J[-1] == 0 and np.isnan(bwd.threshold[-1])


def brute_force_smoother(model, dt, z, u):
    """Posterior of all states given all measurements, from the joint Gaussian (independent of
    any recursion). x_0 ~ N(0, P0); x_k = Phi_k x_{k-1} + Bd_k u_k + w_k."""
    n, N = model.n, len(z)
    L = np.zeros((N * n, N * n))      # X = L [x_0; w_1; ...] + c
    c = np.zeros(N * n)
    Sig0 = np.zeros((N * n, N * n))
    Sig0[:n, :n] = model.P0
    trans = [np.eye(n)]
    for k in range(1, N):
        Phi, Qd, Bd = model.discretize(dt[k])
        Sig0[k * n:(k + 1) * n, k * n:(k + 1) * n] = Qd
        c[k * n:(k + 1) * n] = Phi @ c[(k - 1) * n:k * n] + Bd @ u[k]
        trans.append(Phi)
    for k in range(N):
        for j in range(k + 1):
            M = np.eye(n)
            for i in range(j + 1, k + 1):
                M = trans[i] @ M
            L[k * n:(k + 1) * n, j * n:(j + 1) * n] = M
    SX = L @ Sig0 @ L.T
    Hb = np.kron(np.eye(N), model.H)
    Rb = np.kron(np.eye(N), model.R)
    G = SX @ Hb.T @ np.linalg.inv(Hb @ SX @ Hb.T + Rb)
    mean = c + G @ (z.reshape(-1) - Hb @ c)
    A = np.eye(N * n) - G @ Hb
    cov = A @ SX @ A.T + G @ Rb @ G.T  # Joseph form: SX - G Hb SX cancels too many digits
    return mean.reshape(N, n), np.array([cov[k * n:(k + 1) * n, k * n:(k + 1) * n]
                                         for k in range(N)])


def test_smoother_with_control_equals_brute_force_joint_gaussian():
    model = attitude_axis(sigma_rate=1e-3, sigma_md_walk=1e-5)
    rng = np.random.default_rng(2)
    N = 40
    t = np.cumsum(rng.uniform(0.05, 0.3, N))
    u = rng.normal(0, 1, (N, 1))
    z = rng.normal(0, 1e-3, (N, 2)) + np.linspace(0, 0.01, N)[:, None]
    fwd = run_forward(model, t, z, u=u)
    bwd = run_backward(model, fwd)
    xs, Ps = brute_force_smoother(model, fwd.dt, z, u)
    sd = np.sqrt(np.einsum("kii->ki", Ps))
    assert np.max(np.abs(bwd.x_s - xs) / sd) < 1e-7
    assert np.max(np.abs(bwd.P_s - Ps) / np.einsum("ki,kj->kij", sd, sd)) < 1e-7


def test_information_form_J_equals_direct_formula_where_Y_is_invertible():
    model = attitude_axis(sigma_rate=1e-3, sigma_md_walk=1e-5)
    rng = np.random.default_rng(3)
    N = 300
    t = np.arange(N) * 0.1
    z = rng.normal(0, 1e-3, (N, 2))
    z[150:, 1] += 4e-3  # an inconsistency, so that J is not small
    fwd = run_forward(model, t, z)
    bwd = run_backward(model, fwd)
    inv = bwd.invertible
    assert inv[:-5].all() and not inv[-1]
    dP = fwd.P[inv] + bwd.P_b[inv]
    v = bwd.v[inv]
    J_direct = np.einsum("ki,kij,kj->k", v, np.linalg.inv(dP), v)
    np.testing.assert_allclose(bwd.J[inv], J_direct, rtol=1e-7)
    assert J_direct.max() > 100
    # W is the inverse of dP and W v its product with v
    np.testing.assert_allclose(np.einsum("kij,kjl->kil", bwd.W[inv], dP),
                               np.broadcast_to(np.eye(3), dP.shape), atol=1e-7)
    np.testing.assert_allclose(bwd.Wv[inv], np.einsum("kij,kj->ki", bwd.W[inv], v), rtol=1e-6,
                               atol=1e-9 * np.abs(bwd.Wv[inv]).max())
    # x_b = Y^-1 y, and the smoother is the information-weighted mean
    np.testing.assert_allclose(np.einsum("kij,kj->ki", bwd.Y[inv], bwd.x_b[inv]), bwd.y[inv],
                               rtol=1e-8, atol=1e-10 * np.abs(bwd.y[inv]).max())
    assert (bwd.dof[inv] == 3).all()
    np.testing.assert_allclose(bwd.threshold[inv], 3 + 3 * np.sqrt(6))


def test_J_is_chi_square_with_dof_on_nominal_data(simulate):
    """Over many seeded flights of the model itself, J at a mid-flight step has mean dof."""
    model = attitude_axis(sigma_md_walk=1e-6)
    t = np.arange(150) * 0.1
    J = []
    for i in range(150):
        rng = np.random.default_rng(100 + i)
        X = simulate(model, t, rng)
        z = X[:, :1] + rng.normal(0, 1e-4, (len(t), 1))
        bwd = run_backward(model, run_forward(model, t, z))
        assert bwd.dof[75] == 3
        J.append(bwd.J[75])
    J = np.array(J)
    assert abs(J.mean() - 3.0) < 4 * np.sqrt(6.0 / len(J))
    assert abs(J.var() - 6.0) < 3.0


def test_ins_channel_backward_information_is_rank_deficient():
    """With tau_a == tau_w the INS channel is rank-3 observable: Y is singular everywhere, the
    information form still gives W v and J over 3 degrees of freedom; with tau_w != tau_a the
    full 4 are reached."""
    rng = np.random.default_rng(4)
    N = 3000
    t = np.arange(N) * 0.1
    z = rng.normal(0, 0.1, N)
    for model, full in ((ins_channel(), 3), (ins_channel(tau_w=1800.0), 4)):
        fwd = run_forward(model, t, z)
        bwd = run_backward(model, fwd)
        assert bwd.dof.max() == full
        assert bwd.dof[: N // 2].min() == full
        assert np.all(np.isfinite(bwd.J)) and np.all(np.isfinite(bwd.Wv))
        assert bwd.invertible.any() == (full == 4)
        assert np.all(np.isnan(bwd.x_b[~bwd.invertible]))
        # the pivot information ratios lie in [0, 1]
        assert bwd.info_ratio.min() >= 0 and bwd.info_ratio.max() <= 1
        # the dof ramp up from the end of the record
        assert np.all(np.diff(bwd.dof[-60:]) <= 0)


def test_prior_at_the_end_enters_the_last_backward_prediction():
    model = attitude_axis()
    rng = np.random.default_rng(5)
    N = 50
    t = np.arange(N) * 0.1
    z = rng.normal(0, 1e-4, (N, 1))
    fwd = run_forward(model, t, z)
    xp = np.array([1e-3, -2e-4, 1e-5])
    Pp = np.diag([1e-6, 1e-7, 1e-9])
    bwd = run_backward(model, fwd, prior=(xp, Pp))
    np.testing.assert_allclose(bwd.Y[-1], np.linalg.inv(Pp), rtol=1e-10)
    np.testing.assert_allclose(bwd.y[-1], np.linalg.solve(Pp, xp), rtol=1e-10)
    assert bwd.invertible[-1]
    np.testing.assert_allclose(bwd.x_b[-1], xp, rtol=1e-9)
    with pytest.raises(CoreError, match="positive definite"):
        run_backward(model, fwd, prior=(xp, -Pp))


def test_backward_from_a_record_equals_backward_from_the_forward_result():
    model = ins_channel()
    rng = np.random.default_rng(6)
    N = 500
    t = np.arange(N) * 0.1
    z = rng.normal(0, 0.1, N)
    fwd = run_forward(model, t, z)
    rec = ForwardResult.from_record(model, fwd.t, fwd.dt, fwd.z, fwd.R, fwd.H, fwd.fused, fwd.u,
                                    fwd.x, fwd.P)
    a, b = run_backward(model, fwd), run_backward(model, rec)
    np.testing.assert_array_equal(a.Y, b.Y)
    np.testing.assert_array_equal(a.x_s, b.x_s)
    np.testing.assert_array_equal(a.J, b.J)


def test_unfused_samples_carry_no_backward_information():
    model = ins_channel()
    rng = np.random.default_rng(7)
    N = 200
    t = np.arange(N) * 0.1
    z = rng.normal(0, 0.1, N)
    fwd = run_forward(model, t, z)
    fused = fwd.fused.copy()
    fused[-1] = False
    rec = ForwardResult.from_record(model, fwd.t, fwd.dt, fwd.z, fwd.R, fwd.H, fused, None,
                                    fwd.x, fwd.P)
    bwd = run_backward(model, rec)
    # the information at N-2 would come only from the last sample, which was not fused
    assert np.all(bwd.Y[-2] == 0) and bwd.dof[-2] == 0


def test_seed_threshold():
    np.testing.assert_allclose(seed_threshold([1, 2, 4]), [1 + 3 * np.sqrt(2), 8.0,
                                                          4 + 3 * np.sqrt(8)])
    assert np.isnan(seed_threshold(0))


def test_backward_bad_input():
    model = ins_channel()
    fwd = run_forward(model, np.arange(10) * 0.1, np.zeros(10))
    with pytest.raises(CoreError, match="ForwardResult"):
        run_backward(model, {"t": fwd.t})
    with pytest.raises(CoreError, match="rank_tol"):
        run_backward(model, fwd, rank_tol=0.0)
    rec = ForwardResult.from_record(model, fwd.t, fwd.dt, fwd.z, np.zeros((10, 1, 1)), fwd.H,
                                    fwd.fused, None, fwd.x, fwd.P)
    with pytest.raises(CoreError, match="positive definite"):
        run_backward(model, rec)


# ------------------------------------------------------------- the sweep compiled per state size

def constant_velocity():
    """A 2-state model (position, velocity): its n is not specialised, the generic sweep runs."""
    from flight_fdi.core.models import LinearModel

    return LinearModel(name="cv", state_names=("p", "v"), state_units=("m", "m/s"),
                       A=[[0.0, 1.0], [0.0, 0.0]], Qc=np.diag([0.0, 0.05]), H=[[1.0, 0.0]],
                       R=[[0.04]], P0=np.diag([1.0, 0.25]))


def _stamps(kind, N, rng):
    t = np.arange(N) * 0.1
    return t if kind == "regular" else t + rng.normal(0.0, 1e-3, N)


@pytest.mark.parametrize("kind", ["regular", "jittered"])
@pytest.mark.parametrize("make", [ins_channel, attitude_axis])
def test_sweep_compiled_for_the_state_size_equals_the_generic_sweep(kind, make, monkeypatch):
    """The built-in models' sizes run a sweep compiled with n fixed: the same arithmetic as the
    generic sweep, so the same bits (outputs, J, localization), with gating and control."""
    from flight_fdi.core import information
    from flight_fdi.core.kalman import GateConfig

    model = make()
    rng = np.random.default_rng(11)
    N = 500
    t = _stamps(kind, N, rng)
    z = rng.normal(0.0, np.sqrt(model.R[0, 0]), (N, model.m)) + 0.2 * np.sin(t / 20.0)[:, None]
    z[200::41] += 30 * np.sqrt(model.R[0, 0])  # outliers, rejected by the gate
    u = None if model.B is None else rng.normal(0.0, 1.0, (N, model.B.shape[1]))
    fwd = run_forward(model, t, z, u=u, gate=GateConfig(action="reject"))
    assert not fwd.fused.all()
    special = information.sweep_for(model.n)
    assert model.n in information.SPECIALISED and special is not information.smooth_pass
    fixed = run_backward(model, fwd)
    monkeypatch.setattr(information, "sweep_for", lambda n: information.smooth_pass)
    generic = run_backward(model, fwd)
    for name in ("Y", "y", "x_s", "P_s", "W", "Wv", "J", "dof", "info_ratio"):
        np.testing.assert_array_equal(getattr(fixed, name), getattr(generic, name), err_msg=name)
    for name in ("terms", "v_tilde", "d", "normalized"):
        np.testing.assert_array_equal(getattr(fixed.localization, name),
                                      getattr(generic.localization, name), err_msg=name)


@pytest.mark.parametrize("kind", ["regular", "jittered"])
def test_generic_sweep_equals_filterpy_rts_for_another_state_size(kind):
    """A 2-state model runs the generic sweep: FilterPy's RTS smoother to 1e-9 of the scale."""
    from flight_fdi.core import information
    from scipy.linalg import expm

    model = constant_velocity()
    assert information.sweep_for(model.n) is information.smooth_pass
    rng = np.random.default_rng(12)
    N = 400
    t = _stamps(kind, N, rng)
    z = 0.5 * np.sin(t / 5.0) + rng.normal(0.0, 0.2, N)
    fwd = run_forward(model, t, z)
    bwd = run_backward(model, fwd)
    n = model.n
    Fs, Qs = [np.eye(n)], [np.zeros((n, n))]
    for dt in np.diff(t):  # Van Loan with scipy's expm, independent of the kernels
        M = np.zeros((2 * n, 2 * n))
        M[:n, :n], M[:n, n:], M[n:, n:] = -model.A, model.Qc, model.A.T
        E = expm(M * dt)
        Fs.append(E[n:, n:].T)
        Qs.append(Fs[-1] @ E[:n, n:])
    kf = FilterPyKF(n, 1)
    kf.x, kf.P, kf.H, kf.R = np.zeros(n), np.array(model.P0), np.array(model.H), model.R
    mu, cov, _, _ = kf.batch_filter(z, Fs=Fs, Qs=Qs)
    xs, Ps, _, _ = kf.rts_smoother(mu, cov, Fs=Fs, Qs=Qs)
    s = model.scale
    assert rel(bwd.x_s, xs, s) < 1e-9
    assert rel(bwd.P_s, Ps, np.outer(s, s)) < 1e-9
