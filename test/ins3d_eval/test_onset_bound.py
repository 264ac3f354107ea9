"""The onset's information bounds (flight_fdi/eval/onset_bound.py): known answers first -- an
integrator fault seen without a filter (closed form), and a Kalman filter's innovation form equal
to the batch Gaussian form of the same measurements -- then the ins3d flight: the central
difference converges, I_bb equals the GLR's own information, the bound scales like 1/b, an
accelerometer step's onset is far better determined than a gyro step's of the same
detectability, and the Hammersley-Chapman-Robbins bound is at least the Cramer-Rao one."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.onset_bound import (OnsetFisher, Signatures, analyse_case, fisher_onset,
                                         hcr_bound, synthetic_onsets, window_mass)

DEG_H = math.radians(1.0) / 3600.0
MG = 9.80665e-3


# --------------------------------------------------------------------------- closed forms

def test_integrator_seen_without_a_filter_matches_the_closed_form():
    """nu_k = z_k (no gain), rho_k = (t_k - tau)_+: I_tt = b^2 N / sigma^2 (N samples after
    the onset), I_tb = -b sum u / sigma^2, I_bb = sum u^2 / sigma^2 (u = t_k - tau); with b
    estimated the sd doubles as N grows (N - (N T / 2)^2 / (N T^2 / 3) = N / 4)."""
    sigma, b, h = 0.05, 0.02, 0.1
    t = np.arange(0.0, 400.0, h)
    tau, delta = 100.03, 0.01                       # no sample within delta of the onset
    rho = lambda s: np.maximum(t - s, 0.0)[:, None]   # noqa: E731
    S_inv = np.full((t.size, 1, 1), 1.0 / sigma**2)
    f = fisher_onset(rho(tau - delta), rho(tau), rho(tau + delta), S_inv, delta, b)
    u = t[t > tau] - tau
    assert f.I_tt == pytest.approx(b * b * u.size / sigma**2, rel=1e-10)
    assert f.I_tb == pytest.approx(-b * u.sum() / sigma**2, rel=1e-10)
    assert f.I_bb == pytest.approx((u * u).sum() / sigma**2, rel=1e-10)
    assert f.sd_known == pytest.approx(sigma / (b * math.sqrt(u.size)), rel=1e-10)
    assert f.sd_joint / f.sd_known == pytest.approx(2.0, rel=2e-3)
    assert f.expected_glr == pytest.approx(b * b * f.I_bb)
    with pytest.raises(EvalError):
        fisher_onset(rho(tau), rho(tau), rho(tau), S_inv, 0.0, b)


def _kalman_model(n_steps=80, dt=0.5):
    """v' = bias + fault, bias a random walk; z = v + noise. Phi, Q, H, R, P0."""
    Phi = np.array([[1.0, dt], [0.0, 1.0]])
    Q = np.array([[0.02**2 * dt, 0.0], [0.0, 0.004**2 * dt]])
    H = np.array([[1.0, 0.0]])
    return Phi, Q, H, np.array([[0.3**2]]), np.diag([0.5**2, 0.05**2]), n_steps, dt


def _fault_input(tau, k, dt):
    """The velocity a unit step of acceleration from tau adds over step k (t_k = k dt)."""
    return np.array([max(0.0, (k + 1) * dt - max(tau, k * dt)), 0.0])


def _innovation_signature(tau, model):
    """Kalman filter of the no-fault model; the Willsky-Jones signature of a unit fault
    (mu <- Phi mu + Gamma, rho = H mu, mu <- mu - K rho: measurement k at t_k = k dt, after
    step k - 1) and S_k^-1."""
    Phi, Q, H, R, P0, N, dt = model
    P, mu = P0.copy(), np.zeros(2)
    rho, S_inv = np.empty((N, 1)), np.empty((N, 1, 1))
    for k in range(N):
        if k:
            P = Phi @ P @ Phi.T + Q
            mu = Phi @ mu + _fault_input(tau, k - 1, dt)
        S = H @ P @ H.T + R
        K = P @ H.T @ np.linalg.inv(S)
        rho[k] = H @ mu
        S_inv[k] = np.linalg.inv(S)
        mu = mu - K @ rho[k]
        P = (np.eye(2) - K @ H) @ P
    return rho, S_inv


