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
from flight_fdi.core.ins3d.model import IBA, IBG, IPHI, IV, Ins3dModel
from flight_fdi.core.ins3d.dynamics import discretize, fill_F

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


def _information_filter_combination(a):
    """Reference: the backward information filter (Y, y) from zero information, predicted with
    (I + Y Q)^-1 per step (numpy), combined with the forward prior at every boundary with updates
    by ``core.information.combine_step`` (the single-axis kernel) -- the two-filter form the sweep
    replaces. Scaled coordinates like the kernels; returns physical x_s, sd_s and the terms."""
    from flight_fdi.core.information import combine_step
    m, steps, refs, fwd = a.model, a.steps, a.refs, a.forward
    n, rows, M = m.n, m.rows, refs.t.size
    s = np.sqrt(m.p0())
    R = white_variance(m, refs.r)
    Y, y = np.zeros((n, n)), np.zeros(n)
    out = {k: np.full((M, n), np.nan) for k in ("x_s", "sd_s", "terms", "normalized", "d")}
    out["dof"] = np.zeros((M, n), dtype=np.int64)
    W, P_s, x_s = np.empty((n, n)), np.empty((n, n)), np.empty(n)
    Wv, ref, Lam, vt, dd = (np.empty(n) for _ in range(5))
    inf = np.empty(n, dtype=np.bool_)
    A, work = np.empty((n, 2 * n + 1)), np.empty((2, n, n))
    # the forward priors in scaled units, once (x_prior, P_prior are properties that scale
    # the whole (M, n, n) array at every access)
    xf_all, Pf_all = fwd.x_prior / s, fwd.P_prior / np.outer(s, s)
    j1 = M
    for k in range(len(steps), -1, -1):
        j0 = j1
        while j0 > 0 and refs.step[j0 - 1] == k:
            j0 -= 1
        for j in range(j0, j1):
            Hs = m.H(refs.a[j]) * s[None, :]
            Y += Hs.T @ np.diag(1.0 / R[j, :rows]) @ Hs
            y += Hs.T @ (refs.z[j, :rows] / R[j, :rows])
        if j0 < j1:
            xf, Pf = xf_all[j0], Pf_all[j0]
            terms, dof, norm = np.empty(n), np.empty(n, dtype=np.int64), np.empty(n)
            assert combine_step(Y, y, xf, Pf, 1e-9, W, Wv, x_s, P_s, ref, Lam, inf, vt, dd,
                                terms, dof, norm, A, work)
            out["x_s"][j0:j1] = x_s * s
            out["sd_s"][j0:j1] = np.sqrt(np.diag(P_s)) * s
            out["terms"][j0:j1], out["dof"][j0:j1], out["normalized"][j0:j1] = terms, dof, norm
            out["d"][j0:j1] = dd * s * s
            j1 = j0
        if k == 0:
            break
        _, Phi, Q = phi_q(m, steps, k - 1)
        Phi, Q = Phi * s[None, :] / s[:, None], Q / np.outer(s, s)
        B = np.linalg.solve(np.eye(n) + Y @ Q, np.column_stack([Y, y]))
        Y, y = Phi.T @ B[:, :n] @ Phi, Phi.T @ B[:, n]
        Y = 0.5 * (Y + Y.T)
    return out


@pytest.mark.parametrize("rows,position", [(2, False), (3, False), (2, True)])
def test_sweep_equals_the_information_filter_combination(rows, position):
    """The adjoint (Bryson-Frazier) sweep gives the two-filter combination of the backward
    information filter: smoothed state and sd, and the seed method's element terms (J(i/k), the
    effective dof, the normalised residuals) at every boundary with updates; 330 s with the
    start of a turn (the first turn starts at 303 s: the flight's tail is the hard part, the
    backward information is small there); 15, 16 (3 rows) and 18 states (position)."""
    inp = from_flight(flight("cruise_turns", 330.0, "navigation", "baro", 5))
    a = analyze_ins3d(inp.steps, inp.refs, rows=rows, position=position,
                      with_observability=False)
    ref = _information_filter_combination(a)
    b = a.backward
    assert np.max(np.abs(b.x_s - ref["x_s"]) / ref["sd_s"]) < 1e-8
    np.testing.assert_allclose(b.sd_s, ref["sd_s"], rtol=1e-8)
    np.testing.assert_array_equal(b.dof, ref["dof"])
    # the LDL' of W where the backward information is small (the flight's last ~30 s) is
    # conditioned like it: J(i/k) of the last elements differ there by up to 5e-4 (vertical loop)
    np.testing.assert_allclose(b.terms, ref["terms"], rtol=1e-3, atol=1e-8)
    ok = np.isfinite(ref["normalized"])
    np.testing.assert_array_equal(ok, np.isfinite(b.normalized))
    d_norm = np.max(np.abs(b.normalized[ok] - ref["normalized"][ok]))
    d_d = np.max(np.abs(b.d[ok] / ref["d"][ok] - 1))
    print(f"normalised residuals {d_norm:.1e}, dD {d_d:.1e} (relative)")
    assert d_norm < 1e-2 and d_d < 1e-2          # measured up to 1.5e-3, 4.1e-3 (the tail)


