"""The simulator: truth statistics match the model, faults act as specified (closed forms)."""
from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from flight_fdi.core.models import ins_channel
from flight_fdi.sim import FlightProfile, SimConfig, SimError, parse_fault, propagate, simulate
from flight_fdi.sim.ins import psd_sqrt

G = 9.80665
R_E = 6_371_000.0
W_S = math.sqrt(G / R_E)  # Schuler frequency
DPH = math.pi / 180 / 3600
IV, IT, IA, IW = 0, 1, 2, 3  # velocity_error, tilt, accel_bias, gyro_drift


def test_state_order_is_the_models():
    assert ins_channel().state_names == ("velocity_error", "tilt", "accel_bias", "gyro_drift")


@pytest.mark.parametrize("N", [2, 3, 17, 1000, 1001])
def test_propagate_equals_the_plain_recursion(N):
    rng = np.random.default_rng(N)
    Phi = np.eye(4) + 0.05 * rng.normal(size=(4, 4))
    x0 = rng.normal(size=4)
    u = rng.normal(size=(N - 1, 4))
    want = np.empty((N, 4))
    want[0] = x0
    for k in range(N - 1):
        want[k + 1] = Phi @ want[k] + u[k]
    assert np.allclose(propagate(Phi, x0, u), want, rtol=1e-10, atol=1e-10)


def test_psd_sqrt_of_a_singular_badly_scaled_covariance():
    model = ins_channel()
    _, Qd, _ = model.discretize(0.02)  # rank 2: only the biases are driven; entries 1e-6..1e-26
    L = psd_sqrt(Qd, model.scale)
    s = np.outer(model.scale, model.scale)
    assert np.allclose((L @ L.T) / s, Qd / s, rtol=1e-9, atol=1e-18)
    with pytest.raises(SimError, match="not positive semidefinite"):
        psd_sqrt(np.diag([1.0, -1.0]))


def test_gauss_markov_biases_have_the_model_statistics():
    """Stationary variance sigma^2 and lag-1 correlation exp(-dt/tau) of both GM states."""
    tau, dt = 5.0, 0.1
    fl = simulate(SimConfig(duration_s=2000, ins_rate_hz=1 / dt, ref_rate_hz=1 / dt,
                            truth_rate_hz=1 / dt, seed=11,
                            model_params={"tau_a": tau, "tau_w": tau}))
    sigma_a, sigma_w = 1e-3, 0.01 * DPH
    for axis in (0, 1):
        for idx, sigma in ((IA, sigma_a), (IW, sigma_w)):
            b = fl.x_true[axis, :, idx]
            # about 200 independent samples: the variance is known to ~10 %
            assert 0.7 < np.var(b) / sigma**2 < 1.3
            rho = np.corrcoef(b[:-1], b[1:])[0, 1]
            assert abs(rho - math.exp(-dt / tau)) < 0.005


def test_ensemble_covariance_follows_the_continuous_lyapunov_equation():
    """300 seeded flights: the covariance of the truth state after 600 s equals the solution of
    dP/dt = A P + P A^T + Qc from P0 (integrated numerically, independent of Van Loan)."""
    model = ins_channel()
    T = np.diag(model.scale)
    Ti = np.linalg.inv(T)
    As, Qs, P0s = Ti @ model.A @ T, Ti @ model.Qc @ Ti, Ti @ model.P0 @ Ti
    t_end = 599.0

    def rhs(_, p):
        P = p.reshape(4, 4)
        return (As @ P + P @ As.T + Qs).ravel()

    P = solve_ivp(rhs, (0, t_end), P0s.ravel(), rtol=1e-10, atol=1e-14).y[:, -1].reshape(4, 4)
    n = 300
    xs = np.array([simulate(SimConfig(duration_s=600, ins_rate_hz=1, ref_rate_hz=1,
                                      truth_rate_hz=1, seed=s)).x_true[0, -1] for s in range(n)])
    C = np.cov((xs @ Ti).T)
    se = np.sqrt((np.outer(np.diag(P), np.diag(P)) + P**2) / n)
    assert np.all(np.abs(C - P) < 5 * se), (C, P)
    # the dynamics matter over 600 s: the velocity variance has grown well beyond P0
    assert P[0, 0] > 10 * P0s[0, 0]


def _pair(fault: str, **kw):
    """(nominal, faulty) flights with one seed: they differ by the fault's effect only."""
    base = dict(duration_s=3000, ins_rate_hz=2, ref_rate_hz=1, truth_rate_hz=1, seed=5)
    base.update(kw)
    nominal = simulate(SimConfig(**base))
    faulty = simulate(SimConfig(**base, faults=(parse_fault(fault),)))
    return nominal, faulty