def _batch_fisher(tau, delta, b, model):
    """The same Fisher matrix from the measurements' joint Gaussian: mean b m(tau) (the fault's
    open-loop effect H x_fault(t_k)), covariance from P0, Q, R."""
    Phi, Q, H, R, P0, N, dt = model
    A = [np.eye(2)]                                 # x_k = Phi^k x0 + sum Phi^(k-1-i) w_i
    for _ in range(N):
        A.append(Phi @ A[-1])
    C = np.zeros((N, N))
    for i in range(N):
        for j in range(N):
            Pij = A[i] @ P0 @ A[j].T
            for m in range(min(i, j)):
                Pij = Pij + A[i - 1 - m] @ Q @ A[j - 1 - m].T
            C[i, j] = (H @ Pij @ H.T)[0, 0] + (R[0, 0] if i == j else 0.0)

    def mean(s):
        x, out = np.zeros(2), np.empty(N)
        for k in range(N):
            if k:
                x = Phi @ x + _fault_input(s, k - 1, dt)
            out[k] = (H @ x)[0]
        return out

    m, dm = mean(tau), (mean(tau + delta) - mean(tau - delta)) / (2 * delta)
    Ci = np.linalg.inv(C)
    return b * b * dm @ Ci @ dm, b * dm @ Ci @ m, m @ Ci @ m


def test_innovation_form_equals_the_batch_gaussian_form():
    """Whitening by the Kalman filter loses no information: the Fisher matrix of (onset, b) from
    the filter's signature and S_k equals the one of the stacked measurements' Gaussian."""
    model = _kalman_model()
    tau, delta, b = 12.3, 0.05, 0.07
    f = fisher_onset(*(_innovation_signature(s, model)[0] for s in (tau - delta, tau,
                                                                     tau + delta)),
                     _innovation_signature(tau, model)[1], delta, b)
    I_tt, I_tb, I_bb = _batch_fisher(tau, delta, b, model)
    assert f.I_tt == pytest.approx(I_tt, rel=1e-8)
    assert f.I_tb == pytest.approx(I_tb, rel=1e-8)
    assert f.I_bb == pytest.approx(I_bb, rel=1e-8)
    assert f.sd_joint > f.sd_known


def test_hcr_tends_to_the_cramer_rao_bound_and_is_at_least_it():
    model = _kalman_model()
    tau, b = 12.3, 0.07
    rho, S_inv = _innovation_signature(tau, model)
    f = fisher_onset(_innovation_signature(tau - 1e-3, model)[0], rho,
                     _innovation_signature(tau + 1e-3, model)[0], S_inv, 1e-3, b)
    small = hcr_bound(rho, {h: _innovation_signature(tau + h, model)[0] for h in (-1e-3, 1e-3)},
                      S_inv, b)
    assert small["sd_known_s"] == pytest.approx(f.sd_known, rel=1e-3)
    wide = hcr_bound(rho, {h: _innovation_signature(tau + h, model)[0]
                           for h in (-5.0, -1.0, -1e-3, 1e-3, 1.0, 5.0)}, S_inv, b)
    assert wide["sd_known_s"] >= small["sd_known_s"]
    assert wide["sd_profiled_s"] >= wide["sd_known_s"]


def test_window_mass_of_a_gaussian_posterior():
    t = np.arange(-200.0, 200.0, 0.1)
    sd, w = 20.0, 5.0
    got = window_mass(t, -0.5 * ((t - 3.0) / sd) ** 2, w)
    assert got == pytest.approx(math.erf(w / (sd * math.sqrt(2.0))), abs=3e-3)
    assert window_mass(t, np.zeros_like(t), 200.0) == pytest.approx(1.0)


def test_bounds_of_a_fisher_matrix():
    f = OnsetFisher(I_tt=4.0, I_tb=1.0, I_bb=1.0, b=2.0, delta_s=0.1)
    assert f.sd_known == 0.5
    assert f.sd_joint == pytest.approx(1.0 / math.sqrt(3.0))
    assert f.expected_glr == 4.0
    assert OnsetFisher(0.0, 0.0, 1.0, 1.0, 0.1).sd_known == math.inf


# --------------------------------------------------------------------------- ins3d flight

@pytest.fixture(scope="module")
def sig():
    """600 s of cruise_turns (first turn 303-372 s), navigation grade, nominal."""
    from flight_fdi.eval.montecarlo3d import Case3D, Study3DConfig

    cfg = Study3DConfig(nominal=1, per_scenario=0, duration_s=600.0, profile="cruise_turns",
                        single_axis=False)
    _, an = analyse_case(Case3D(0, "nominal", 11, 12), cfg)
    return Signatures(an)