def test_rejected_updates_are_judged_after_the_flight():
    """With the gate action ``reject`` the forward pass skips gated updates; the post-flight part
    still judges all the data: its sweep runs on a forward pass that fuses every update, so it
    equals the analysis with the action ``flag``."""
    from flight_fdi.core.kalman import GateConfig
    inp = from_flight(flight("cruise_turns", 200.0, "navigation", "baro", 5))
    rej = analyze_ins3d(inp.steps, inp.refs, with_observability=False,
                        gate=GateConfig(action="reject", probability=0.05))
    flag = analyze_ins3d(inp.steps, inp.refs, with_observability=False,
                         gate=GateConfig(action="flag", probability=0.05))
    assert not rej.forward.fused.all() and flag.forward.fused.all()
    assert not np.array_equal(rej.forward.x, flag.forward.x)
    np.testing.assert_array_equal(rej.backward.x_s, flag.backward.x_s)
    np.testing.assert_array_equal(rej.backward.eta, flag.backward.eta)


def test_merged_steps_match_the_per_step_analysis():
    """The INS topics at 100 Hz: the analysis on the steps merged onto the 10-Hz reference grid
    (``max_dt`` 0.1 s, the default) against the same analysis on every 100-Hz step (the model
    as defined: discretised per step at the actual dt) over 330 s with a turn and a gyro step:
    innovations within 1e-4 of their sd, smoothed states within 1e-2 sd, the GLR statistics
    within 0.1 % and the same onset and magnitude."""
    fl = flight("cruise_turns", 330.0, "navigation", "baro", 6,
                faults=("gyro:step:t=200,mag=0.5deg/h,axis=x",))
    inp = from_flight(fl, imu_rate_hz=100.0, velocity_rate_hz=100.0)
    merged = analyze_ins3d(inp.steps, inp.refs, with_observability=False)
    fine = analyze_ins3d(inp.steps, inp.refs, with_observability=False, max_dt=None)
    assert len(fine.steps) > 9 * len(merged.steps)
    sd_nu = np.sqrt(np.diagonal(fine.forward.S, axis1=1, axis2=2))
    d_nu = np.max(np.abs(merged.forward.nu - fine.forward.nu) / sd_nu)
    d_x = np.max(np.abs(merged.backward.x_s - fine.backward.x_s) / fine.backward.sd_s)
    print(f"innovations {d_nu:.1e} sd, smoothed states {d_x:.1e} sd")
    assert d_nu < 1e-4 and d_x < 1e-2            # measured 1.2e-5, 1.7e-3
    for name in ("gyro_x_step", "gyro_x_ramp", "accelerometer_y_step"):
        cm, cf = merged.glr[name], fine.glr[name]
        np.testing.assert_array_equal(cm.t, cf.t)
        print(name, cm.statistic, cf.statistic)
        assert cm.statistic == pytest.approx(cf.statistic, rel=1e-3)   # measured 3e-5
        assert cm.best == cf.best
        assert cm.mag[cm.best] == pytest.approx(cf.mag[cf.best], rel=1e-2)
    assert merged.isolation.best == fine.isolation.best == "gyro_x_step"


def test_the_two_threads_of_the_sweep_equal_one(short):
    """The combination and the fault blocks with their 3-dof statistics on two threads (each
    carries the same (lambda, Lambda)) give exactly the one-thread sweep."""
    from flight_fdi.core.ins3d.glr3d import joint
    from flight_fdi.core.ins3d.postflight import run_backward
    a = short
    one = run_backward(a.model, a.steps, a.refs, a.forward, 1e-9, threads=1)
    two = run_backward(a.model, a.steps, a.refs, a.forward, 1e-9, threads=2)
    for k in ("x_s", "sd_s", "terms", "dof", "normalized", "v_tilde", "d", "eta", "I3", "oe",
              "oI"):
        np.testing.assert_array_equal(getattr(one, k), getattr(two, k), err_msg=k)
    f = one.first
    ref = joint(one.eta[f], one.I3[f], a.model.rows)
    assert set(one.joint) == set(two.joint) == set(ref) == {"accelerometer_step", "gyro_step",
                                                             "reference_jump"}
    for k in ref:
        np.testing.assert_array_equal(one.joint[k], ref[k], err_msg=k)
        np.testing.assert_array_equal(two.joint[k], ref[k], err_msg=k)
    # the states alone (a relinearisation's need: no fault information) are the same numbers
    from flight_fdi.core.ins3d.postflight import smoothed_states
    np.testing.assert_array_equal(smoothed_states(a.model, a.steps, a.refs, a.forward, 1e-9),
                                  one.x_s)


def test_merged_steps_carry_the_dt_weighted_means():
    """coarsen: every merged step's C, f_n, w_b, v, lat, h is the dt-weighted mean of its
    steps (numpy's average as the reference; one compiled pass), dt their sum; the updates
    land on the merged boundaries."""
    inp = from_flight(flight("cruise_turns", 120.0, "navigation", "baro", 5))
    st = inp.steps
    cs, cr = coarsen(st, inp.refs, 0.1)
    b = np.searchsorted(st.t, cs.t)
    np.testing.assert_array_equal(st.t[b], cs.t)
    np.testing.assert_array_equal(cs.t[cr.step], st.t[inp.refs.step])
    for i in (0, 1, len(cs) // 2, len(cs) - 1):
        sl = slice(b[i], b[i + 1])
        assert cs.dt[i] == pytest.approx(st.dt[sl].sum(), rel=1e-15)
        for k in ("C", "f_n", "w_b", "v", "lat", "h"):
            ref = np.average(getattr(st, k)[sl], axis=0, weights=st.dt[sl])
            np.testing.assert_allclose(getattr(cs, k)[i], ref, rtol=1e-14, atol=1e-15,
                                       err_msg=k)
    assert cs.C.flags.c_contiguous and cs.C.shape == (len(cs), 3, 3)