def test_accel_step_gives_the_schuler_response():
    b, t0 = 0.015, 500.0
    nom, flt = _pair(f"accel:step:t={t0},mag={b}")
    d = flt.x_true[0] - nom.x_true[0]
    tau = np.clip(flt.t - t0, 0, None)
    assert np.allclose(d[:, IA], np.where(flt.t >= t0, b, 0.0), rtol=0, atol=1e-15)
    assert np.allclose(d[:, IV], b / W_S * np.sin(W_S * tau), rtol=0, atol=1e-9)
    assert np.allclose(d[:, IT], b / G * (1 - np.cos(W_S * tau)), rtol=0, atol=1e-12)
    assert np.all(d[:, IW] == 0)
    assert np.array_equal(flt.x_true[1], nom.x_true[1])  # the y channel is untouched
    assert np.array_equal(flt.v_ins[:, 1], nom.v_ins[:, 1])
    assert np.allclose(flt.v_ins[:, 0] - nom.v_ins[:, 0], d[:, IV], rtol=0, atol=1e-12)


def test_gyro_step_gives_the_schuler_response():
    w, t0 = 10 * DPH, 500.0
    nom, flt = _pair(f"gyro:step:t={t0},mag=10deg/h")
    d = flt.x_true[0] - nom.x_true[0]
    tau = np.clip(flt.t - t0, 0, None)
    assert np.allclose(d[:, IW], np.where(flt.t >= t0, w, 0.0), rtol=0, atol=1e-20)
    assert np.allclose(d[:, IT], w / W_S * np.sin(W_S * tau), rtol=0, atol=1e-12)
    assert np.allclose(d[:, IV], -R_E * w * (1 - np.cos(W_S * tau)), rtol=0, atol=1e-8)
    assert np.all(d[:, IA] == 0)


def test_ended_step_on_y_is_the_difference_of_two_steps():
    b, t0, t1 = 0.01, 400.0, 1400.0
    nom, flt = _pair(f"accel:step:t={t0},end={t1},mag={b},axis=y")
    d = flt.x_true[1] - nom.x_true[1]
    on = lambda t_on: np.sin(W_S * np.clip(flt.t - t_on, 0, None))  # noqa: E731
    assert np.allclose(d[:, IV], b / W_S * (on(t0) - on(t1)), rtol=0, atol=1e-9)
    assert np.allclose(d[:, IA], np.where((flt.t >= t0) & (flt.t < t1), b, 0.0), rtol=0,
                       atol=1e-15)
    assert np.array_equal(flt.x_true[0], nom.x_true[0])


@pytest.mark.parametrize("fault,target,expected", [
    ("accel:ramp:t=100,end=2000,mag=1e-5", IA,
     lambda fl: np.where((fl.t >= 100) & (fl.t < 2000), 1e-5 * (fl.t - 100), 0.0)),
    ("gyro:sine:t=100,mag=5deg/h,freq=0.01", IW,
     lambda fl: np.where(fl.t >= 100, 5 * DPH * np.sin(2 * np.pi * 0.01 * (fl.t - 100)), 0.0)),
    ("gyro:square:t=100,mag=5deg/h,freq=0.01", IW,
     lambda fl: np.where(fl.t >= 100, np.where((fl.t - 100) % 100 < 50, 1, -1) * 5 * DPH, 0.0)),
    ("accel:stuck:t=100,mag=0", IA,
     lambda fl: np.where(fl.t >= 100, -fl.motion.specific_force[:, 0], 0.0)),
    ("accel:scale:t=100,mag=0.5", IA,
     lambda fl: np.where(fl.t >= 100, 0.5 * fl.motion.specific_force[:, 0], 0.0)),
    ("gyro:stuck:t=100,mag=1e-4", IW,
     lambda fl: np.where(fl.t >= 100, 1e-4 - fl.motion.angular_rate[:, 0], 0.0)),
    ("gyro:scale:t=100,mag=1", IW,
     lambda fl: np.where(fl.t >= 100, fl.motion.angular_rate[:, 0], 0.0)),
])
def test_instrument_faults_change_the_truth_as_specified(fault, target, expected):
    nom, flt = _pair(fault)
    d = flt.x_true[0] - nom.x_true[0]
    want = expected(flt)
    assert np.any(want != 0)
    # (GM bias + e) - GM bias: exact up to the rounding of the sum
    assert np.allclose(d[:, target], want, rtol=0, atol=1e-6 * np.max(np.abs(want)))
    other = IW if target == IA else IA
    assert np.all(d[:, other] == 0)
    assert np.any(d[:, IV] != 0)  # the error reaches the velocity the INS outputs
    assert np.array_equal(flt.fault_error[0, :, 0 if target == IA else 1], want)


def test_stuck_and_scale_faults_see_real_motion():
    """The profile gives non-zero specific force and angular rate, so these faults matter."""
    fl = simulate(SimConfig(duration_s=1000, seed=0))
    assert np.max(np.abs(fl.motion.specific_force)) > 2.0       # take-off, turns
    assert np.max(np.abs(fl.motion.angular_rate[:, 1])) > 0.01  # roll into the turns


