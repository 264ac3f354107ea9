"""The forward filter on the time-varying ins3d model: equality with FilterPy, consistency on
flights that follow the model's assumptions, the gate per row, the reject action."""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from flight_fdi.bagio.ins3d_input import from_flight, truth_from_flight
from flight_fdi.core.ins3d.data import RefRows
from flight_fdi.core.ins3d.filter import run_forward, white_variance
from flight_fdi.core.ins3d.model import Ins3dModel
from flight_fdi.core.ins3d.dynamics import discretize, fill_F
from flight_fdi.core.kalman import GateConfig

from .conftest import flight


def test_equals_filterpy_on_the_same_ltv_model():
    """Scaled numba kernel == FilterPy (unscaled, Joseph) fed the same Phi_k, Q_k per step."""
    fl = flight("cruise_turns", 600.0, "tactical", "baro", 3)
    inp = from_flight(fl)
    m = Ins3dModel.from_grade("tactical", rows=3)
    K = 7000                                            # 350 s at 20 Hz: into the first turn
    steps = inp.steps
    sel = inp.refs.step <= K
    refs = RefRows(inp.refs.t[sel], inp.refs.z[sel], inp.refs.r[sel], inp.refs.step[sel])
    res = run_forward(m, steps, refs)
    kf = KalmanFilter(dim_x=m.n, dim_z=3)
    kf.x = np.zeros(m.n)
    kf.P = np.diag(m.p0())
    kf.H = m.H()
    F, Phi, Q = (np.empty((m.n, m.n)) for _ in range(3))
    j = 0
    for k in range(K + 1):
        if k > 0:
            fill_F(F, steps.C[k - 1], steps.f_n[k - 1], steps.v[k - 1], steps.lat[k - 1],
                   steps.h[k - 1], m.kernel_params())
            discretize(F, steps.dt[k - 1], m.qc(), Phi, Q)
            kf.predict(F=Phi.copy(), Q=Q.copy())
        while j < refs.step.size and refs.step[j] == k:
            kf.update(refs.z[j], R=np.diag(refs.r[j]))
            assert kf.y == pytest.approx(res.nu[j], rel=1e-6, abs=1e-9)
            j += 1
    assert j == 3500
    sd = np.sqrt(np.diag(kf.P))
    np.testing.assert_allclose(res.sd[K], sd, rtol=1e-6)
    assert np.max(np.abs(res.x[K] - kf.x) / sd) < 1e-5


@pytest.fixture(scope="module")
def nominal():
    """30 min of cruise_turns under the model's assumptions (no scale-factor / misalignment
    error, white GNSS noise without latency), navigation grade, baro-damped INS."""
    fl = flight("cruise_turns", 1800.0, "navigation", "baro", 4, ideal_gnss=True, scale=False)
    inp = from_flight(fl)
    m = Ins3dModel.from_grade("navigation")
    P0 = m.p0_aligned(inp.steps.C[0], inp.steps.f_n[0], inp.steps.lat[0])
    return inp, truth_from_flight(fl, inp), m, run_forward(m, inp.steps, inp.refs, P0=P0,
                                                           keep_cov=True)


def test_beta2_is_chi2_on_a_nominal_flight(nominal):
    inp, _, m, res = nominal
    assert res.beta2.size == 18000
    assert res.beta2.mean() == pytest.approx(2.0, abs=0.08)
    np.testing.assert_allclose(res.beta2_row.mean(axis=0), 1.0, atol=0.06)
    assert res.exceeded.mean() < 3e-3                   # the gate's per-sample 1e-3
    assert not np.any(res.alarm == 1)                   # 3 of 5: no alarm on a nominal flight


