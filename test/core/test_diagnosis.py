"""Seed diagnosis: UDU^T, localization (seed and information form, the KDZ-3 example), the Fisher
test, and the verdict over simulated flights."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.core.diagnosis import (DiagnosisConfig, diagnose, fisher, fisher_threshold, ldl,
                                       localize, udu)
from flight_fdi.core.errors import CoreError
from flight_fdi.core.kalman import run_forward
from flight_fdi.core.models import ins_channel
from flight_fdi.core.smoother import run_backward


def random_spd(rng, n, spread=0.0):
    A = rng.normal(size=(n, n))
    s = 10.0 ** rng.uniform(-spread, spread, n)
    return s[:, None] * (A @ A.T + 0.1 * np.eye(n)) * s[None, :]


# --------------------------------------------------------------------------- UDU^T


def test_udu_reconstructs_and_is_unit_upper_triangular():
    rng = np.random.default_rng(1)
    for n in (1, 2, 4, 6):
        for spread in (0.0, 5.0):  # up to ten orders of magnitude between states
            P = random_spd(rng, n, spread)
            U, D = udu(P)
            assert np.all(np.tril(U, -1) == 0) and np.all(np.diag(U) == 1)
            assert np.all(D > 0)
            np.testing.assert_allclose(U @ np.diag(D) @ U.T, P, rtol=1e-10,
                                       atol=1e-12 * np.sqrt(np.outer(np.diag(P), np.diag(P))).max())
            # D_n is the last variance; D_1 the variance of x_1 given the others
            assert D[-1] == pytest.approx(P[-1, -1])
            assert D[0] == pytest.approx(1.0 / np.linalg.inv(P)[0, 0], rel=1e-8)
    stack = np.stack([random_spd(rng, 3) for _ in range(5)])
    U, D = udu(stack)
    np.testing.assert_allclose(np.einsum("kij,kj,klj->kil", U, D, U), stack, rtol=1e-10)


def test_udu_rejects_bad_matrices():
    with pytest.raises(CoreError, match="not symmetric"):
        udu([[1.0, 0.5], [0.0, 1.0]])
    with pytest.raises(CoreError, match="not positive definite"):
        udu([[1.0, 2.0], [2.0, 1.0]])
    with pytest.raises(CoreError, match="NaN"):
        udu([[np.nan, 0.0], [0.0, 1.0]])


def test_ldl_of_the_inverse_matches_udu():
    """W = dP^-1 = L Lam L^T with L = U^-T, Lam = D^-1 (the algebra of the information form)."""
    rng = np.random.default_rng(2)
    P = random_spd(rng, 4, 3.0)
    U, D = udu(P)
    L, Lam, informative = ldl(np.linalg.inv(P))
    assert informative.all()
    np.testing.assert_allclose(L, np.linalg.inv(U).T, rtol=1e-8, atol=1e-8 * np.abs(L).max())
    np.testing.assert_allclose(Lam, 1.0 / D, rtol=1e-8)


# --------------------------------------------------------------------------- localization


def test_kdz3_worked_example():
    """Seed 000, KDZ-3: x(i/i) = [5, 2], x(i/N) = [3, 1], dP^-1 = [[1,0],[3,1]] diag(1,2)
    [[1,3],[0,1]] -> v = [-2, -1], v~ = [-5, -1], J = 27 > 8, J(i/1) = 25 > 5.243 -> element 1."""
    x_f, x_s = np.array([5.0, 2.0]), np.array([3.0, 1.0])
    Lw = np.array([[1.0, 0.0], [3.0, 1.0]])
    W = Lw @ np.diag([1.0, 2.0]) @ Lw.T
    v = x_s - x_f
    np.testing.assert_array_equal(v, [-2.0, -1.0])
    for loc in (localize(v, dP=np.linalg.inv(W)), localize(v, W=W), localize(Wv=W @ v, W=W)):
        np.testing.assert_allclose(loc.v_tilde, [-5.0, -1.0], rtol=1e-12)
        np.testing.assert_allclose(loc.terms, [25.0, 27.0], rtol=1e-12)
        assert loc.J == pytest.approx(27.0)
        np.testing.assert_allclose(loc.gammas, [1 + 3 * math.sqrt(2), 8.0])
        assert loc.gammas[0] == pytest.approx(5.243, abs=1e-3)
        assert loc.element == 0
        np.testing.assert_array_equal(loc.dof, [1, 2])
        np.testing.assert_allclose(loc.d, [1.0, 0.5], rtol=1e-12)


def test_information_form_equals_seed_form():
    rng = np.random.default_rng(3)
    for _ in range(20):
        dP = random_spd(rng, 4, 2.0)
        v = rng.multivariate_normal(np.zeros(4), dP) * 2
        a = localize(v, dP=dP)
        b = localize(v, W=np.linalg.inv(dP))
        np.testing.assert_allclose(b.terms, a.terms, rtol=1e-7)
        np.testing.assert_allclose(b.v_tilde, a.v_tilde, rtol=1e-6, atol=1e-9 * np.abs(v).max())
        assert a.element == b.element
        assert a.J == pytest.approx(v @ np.linalg.solve(dP, v), rel=1e-9)


def test_information_form_with_singular_W():
    """No information on one element (given the earlier ones): its term is 0, one dof fewer,
    and J = (Wv)^T W^+ (Wv)."""
    rng = np.random.default_rng(4)
    B = rng.normal(size=(3, 2))
    B[2] = B[0] * 0.5 + B[1] * 2.0      # row 3 depends on rows 1, 2: W has rank 2
    W = B @ B.T
    a = rng.normal(size=3)
    Wv = W @ a
    loc = localize(Wv=Wv, W=W)
    np.testing.assert_array_equal(loc.dof, [1, 2, 2])
    assert loc.terms[2] == pytest.approx(loc.terms[1])
    assert np.isnan(loc.v_tilde[2]) and np.isinf(loc.d[2])
    assert loc.J == pytest.approx(Wv @ np.linalg.pinv(W) @ Wv, rel=1e-8)
    assert loc.J == pytest.approx(a @ W @ a, rel=1e-8)
    # no information at all
    empty = localize(Wv=np.zeros(3), W=np.zeros((3, 3)))
    assert empty.J == 0 and empty.element is None
    np.testing.assert_array_equal(empty.dof, [0, 0, 0])


def test_localize_bad_input():
    with pytest.raises(CoreError, match="exactly one"):
        localize(np.zeros(2), dP=np.eye(2), W=np.eye(2))
    with pytest.raises(CoreError, match="needs v"):
        localize(dP=np.eye(2))
    with pytest.raises(CoreError, match="NaN"):
        localize([np.nan, 0.0], dP=np.eye(2))


# --------------------------------------------------------------------------- Fisher


def test_fisher_thresholds_by_hand():
    a, b, eta2 = fisher_threshold(10)
    assert a == pytest.approx(1.25)                      # 10 / 8
    assert b == pytest.approx(0.9375)                    # 4*10*9 / (64 * 6)
    assert eta2 == pytest.approx(1.25 + 3 * math.sqrt(0.9375))
    a, b, eta2 = fisher_threshold(50)
    assert a == pytest.approx(50 / 48) and b == pytest.approx(9800 / (2304 * 46))
    for bad in (4, 3, 0, 2.5, True):
        with pytest.raises(CoreError, match="fisher window"):
            fisher_threshold(bad)


def test_fisher_equals_windowed_sample_variance():
    rng = np.random.default_rng(5)
    x = rng.normal(3.0, 2.0, (300, 2))
    x[100, 1] = np.nan
    w = 20
    F = fisher(x, w)
    assert np.all(np.isnan(F[:w - 1]))
    for i in range(w - 1, 300):
        for k in range(2):
            win = x[i - w + 1:i + 1, k]
            if np.isnan(win).any():
                assert np.isnan(F[i, k])
            else:
                assert F[i, k] == pytest.approx(np.var(win, ddof=1), rel=1e-9)


def test_fisher_fires_on_a_variance_increase_not_on_nominal_data():
    rng = np.random.default_rng(6)
    w = 50
    _, _, eta2 = fisher_threshold(w)
    nominal = fisher(rng.normal(0, 1, 4000), w)
    assert np.nanmax(nominal) < eta2
    x = np.r_[rng.normal(0, 1, 1000), rng.normal(0, 3, 1000)]
    F = fisher(x, w)
    assert np.nanmax(F[:1000]) < eta2
    assert np.all(F[1000 + w:] > eta2)


# --------------------------------------------------------------------------- over a flight


@pytest.fixture(scope="module")
def flights(simulate, step):
    """Seeded 400 s flights at 10 Hz of the INS channel: nominal, an accelerometer bias step at
    200 s, and a short burst of reference outliers."""
    model = ins_channel()
    t = np.arange(4000) * 0.1
    out = {}
    for name, seed in (("nominal", 21), ("accel", 22), ("outliers", 23)):
        rng = np.random.default_rng(seed)
        X = simulate(model, t, rng)
        if name == "accel":
            X = X + step(model, t, "accel_bias", 200.0, 0.02)
        z = X[:, 0] + rng.normal(0, 0.1, len(t))
        if name == "outliers":
            z[2000:2003] += 10.0
        fwd = run_forward(model, t, z)
        out[name] = (fwd, run_backward(model, fwd))
    return model, out


def test_diagnose_nominal_flight_is_no_fault(flights):
    model, out = flights
    d = diagnose(model, *out["nominal"])
    assert d.verdict == "no_fault" and d.element is None and d.onset_t is None
    assert d.valid.sum() > 3900
    assert d.dof[d.valid].min() == 3  # the INS channel is rank-3 observable
    # J is chi-square(3) on healthy data: mean near 3
    assert 1.5 < d.J[d.valid].mean() < 4.5
    names = [e.name for e in d.elements]
    assert names == list(model.state_names)
    assert all(e.F_peak < e.eta2 for e in d.elements if np.isfinite(e.F_peak))


def test_diagnose_accelerometer_step(flights):
    """The seed method sees the step (J far over its bound, the peak right after the onset); as
    the SPEC warns, its UDU^T order blames the first element (velocity error) rather than the
    accelerometer -- the GLR isolator is the one that separates them (test_analysis)."""
    model, out = flights
    d = diagnose(model, *out["accel"])
    assert d.verdict in ("failure", "glitch", "ambiguous")
    assert 200.0 <= d.onset_t <= 215.0
    assert d.J[d.valid].max() > 100 * d.gamma2[d.valid].max()
    after = d.valid & (d.t > 200)
    assert np.mean(d.J[after] > d.gamma2[after]) > 0.5
    assert d.element in model.state_names
    acc = d.elements[model.index("accel_bias")]
    assert acc.J_peak > acc.gamma2 and acc.exceed_fraction > 0.3


def test_diagnose_outlier_burst_is_a_glitch(flights):
    model, out = flights
    d = diagnose(model, *out["outliers"])
    assert d.verdict == "glitch"
    assert d.element == "velocity_error"
    assert abs(d.onset_t - 200.0) < 1.0
    assert d.end_t is not None and d.end_t < 300.0  # the episode ends: not a lasting change


def test_diagnose_short_record_is_insufficient():
    model = ins_channel()
    rng = np.random.default_rng(8)
    t = np.arange(60) * 0.1
    fwd = run_forward(model, t, rng.normal(0, 0.1, 60))
    d = diagnose(model, fwd, run_backward(model, fwd))
    assert d.verdict == "insufficient_data"


@pytest.mark.parametrize("kwargs, field", [
    ({"fisher_window": 4}, "fisher window"), ({"persistence_s": -1.0}, "persistence_s"),
    ({"episode_probability": 0.0}, "episode_probability"),
    ({"min_valid_steps": 0}, "min_valid_steps"), ({"rank_tol": 1.0}, "rank_tol"),
])
def test_diagnosis_config_validation(kwargs, field):
    with pytest.raises(CoreError, match=field):
        DiagnosisConfig(**kwargs)


def test_decorrelated_residuals_in_physical_units(flights):
    """v~ and dD reported per step reproduce the element terms: J(i/k) = sum v~_j^2 / dD_j;
    the same with a different rank tolerance (recomputed) as with the backward pass's own."""
    model, out = flights
    fwd, bwd = out["accel"]
    for tol in (bwd.rank_tol, 1e-7):
        d = diagnose(model, fwd, bwd, DiagnosisConfig(rank_tol=tol))
        single = np.where(np.isfinite(d.v_tilde), d.v_tilde ** 2 / d.delta_d, 0.0)
        v = d.valid
        np.testing.assert_allclose(np.cumsum(single, axis=1)[v], d.terms[v], rtol=1e-8,
                                   atol=1e-12)
        # velocity error residual in m/s: its variance dD is of the order of (0.1 m/s)^2
        assert 1e-6 < np.median(d.delta_d[v, 0]) < 1.0


def test_diagnose_accepts_settings_as_keywords(flights):
    model, out = flights
    a = diagnose(model, *out["outliers"], fisher_window=100, persistence_s=2.0)
    b = diagnose(model, *out["outliers"], DiagnosisConfig(fisher_window=100, persistence_s=2.0))
    assert a.config == b.config and a.verdict == b.verdict
    np.testing.assert_array_equal(a.F, b.F)
    with pytest.raises(CoreError, match="fisher window"):
        diagnose(model, *out["outliers"], fisher_window=2)
    with pytest.raises(CoreError, match="unexpected keyword"):
        diagnose(model, *out["outliers"], window=2)
