"""GLR over the body-axis hypotheses: the one-sweep statistics of every onset (backward
information on the state augmented with the fault) against brute force for fixed onsets -- the
forward signature recursion and FilterPy running the augmented state with the fault as a
diffuse constant state from the onset."""
from __future__ import annotations

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from flight_fdi.core.ins3d.backward import REF, fault_gamma
from flight_fdi.core.ins3d.filter import white_variance
from flight_fdi.core.ins3d.glr3d import (AMBIGUITY_MARGIN, GlrCurve, hypotheses, isolate,
                                         resolved_time)
from flight_fdi.core.ins3d.postflight import data_up_to

from .test_backward import phi_q, short_analysis

CASES = [("accelerometer_y_step", 150.0), ("gyro_z_step", 330.0), ("gyro_x_ramp", 250.0),
         ("accelerometer_z_ramp", 360.0), ("reference_east_jump", 300.0)]


@pytest.fixture(scope="module")
def faulty():
    """A gyro x step of 0.5 deg/h at 200 s before the first turn (303 s)."""
    return short_analysis(faults=("gyro:step:t=200,mag=0.5deg/h,axis=x",), seed=6)


def _at_onset(cv: GlrCurve, t: float) -> GlrCurve:
    """The curve with its 'best' onset forced to the onset nearest t."""
    k = int(np.argmin(np.abs(cv.t - t)))
    stat = np.zeros_like(cv.stat)
    stat[k] = 1.0
    return GlrCurve(cv.hypothesis, cv.t, stat, cv.mag, cv.sd), k


@pytest.mark.parametrize("name,t_onset", CASES)
def test_backward_glr_equals_the_forward_signature(faulty, name, t_onset):
    a = faulty
    cv, k = _at_onset(a.glr[name], t_onset)
    glr_t = data_up_to(a.model, a.steps, a.refs, a.forward, cv)
    assert glr_t[-1] == pytest.approx(a.glr[name].stat[k], rel=1e-6, abs=1e-9)
    assert np.all(glr_t[a.refs.t < cv.t[k] - 1e-9] == 0.0)


def test_backward_glr_equals_filterpy_with_the_fault_as_a_state(faulty):
    """FilterPy on [x; b] with b a constant state of prior sd 300 x the GLR sd from the onset on
    (Gamma_k through the same F): its final b and sd equal b^(theta) and sd(b^)."""
    a = faulty
    m, steps, refs = a.model, a.steps, a.refs
    R = white_variance(m, refs.r)
    P0 = m.p0_aligned(steps.C[0], steps.f_n[0], float(steps.lat[0]))
    t_start = float(steps.t[0])
    for name, t_onset in CASES[:3] + CASES[4:]:
        cv, k = _at_onset(a.glr[name], t_onset)
        h = cv.hypothesis
        k0 = int(np.searchsorted(steps.t, cv.t[k] - 1e-9))
        sd_b = float(cv.sd[k])
        n = m.n
        kf = KalmanFilter(dim_x=n + 1, dim_z=m.rows)
        kf.x = np.zeros(n + 1)
        kf.P = np.zeros((n + 1, n + 1))
        kf.P[:n, :n] = P0
        kf.P[n, n] = (300.0 * sd_b) ** 2
        sB = np.ones(12 + m.rows)
        G = np.empty((n, sB.size))
        j = 0
        for kk in range(len(steps) + 1):
            if kk > 0:
                F, Phi, Q = phi_q(m, steps, kk - 1)
                fault_gamma(F, float(steps.dt[kk - 1]), float(steps.t[kk - 1] - t_start),
                            np.ones(n), sB, G)
                Fa = np.eye(n + 1)
                Fa[:n, :n] = Phi
                if kk - 1 >= k0:        # the fault acts from the onset on (SI: sB = 1)
                    Fa[:n, n] = G[:, h.column]
                    if h.kind == "ramp":            # r (t - theta) = r t~ - r theta~
                        Fa[:n, n] -= (cv.t[k] - t_start) * G[:, h.column - 3]
                Qa = np.zeros((n + 1, n + 1))
                Qa[:n, :n] = Q
                kf.predict(F=Fa, Q=Qa)
            while j < refs.t.size and refs.step[j] == kk:
                H = np.zeros((m.rows, n + 1))
                H[:, :n] = m.H(refs.a[j])
                if h.sensor == "reference" and kk >= k0:
                    H[h.column - REF, n] = 1.0
                kf.update(refs.z[j, :m.rows], R=np.diag(R[j, :m.rows]), H=H)
                j += 1
        b_fp, sd_fp = kf.x[n], np.sqrt(kf.P[n, n])
        print(f"{name} at {cv.t[k]:.1f}: GLR b {cv.mag[k]:.6g} sd {sd_b:.4g}; "
              f"FilterPy b {b_fp:.6g} sd {sd_fp:.4g}")
        assert b_fp == pytest.approx(cv.mag[k], rel=2e-4, abs=1e-3 * sd_b)
        assert sd_fp == pytest.approx(sd_b, rel=2e-4)


def test_gyro_step_before_a_turn_is_isolated_with_the_ambiguity_resolved(faulty):
    a = faulty
    pf = a.post_flight_dict()
    f = pf["fault"]
    print(pf["headline"])
    assert pf["isolation"] == "single" and f["sensor"] == "gyro" and f["axis"] == "x"
    assert f["kind"] == "step"
    assert f["magnitude_eng"] == pytest.approx(0.5, rel=0.3)
    assert abs(f["onset_s"] - 200.0) < 30.0
    lo, hi = f["onset_interval_s"]
    assert lo <= f["onset_s"] <= hi
    assert pf["ambiguity_resolved_s"] is not None and pf["ambiguity_resolved_s"] >= f["onset_s"]