def test_estimation_errors_are_consistent_with_the_covariance(nominal):
    inp, tr, m, res = nominal
    idx = inp.refs.step
    keep = [i for i in range(12) if i != 2]             # dv_U: not measured, Markov model only
    e = (res.x[idx] - tr["x"][idx, :12])[:, keep]
    P = res.P_post[:, keep][:, :, keep]
    nees = np.einsum("ki,kij,kj->k", e, np.linalg.inv(P), e)
    second = nees[idx.size // 2:]
    print(f"NEES mean {second.mean():.2f} (dof 11)")
    assert 4.0 < second.mean() < 25.0                   # one flight: strongly correlated errors
    z_end = e[-1] / np.sqrt(np.diagonal(P[-1]))
    assert np.all(np.abs(z_end) < 4.0), z_end


def test_turns_make_heading_and_vertical_sensors_observable(nominal):
    inp, tr, m, res = nominal
    t = res.t
    before, after = np.searchsorted(t, 295.0), np.searchsorted(t, 420.0)
    # the first turn (90 deg right, 25 deg bank) starts at 300 s
    for i in (5, 8):                                    # phi_U, ba_z (through the bank)
        assert res.sd[after, i] < 0.5 * res.sd[before, i], m.names[i]
    assert res.sd[-1, 11] < 0.7 * res.sd[before, 11]    # bg_z: heading drift between turns
    assert abs(res.x[-1, 5] - tr["x"][-1, 5]) < 3 * res.sd[-1, 5]
    # the same aircraft flying straight learns none of them
    fl = flight("straight", 1800.0, "navigation", "baro", 4, ideal_gnss=True, scale=False)
    inp_s = from_flight(fl)
    st = run_forward(m, inp_s.steps, inp_s.refs)
    assert st.sd[-1, 5] > 0.6 * st.sd[0, 5]
    # (ba_z: 4 % -- its prior includes the 1-g scale error; the 2-deg angle of attack leaks it)
    assert st.sd[-1, 8] > 0.95 * st.sd[0, 8] and st.sd[-1, 11] > 0.98 * st.sd[0, 11]


def test_reference_jump_is_flagged_on_its_row_and_rejected():
    fl = flight("cruise_turns", 900.0, "navigation", "baro", 5, ideal_gnss=True, scale=False,
                faults=("ref:jump:t=600,mag=0.3,axis=y",))
    inp = from_flight(fl)
    m = Ins3dModel.from_grade("navigation", rows=3)
    flag = run_forward(m, inp.steps, inp.refs)
    rej = run_forward(m, inp.steps, inp.refs, gate=GateConfig(action="reject"))
    after = (flag.t_ref >= 600.0) & (flag.t_ref < 602.0)
    assert flag.exceeded_row[after, 1].mean() > 0.9     # the north row
    assert flag.exceeded_row[after][:, [0, 2]].mean() < 0.1
    assert np.any(flag.alarm[(flag.t_ref >= 600.0) & (flag.t_ref < 601.0)] == 1)
    assert not np.any(flag.alarm[flag.t_ref < 600.0] == 1)
    # the flag filter absorbs the jump over time; the rejecting one keeps gating it
    late = flag.t_ref > 700.0
    assert rej.exceeded[late].mean() > 0.9 > flag.exceeded[late].mean()


def test_latency_state_estimates_the_reference_latency():
    """Default GNSS (white + Markov noise, 20 ms latency; scale factor and misalignment on):
    the latency state finds the 20 ms from the turns; without it the turns inflate beta^2."""
    fl = flight("cruise_turns", 1200.0, "navigation", "baro", 2)
    inp = from_flight(fl)
    out = {}
    for lat in (False, True):
        m = Ins3dModel.from_grade("navigation", latency=lat)
        P0 = m.p0_aligned(inp.steps.C[0], inp.steps.f_n[0], inp.steps.lat[0])
        out[lat] = run_forward(m, inp.steps, inp.refs, P0=P0)
    r = out[True]
    assert r.names[-1] == "latency"
    assert r.x[-1, -1] == pytest.approx(0.020, abs=max(3 * r.sd[-1, -1], 1e-3))
    assert r.sd[-1, -1] < 1e-3 < r.sd[np.searchsorted(r.t, 295.0), -1]   # learnt in the turn
    turn = (r.t_ref > 300.0) & (r.t_ref < 375.0)
    assert out[False].beta2[turn].mean() > 1.5 * r.beta2[turn].mean()
    assert not np.any(r.alarm == 1)


def test_reference_markov_states_make_the_filter_consistent_on_correlated_gnss():
    """Default GNSS (white + 30-s Markov noise, 20 ms latency), no scale-factor error: fused as
    white, the errors are ~20x their sigma (NEES in the hundreds); with the Markov states and the
    latency state beta^2 is chi^2(2) and the NEES matches its 11 dof."""
    fl = flight("cruise_turns", 1800.0, "navigation", "baro", 5, scale=False)
    inp = from_flight(fl)
    tr = truth_from_flight(fl, inp)
    keep = [i for i in range(12) if i != 2]
    nees = {}
    for mk in (None, (0.02, 0.03, 30.0)):
        m = Ins3dModel.from_grade("navigation", latency=True, ref_markov=mk)
        P0 = m.p0_aligned(inp.steps.C[0], inp.steps.f_n[0], inp.steps.lat[0])
        res = run_forward(m, inp.steps, inp.refs, P0=P0, keep_cov=True)
        idx = inp.refs.step
        e = (res.x[idx, :12] - tr["x"][idx, :12])[:, keep]
        P = res.P_post[:, keep][:, :, keep]
        nees[mk] = np.einsum("ki,kij,kj->k", e, np.linalg.inv(P), e)[idx.size // 2:].mean()
    assert m.names[12:] == ("ref_m_e", "ref_m_n", "latency")
    assert res.beta2.mean() == pytest.approx(2.0, abs=0.08)
    assert not np.any(res.alarm == 1)
    assert res.x[-1, -1] == pytest.approx(0.020, abs=3 * res.sd[-1, -1])
    print({k: round(v, 1) for k, v in nees.items()})
    assert nees[(0.02, 0.03, 30.0)] < 25.0 < 100.0 < nees[None]


def test_discretisation_ahead_on_a_second_thread_gives_the_same_pass():
    """``threads=2``: the Phi', Qd' of the next chunk of steps (64-512) are computed on a second
    thread while the filter takes the current ones -- the same kernels, so the same numbers as
    one thread, bit for bit (on the 20-Hz grid: 12 000 steps; with the reject action, which
    keeps the gains of rejected updates too)."""
    inp = from_flight(flight("cruise_turns", 600.0, "tactical", "baro", 3,
                             faults=("ref:jump:t=300,mag=2,axis=x",)))
    m = Ins3dModel.from_grade("tactical", rows=3)
    gate = GateConfig(action="reject")
    one = run_forward(m, inp.steps, inp.refs, gate=gate, keep_cov=True, keep_prior=True,
                      threads=1)
    two = run_forward(m, inp.steps, inp.refs, gate=gate, keep_cov=True, keep_prior=True,
                      threads=2)
    assert len(inp.steps) > 20 * 512 and not one.fused.all()
    for k in ("x", "sd", "nu", "S", "beta2", "beta2_row", "exceeded", "P_post", "xs_prior",
              "Ps_prior", "Ks", "S_inv"):
        np.testing.assert_array_equal(getattr(one, k), getattr(two, k), err_msg=k)


def test_kept_priors_and_gains_are_the_scaled_filter_quantities():
    """x_prior, P_prior (physical) = T xs_prior, T Ps_prior T; Ks = T^-1 P H' S^-1 and
    S_inv = S^-1 of every update (H with the latency and Markov columns)."""
    inp = from_flight(flight("cruise_turns", 300.0, "navigation", "baro", 2))
    m = Ins3dModel.from_grade("navigation", rows=2, latency=True,
                              ref_markov=(0.02, 0.03, 30.0))
    res = run_forward(m, inp.steps, inp.refs, keep_prior=True)
    s = np.sqrt(m.p0())
    np.testing.assert_allclose(res.x_prior, res.xs_prior * s, rtol=1e-15)
    np.testing.assert_allclose(res.P_prior, res.Ps_prior * np.outer(s, s), rtol=1e-15)
    order = np.argsort(inp.refs.step, kind="stable")
    for j in (0, 1, 777, inp.refs.t.size - 1):
        H = m.H(inp.refs.a[order][j])
        P = res.P_prior[j]
        S = H @ P @ H.T + np.diag(white_variance(m, inp.refs.r[order][j][None])[0][:m.rows])
        np.testing.assert_allclose(res.S[j], S, rtol=1e-12)
        np.testing.assert_allclose(res.S_inv[j], np.linalg.inv(S), rtol=1e-10)
        np.testing.assert_allclose(res.Ks[j] * s[:, None], P @ H.T @ np.linalg.inv(S),
                                   rtol=1e-9, atol=1e-12 * np.abs(P @ H.T).max())
