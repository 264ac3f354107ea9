"""The backward information filter and the two-filter combination on the time-varying ins3d
model: equal to FilterPy's RTS smoother fed the same Phi_k, Q_k; the coarser step grid; the fault
input Gamma_k against the exponential of the augmented F."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg
from filterpy.kalman import KalmanFilter

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.backward import ACC_A, ACC_R, GYR_A, GYR_R, fault_gamma
from flight_fdi.core.ins3d.data import RefRows, coarsen
from flight_fdi.core.ins3d.filter import run_forward, white_variance
from flight_fdi.core.ins3d.model import IBA, IBG, IPHI, IV, Ins3dModel, discretize, fill_F

from .conftest import flight


def short_analysis(t_end: float = 420.0, faults: tuple[str, ...] = (), seed: int = 5):
    """cruise_turns up to t_end (the first turn starts at 303 s), navigation grade, with the
    post-flight part (no observability report)."""
    inp = from_flight(flight("cruise_turns", t_end, "navigation", "baro", seed, faults=faults))
    return analyze_ins3d(inp.steps, inp.refs, with_observability=False)


@pytest.fixture(scope="module")
def short():
    return short_analysis()


def phi_q(model, steps, k):
    F, Phi, Q = (np.empty((model.n, model.n)) for _ in range(3))
    fill_F(F, steps.C[k], steps.f_n[k], steps.v[k], steps.lat[k], steps.h[k],
           model.kernel_params())
    discretize(F, steps.dt[k], model.qc(), Phi, Q)
    return F, Phi, Q


def test_two_filter_combination_equals_filterpy_rts(short):
    """The smoothed state of the combination (forward prior + backward information) equals
    FilterPy's RTS smoother over the same Phi_k, Q_k, H_j, R_j (latency and Markov states)."""
    a = short
    m, steps, refs = a.model, a.steps, a.refs
    K = len(steps)
    P0 = m.p0_aligned(steps.C[0], steps.f_n[0], float(steps.lat[0]))
    kf = KalmanFilter(dim_x=m.n, dim_z=m.rows)
    kf.x, kf.P = np.zeros(m.n), P0.copy()
    R = white_variance(m, refs.r)
    Xs, Ps, Fs, Qs = [], [], [np.eye(m.n)], [np.zeros((m.n, m.n))]
    j = 0
    for k in range(K + 1):
        if k > 0:
            _, Phi, Q = phi_q(m, steps, k - 1)
            kf.predict(F=Phi, Q=Q)
            if k < K:
                Fs.append(Phi.copy())
                Qs.append(Q.copy())
        while j < refs.t.size and refs.step[j] == k:
            kf.update(refs.z[j, :m.rows], R=np.diag(R[j, :m.rows]), H=m.H(refs.a[j]))
            j += 1
        Xs.append(kf.x.copy())
        Ps.append(kf.P.copy())
    _, Phi, Q = phi_q(m, steps, K - 1)
    Fs.append(Phi)
    Qs.append(Q)
    xs, Pss, _, _ = kf.rts_smoother(np.array(Xs), np.array(Ps), np.array(Fs[:K + 1]),
                                     np.array(Qs[:K + 1]))
    idx = refs.step
    sd = np.sqrt(np.diagonal(Pss, axis1=1, axis2=2))[idx]
    err = np.abs(a.backward.x_s - xs[idx]) / sd
    rel = np.max(np.abs(a.backward.sd_s / sd - 1))
    print(f"max |x_s - RTS| / sd {err.max():.2e}; sd rel {rel:.2e}")
    assert err.max() < 1e-5
    np.testing.assert_allclose(a.backward.sd_s, sd, rtol=1e-5)
    # the backward filter starts from zero information: at the last update it is the forward
    assert np.allclose(a.backward.x_s[-1], a.forward.x[-1], atol=1e-9 * np.max(np.abs(xs)))