def test_reference_noise_and_covariance():
    fl = simulate(SimConfig(duration_s=1000, seed=3, model_params={"sigma_ref": 0.2}))
    e = fl.v_ref - fl.motion.velocity[fl.ref_index]
    assert fl.sigma_ref == 0.2
    assert np.all(np.abs(np.std(e, axis=0) / 0.2 - 1) < 0.05)
    assert np.all(np.abs(np.mean(e, axis=0)) < 4 * 0.2 / math.sqrt(len(e)))
    assert abs(np.corrcoef(e[:, 0], e[:, 1])[0, 1]) < 0.05
    assert np.array_equal(fl.ref_index, np.arange(0, 50000, 5))


def test_reference_jump_and_outliers():
    nom, jump = _pair("ref:jump:t=1000,end=2000,mag=-2.5")
    d = jump.v_ref - nom.v_ref
    t = jump.t_ref
    assert np.allclose(d[:, 0], np.where((t >= 1000) & (t < 2000), -2.5, 0.0), rtol=0,
                       atol=1e-12)
    assert np.all(d[:, 1] == 0)
    assert np.array_equal(jump.v_ins, nom.v_ins)

    nom, out = _pair("ref:outliers:t=500,end=2500,mag=3,freq=0.1,axis=y")
    d = out.v_ref - nom.v_ref
    hit = d[:, 1] != 0
    assert np.array_equal(hit, out.ref_outlier[:, 1]) and not out.ref_outlier[:, 0].any()
    assert np.allclose(np.abs(d[hit, 1]), 3.0) and np.all(d[:, 0] == 0)
    t = out.t_ref
    assert np.all((t[hit] >= 500) & (t[hit] < 2500))
    n, p = 2000, 0.1  # 2000 reference samples in the window at 1 Hz, each hit with p = 0.1
    assert abs(hit.sum() - n * p) < 4 * math.sqrt(n * p * (1 - p))
    assert 0.3 < np.mean(d[hit, 1] > 0) < 0.7  # both signs


def test_reference_dropout_leaves_a_gap():
    nom, drop = _pair("ref:dropout:t=1000,end=1030.5")
    t = drop.t_ref
    assert not np.any((t >= 1000) & (t < 1030.5))
    assert len(nom.t_ref) - len(t) == 31  # 1000, 1001, ..., 1030
    kept = ~((nom.t_ref >= 1000) & (nom.t_ref < 1030.5))
    assert np.array_equal(drop.v_ref, nom.v_ref[kept])  # the noise of the others is unchanged


def test_profile_is_consistent():
    prof = FlightProfile(1000.0)
    t = np.arange(0, 1000, 0.01)
    m = prof.evaluate(t)
    dv = np.gradient(m.velocity, t, axis=0)
    assert np.allclose(dv[1:-1], m.specific_force[1:-1], atol=2e-3)
    assert np.all(m.velocity[t < prof.taxi_s] == 0)
    speed = np.hypot(*m.velocity.T)
    assert abs(speed[np.searchsorted(t, prof.cruise_start_s + 1)] - 220) < 1e-6
    assert abs(speed[-1] - 70) < 0.5
    assert 2.0 < np.max(np.abs(m.specific_force)) < 7.0  # turns of up to ~30 deg of bank
    # at rest the x gyro senses the horizontal earth rate (45 deg latitude), the y gyro nothing
    assert np.allclose(m.angular_rate[0], [7.2921150e-5 * math.cos(math.pi / 4), 0.0])
    assert len(prof.turn_starts()) >= 1
    with pytest.raises(SimError, match="cruise_speed must be a positive"):
        FlightProfile(100.0, cruise_speed=-1)


@pytest.mark.parametrize("kw,match", [
    (dict(duration_s=-1), "duration s must be a positive"),
    (dict(duration_s=10.01), "whole number"),
    (dict(ref_rate_hz=7), "must divide the INS rate"),
    (dict(truth_rate_hz=3), "truth rate .* must divide"),
    (dict(channel="z"), "channel must be x or y"),
    (dict(seed=-3), "seed must be an integer"),
    (dict(seed=1.5), "seed must be an integer"),
    (dict(model_params={"tau_q": 1.0}), "model parameters"),
    (dict(model_params={"sigma_a": -1.0}), "sigma_a must be a positive"),
    (dict(faults=(parse_fault("accel:step:t=20,mag=1"),)), "after the end of the 10-s flight"),
    (dict(faults=("accel:step:t=2,mag=1",)), "must be FaultSpec"),
    (dict(epoch_s=2**31), "epoch"),
])
def test_config_validation(kw, match):
    base = dict(duration_s=10.0)
    base.update(kw)
    with pytest.raises(SimError, match=match):
        SimConfig(**base).model()


def test_seeded_runs_repeat_and_differ():
    a = simulate(SimConfig(duration_s=20, seed=1))
    b = simulate(SimConfig(duration_s=20, seed=1))
    c = simulate(SimConfig(duration_s=20, seed=2))
    assert np.array_equal(a.v_ins, b.v_ins) and np.array_equal(a.v_ref, b.v_ref)
    assert not np.array_equal(a.v_ins, c.v_ins)
    assert a.stamp_ns[0] == 1_700_000_000 * 10**9 and np.all(np.diff(a.stamp_ns) == 20_000_000)