def test_central_difference_converges_and_I_bb_is_the_glr_information(sig):
    fs = sig.fisher("gyro", "y", 200.0, 0.1 * DEG_H, deltas=(1, 2, 4, 16))
    sd = [f.sd_joint for f in fs]
    assert abs(sd[0] - sd[1]) / sd[0] < 1e-3
    assert abs(sd[0] - sd[1]) < abs(sd[1] - sd[2]) < abs(sd[2] - sd[3])
    c = sig.an.glr["gyro_y_step"]
    k = int(np.argmin(np.abs(c.t - sig.t[sig.boundary(200.0)])))
    assert fs[0].I_bb == pytest.approx(1.0 / c.sd[k] ** 2, rel=1e-6)


def test_bound_scales_like_one_over_b(sig):
    a, b = (sig.fisher("gyro", "x", 150.0, s * DEG_H)[0] for s in (0.05, 0.2))
    assert a.sd_known / b.sd_known == pytest.approx(4.0, rel=1e-9)
    assert a.sd_joint / b.sd_joint == pytest.approx(4.0, rel=1e-9)
    assert b.expected_glr / a.expected_glr == pytest.approx(16.0, rel=1e-9)
    with pytest.raises(EvalError):
        sig.fisher("magnetometer", "x", 150.0, 1.0)


def test_accelerometer_onset_far_sharper_than_a_gyro_onset_equally_detectable(sig):
    """Sizes giving an expected GLR of 200 each: the accelerometer step's velocity signature
    rises within the filter's time constant, the gyro's grows from zero through the tilt (here
    3.7 s against 11.4 s on 450 s of flight after the onset; on the 2-h flights 5 s against
    ~50 s: docs/ins3d_onset_bound.md)."""
    out = {}
    for sensor, unit in (("accelerometer", MG), ("gyro", DEG_H)):
        f1 = sig.fisher(sensor, "x", 150.0, unit)[0]
        b = math.sqrt(200.0 / f1.I_bb)
        out[sensor] = sig.fisher(sensor, "x", 150.0, b)[0]
        assert out[sensor].expected_glr == pytest.approx(200.0)
    assert out["accelerometer"].sd_joint < 0.4 * out["gyro"].sd_joint
    h = sig.hcr("gyro", "x", 150.0, out["gyro"].b)
    assert h["sd_known_s"] >= 0.99 * out["gyro"].sd_known
    assert h["sd_profiled_s"] >= h["sd_known_s"]


def test_model_drawn_glr_onset_near_the_truth_for_a_large_step(sig):
    b = 1.0 * DEG_H
    got = synthetic_onsets(sig, "gyro", "y", 200.0, b, 1, np.random.default_rng(3),
                           (60.0, 480.0))
    assert abs(got["mle"][0] - 200.0) < 3.0 * sig.fisher("gyro", "y", 200.0, b)[0].sd_joint
    assert 0.0 < got["p_marginal"][0] <= 1.0 and 0.0 < got["p_known"][0] <= 1.0


# --------------------------------------------------------------------------- the tool

def _tool():
    import importlib.util
    from pathlib import Path

    path = Path(__file__).resolve().parents[2] / "tools" / "ins3d_onset_bound.py"
    spec = importlib.util.spec_from_file_location("ins3d_onset_bound", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def test_tool_on_one_flight_of_the_20min_study(tmp_path, capsys):
    """The 20-min study's first gyro-step flight (x, 0.05 deg/h): a record with the bounds at
    the three half steps, the HCR, one model draw, and the two tables."""
    tool = _tool()
    args = ["--study", "20min", "--only", "study", "--per", "gyro_step=1", "--reps", "1",
            "--out", str(tmp_path)]
    assert tool.main(args) == 0
    from flight_fdi.eval.records import read_records

    study, recs = read_records(tmp_path / "study_20min.jsonl", key="key")
    assert study["reps"] == 1 and len(recs) == 1
    r = recs[0]
    assert (r["scenario"], r["axis"], r["level"]) == ("gyro_step", "x", 0.05)
    assert [b["delta_s"] for b in r["bounds"]] == pytest.approx([0.1, 0.2, 0.5])
    assert r["bounds"][0]["sd_joint_s"] > 5.0
    assert r["hcr"]["sd_profiled_s"] >= 0.99 * r["bounds"][0]["sd_joint_s"]
    assert len(r["synthetic"]["mle"]) == 1
    tables = (tmp_path / "tables_20min.md").read_text()
    assert "| gyro_step | x | 0.05 deg/h | 1 |" in tables and "best estimator" in tables
    assert tool.main(args + ["--render-only"]) == 0        # the same tables from the records
    assert (tmp_path / "tables_20min.md").read_text() == tables
    with pytest.raises(SystemExit, match="bad --per item"):
        tool.main(["--per", "gyro_ramp=3", "--out", str(tmp_path)])