def test_fault_input_equals_the_augmented_exponential(short):
    """Gamma_a and Gamma_r of one step (a turn, 0.1 s) against expm of [[F, E, 0], [0, 0, I],
    [0, 0, 0]] dt (the error a + r t, t from the step's start t~): second order like Phi."""
    m, steps = short.model, short.steps
    k = int(np.argmax(np.linalg.norm(steps.f_n[:, :2], axis=1)))     # in the turn
    F, _, _ = phi_q(m, steps, k)
    dt, tt, n = float(steps.dt[k]), 300.0, m.n
    ones = np.ones(n)
    G = np.empty((n, 12 + m.rows))
    fault_gamma(F, dt, tt, ones, np.ones(12 + m.rows), G)
    for bcol, ca, cr, rows in ((IBA, ACC_A, ACC_R, slice(IV, IV + 3)),
                               (IBG, GYR_A, GYR_R, slice(IPHI, IPHI + 3))):
        E = np.zeros((n, 3))
        E[rows] = F[rows, bcol:bcol + 3]
        M = np.zeros((n + 6, n + 6))
        M[:n, :n], M[:n, n:n + 3], M[n:n + 3, n + 3:] = F, E, np.eye(3)
        X = scipy.linalg.expm(M * dt)
        ga = X[:n, n:n + 3]                      # the a part: a constant error
        gr = X[:n, n + 3:] + ga * tt             # r (t~ + s): exactly integrated
        # (the vertical loop's states, after the 12 core ones, get the fault only through
        # dh and dv_U: their dt^3 remainder is the one Phi's second-order series leaves too)
        core = slice(0, 12)
        scale = np.abs(ga).max()
        assert np.abs(G[core, ca:ca + 3] - ga[core]).max() < 1e-5 * scale    # measured 2.5e-6
        assert np.abs(G[core, cr:cr + 3] - gr[core]).max() < 1e-5 * scale * tt
        w = 1.0 / np.sqrt(m.p0())[:, None]      # all states, in units of their prior sd
        assert np.abs((G[:, ca:ca + 3] - ga) * w).max() < 1e-3 * np.abs(ga * w).max()


def test_coarser_grid_changes_the_forward_filter_by_little():
    """20-Hz steps merged onto the 10-Hz reference grid: innovations within 1e-3 of their sd,
    states within 1e-2 sd (a 25-degree turn included)."""
    inp = from_flight(flight("cruise_turns", 420.0, "navigation", "baro", 5))
    m = Ins3dModel.from_grade("navigation", latency=True, ref_markov=(0.02, 0.03, 30.0))
    fine = run_forward(m, inp.steps, inp.refs)
    cs, cr = coarsen(inp.steps, inp.refs, 0.1)
    assert len(cs) == pytest.approx(len(inp.steps) / 2, abs=2)
    coarse = run_forward(m, cs, cr)
    sdn = np.sqrt(np.diagonal(fine.S, axis1=1, axis2=2))
    assert np.max(np.abs(coarse.nu - fine.nu) / sdn) < 1e-3
    xf = fine.x[inp.refs.step]
    xc = coarse.x[cr.step]
    assert np.max(np.abs(xc - xf) / fine.sd[inp.refs.step]) < 1e-2
    with pytest.raises(Exception):
        coarsen(inp.steps, inp.refs, 0.0)


def test_unsorted_references_are_sorted(short):
    """analyze_ins3d sorts the updates by step: a shuffled input gives the same result."""
    inp = from_flight(flight("cruise_turns", 420.0, "navigation", "baro", 5))
    p = np.random.default_rng(3).permutation(inp.refs.t.size)
    r = inp.refs
    shuffled = RefRows(r.t[p], r.z[p], r.r[p], r.step[p], r.a[p])
    b = analyze_ins3d(inp.steps, shuffled, with_observability=False)
    np.testing.assert_allclose(b.backward.x_s, short.backward.x_s, rtol=1e-12, atol=1e-15)
