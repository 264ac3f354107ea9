"""The compiled discretization (core.discretize): Phi = expm(A dt), Qd and Bd by Van Loan, against
scipy.linalg.expm of Van Loan's block matrices, to 1e-12 of each state's scale, at regular,
jittered and long steps (scaling and squaring)."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from flight_fdi.core.discretize import (SHORT, VanLoanSeries, _scaling, _terms, discretize,
                                       discretize_all, expm_series)
from flight_fdi.core.models import attitude_axis, ins_channel, model_from_dict
from flight_fdi.core.scaled import scaled_model


def van_loan_reference(A, Qc, B, dt):
    """Phi, Qd, Bd from scipy's expm of the Van Loan matrices (Van Loan 1978)."""
    n = A.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n], M[:n, n:], M[n:, n:] = -A, Qc, A.T
    E = expm(M * dt)
    Phi = E[n:, n:].T
    Qd = Phi @ E[:n, n:]
    p = B.shape[1]
    C = np.zeros((n + p, n + p))
    C[:n, :n], C[:n, n:] = A, B
    return Phi, 0.5 * (Qd + Qd.T), expm(C * dt)[:n, n:]


def random_model():
    rng = np.random.default_rng(3)
    n = 5
    A = rng.normal(0, 2.0, (n, n))
    G = rng.normal(0, 0.3, (n, 2))
    return model_from_dict({"name": "random", "states": [{"name": f"s{i}"} for i in range(n)],
                            "A": A.tolist(), "G": G.tolist(), "H": [[1, 0, 0, 0, 0]],
                            "R": [[0.01]], "P0": np.eye(n).tolist(),
                            "B": rng.normal(size=(n, 1)).tolist()})


MODELS = [ins_channel(), attitude_axis(), random_model()]


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_compiled_van_loan_equals_scipy_expm(model):
    """In scaled coordinates (what the kernels use): every entry to 1e-12, on 0.1 s with 1 ms
    Gaussian jitter, on long steps that need squaring, and on dt = 0."""
    sm = scaled_model(model)
    rng = np.random.default_rng(11)
    dts = np.concatenate([0.1 + rng.normal(0, 1e-3, 40), [0.0, 1e-6, 0.02, 0.5, 1.0, 7.3, 60.0]])
    # Van Loan's reference (expm of [[-A, Qc], [0, A^T]]) itself loses accuracy when ||A dt||
    # is large; up to 8 it holds 1e-12, and needs up to 5 squarings here
    dts = dts[dts * sm.series.norm <= 8.0]
    Phi_all, Qd_all, Bd_all = discretize_all(sm.series, dts)
    for k, dt in enumerate(dts):
        Phi_r, Qd_r, Bd_r = van_loan_reference(sm.A, sm.Qc, sm.B, dt)
        Phi, Qd, Bd = discretize(sm.A, sm.Qc, sm.B, dt, sm.series)
        big = max(1.0, np.abs(Phi_r).max())
        assert np.abs(Phi - Phi_r).max() <= 1e-12 * big, dt
        assert np.abs(Qd - Qd_r).max() <= 1e-12 * max(np.abs(Qd_r).max(), 1e-300), dt
        assert np.abs(Bd - Bd_r).max(initial=0.0) <= 1e-12 * max(1.0, np.abs(Bd_r).max(
            initial=0.0)), dt
        assert np.array_equal(Qd, Qd.T)
        # the vectorised form runs the same kernel: the same bits
        assert np.array_equal(Phi_all[k], Phi) and np.array_equal(Qd_all[k], Qd)
        assert np.array_equal(Bd_all[k], Bd)


@pytest.mark.parametrize("model", MODELS, ids=lambda m: m.name)
def test_model_discretize_equals_the_compiled_kernel(model):
    """LinearModel.discretize (scipy's expm, physical units: the simulator's and GLR's) and the
    kernels' compiled Van Loan agree to 1e-12 of each state's scale."""
    sm = scaled_model(model)
    s = model.scale
    for dt in (0.1, 0.0993, 0.5):
        Phi, Qd, Bd = model.discretize(dt)
        Phi_s, Qd_s, Bd_s = discretize(sm.A, sm.Qc, sm.B, dt, sm.series)
        big = max(1.0, np.abs(Phi_s).max())
        assert np.abs(Phi / s[:, None] * s[None, :] - Phi_s).max() <= 1e-12 * big
        Qd_ref = Qd / np.outer(s, s)
        assert np.abs(Qd_ref - Qd_s).max() <= 1e-12 * max(np.abs(Qd_ref).max(), 1e-300)
        if model.B is not None:
            assert np.abs(Bd / s[:, None] - Bd_s).max() <= 1e-12 * max(1.0, np.abs(Bd_s).max())


def test_series_coefficients_are_the_van_loan_taylor_terms():
    """F[j] = A^j / j!, C[0] = Qc, C[1] = (A Qc + Qc A^T) / 2, G[0] = B."""
    m = attitude_axis()
    vl = VanLoanSeries(m.A, m.Qc, m.B)
    np.testing.assert_allclose(vl.F[2], m.A @ m.A / 2)
    np.testing.assert_allclose(vl.C[1], (m.A @ m.Qc + m.Qc @ m.A.T) / 2)
    np.testing.assert_array_equal(vl.G[0], m.B)
    assert vl.norm == pytest.approx(np.abs(m.A).sum(axis=0).max())


def test_both_horner_paths_equal_scipy_expm():
    """Phi = expm(A dt) alone (GLR's transitions and fault transitions Psi) and the Van Loan
    blocks, on the fixed-length Horner loop (at most SHORT terms suffice: the INS channel, a
    GLR ramp's fault system) and on the run-time length one (more terms: the random model's
    steps), 0.1 s with 1 ms Gaussian jitter: every entry to 1e-12 of scipy's expm."""
    from flight_fdi.core.glr import DEFAULT_HYPOTHESES
    from flight_fdi.core.glr_system import resolve, systems

    ins = ins_channel()
    sm = scaled_model(ins)
    ramp = systems(ins, [resolve(ins, h) for h in DEFAULT_HYPOTHESES])["accel_bias_ramp"]
    Abar = ramp.Fpsi[1]                                 # F[1] = A_bar
    rnd = scaled_model(random_model())
    dts = 0.1 + np.random.default_rng(5).normal(0.0, 1e-3, 30)
    paths = set()
    for A, F, norm in ((sm.A, sm.series.F, sm.series.norm), (Abar, ramp.Fpsi, ramp.norm_psi),
                       (rnd.A, rnd.series.F, rnd.series.norm)):
        for dt in dts:
            paths.add(_terms(norm * _scaling(norm, dt)[1]) <= SHORT)
            Phi = np.empty(A.shape)
            expm_series(F, norm, dt, Phi, np.empty(A.shape))
            ref = expm(A * dt)
            assert np.abs(Phi - ref).max() <= 1e-12 * max(1.0, np.abs(ref).max()), dt
    assert paths == {True, False}
    for model in (sm, rnd):
        for dt in dts:
            Phi, Qd, Bd = discretize(model.A, model.Qc, model.B, dt, model.series)
            Phi_r, Qd_r, Bd_r = van_loan_reference(model.A, model.Qc, model.B, dt)
            assert np.abs(Phi - Phi_r).max() <= 1e-12 * max(1.0, np.abs(Phi_r).max())
            assert np.abs(Qd - Qd_r).max() <= 1e-12 * np.abs(Qd_r).max()
            assert np.array_equal(Qd, Qd.T)