def test_joint_statistic_is_at_least_each_axis_and_equals_it_for_one_axis(faulty):
    """The 3-dof GLR of a sensor's step is >= every one-axis GLR at the same onset, and the
    brute force: eta' I^-1 eta of the 3 x 3 block."""
    a = faulty
    b = a.backward
    f = b.first
    for sensor in ("accelerometer", "gyro"):
        j = a.joint[sensor + "_step"]
        for ax in "xyz":
            assert np.all(j >= a.glr[f"{sensor}_{ax}_step"].stat * (1 - 1e-9) - 1e-9)
        g = 0 if sensor == "accelerometer" else 1
        k = len(f) // 2
        e = b.eta[f[k], 6 * g:6 * g + 3]
        assert j[k] == pytest.approx(e @ np.linalg.solve(b.I3[f[k], g, :3, :3], e), rel=1e-9)
    assert a.post_flight_dict()["glr"]["joint"]["gyro_step"] == pytest.approx(
        a.joint["gyro_step"].max())


def test_isolation_rules():
    """Synthetic curves: single, ambiguous within the margin, outliers only, none."""
    hyps = {h.name: h for h in hypotheses(2)}
    t = np.arange(5.0)

    def cv(name, peak):
        return GlrCurve(hyps[name], t, np.array([0, 1, peak, 1, 0.0]), np.ones(5), np.ones(5))

    thr = {"step": 20.0, "ramp": 20.0, "jump": 20.0, "outliers": 30.0}
    base = {n: cv(n, 1.0) for n in hyps}
    one = dict(base, gyro_x_step=cv("gyro_x_step", 100.0), accelerometer_y_ramp=cv(
        "accelerometer_y_ramp", 100.0 - AMBIGUITY_MARGIN - 1.0))
    iso = isolate(one, thr)
    assert (iso.isolation, iso.best, iso.rival) == ("single", "gyro_x_step",
                                                    "accelerometer_y_ramp")
    two = dict(one, accelerometer_y_ramp=cv("accelerometer_y_ramp", 95.0))
    assert isolate(two, thr).isolation == "ambiguous"
    same = dict(base, gyro_x_step=cv("gyro_x_step", 100.0), gyro_x_ramp=cv("gyro_x_ramp", 99.0))
    iso = isolate(same, thr)                 # step or ramp of one axis: the simpler shape
    assert (iso.isolation, iso.best) == ("single", "gyro_x_step")
    clear = dict(same, gyro_x_ramp=cv("gyro_x_ramp", 100.0 + AMBIGUITY_MARGIN + 1.0))
    assert isolate(clear, thr).best == "gyro_x_ramp"
    out = dict(base, reference_east_outliers=cv("reference_east_outliers", 50.0))
    iso = isolate(out, thr)
    assert (iso.isolation, iso.best, iso.outliers) == ("single", "reference_east_outliers", 1)
    assert isolate(base, thr).isolation == "none"
    gap = np.array([0.0, 12.0, 5.0, 10.0, 11.0])
    assert resolved_time(t, gap) == 3.0
    assert resolved_time(t, np.array([0.0, 12.0, 5.0, 10.0, 1.0])) is None


def test_joint_statistic_equals_numpy_pinv():
    """The 3-dof statistic e' I^+ e (numba Jacobi kernel) against numpy's pinv(rcond=1e-10,
    hermitian=True): random symmetric matrices with eigenvalues over 8 decades, a third of them
    exactly singular, a third with an eigenvalue below the cut (1e-12 of the largest: dropped),
    and the flight's own information blocks."""
    from flight_fdi.core.ins3d.glr3d import joint
    rng = np.random.default_rng(11)
    V = np.linalg.qr(rng.normal(size=(300, 3, 3)))[0]
    lam = np.abs(rng.normal(size=(300, 3))) * 10.0 ** rng.uniform(-6, 2, size=(300, 3))
    lam[::3, 0] = 0.0
    lam[1::3, 1] = 1e-12 * lam[1::3][:, [0, 2]].max(axis=1)
    info = np.einsum("kij,kj,klj->kil", V, lam, V)
    I3 = np.zeros((300, 3, 6, 6))
    I3[:, 0, :3, :3] = info
    eta = rng.normal(size=(300, REF + 3))
    ref = np.einsum("ki,kij,kj->k", eta[:, :3],
                    np.linalg.pinv(info, rcond=1e-10, hermitian=True), eta[:, :3])
    got = joint(eta, I3, 3)["accelerometer_step"]
    np.testing.assert_allclose(got, ref, rtol=1e-5)   # numpy: eps x cond (1e8) on small eigenvalues
    u = np.einsum("kij,ki->kj", V, eta[:, :3])          # the dropped direction carries nothing
    keep = np.ones((300, 3), dtype=bool)
    keep[::3, 0] = keep[1::3, 1] = False
    np.testing.assert_allclose(got, np.sum(np.where(keep, u * u / np.where(keep, lam, 1), 0),
                                           axis=1), rtol=1e-7)
    a = short_analysis()
    f = a.backward.first
    e, I = a.backward.eta[f], a.backward.I3[f]
    for name, g in (("accelerometer_step", 0), ("gyro_step", 1)):
        ref = np.einsum("ki,kij,kj->k", e[:, 6 * g:6 * g + 3],
                        np.linalg.pinv(I[:, g, :3, :3], rcond=1e-10, hermitian=True),
                        e[:, 6 * g:6 * g + 3])
        np.testing.assert_allclose(joint(e, I, 2)[name], ref, rtol=1e-5, atol=1e-9)
