"""IMU error model, body-axis faults, alignment, GNSS reference and baro."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.sim import earth
from flight_fdi.sim.errors import SimError
from flight_fdi.sim.faults import FaultSpec3D, parse_fault
from flight_fdi.sim.gnss import BaroConfig, GnssConfig, held, simulate_gnss
from flight_fdi.sim.imu3d import DEG_H, GRADES, corrupt, gauss_markov
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig, generate

F3 = lambda s: parse_fault(s, FaultSpec3D)  # noqa: E731


def _cfg(duration=300.0, **kw):
    kw.setdefault("trajectory", TrajectoryConfig(duration_s=duration))
    return Sim3DConfig(**kw)


def test_gauss_markov_is_stationary_with_its_sigma_and_correlation():
    rng = np.random.default_rng(2)
    x = gauss_markov(rng, 200000, 2.0, 50.0, 1.0, m=2)
    assert np.std(x, axis=0) == pytest.approx([2.0, 2.0], rel=0.1)
    lag = 50
    rho = np.mean(x[lag:] * x[:-lag]) / np.mean(x * x)
    assert rho == pytest.approx(math.exp(-1), abs=0.05)


def test_white_noise_matches_the_random_walk_coefficients():
    """Tactical grade on a still IMU: the std of a rate sample is ARW/sqrt(dt) (gyro) and
    VRW/sqrt(dt) (accel) once the slow bias is removed."""
    g = GRADES["tactical"]
    n, dt = 100000, 0.01
    t = np.arange(n) * dt
    rng = np.random.default_rng(3)
    out = corrupt(np.zeros((n, 3)), t, dt, "gyro", g, (), rng, n * dt, False)
    assert np.std(out.rate - out.bias, axis=0) == pytest.approx([g.arw / math.sqrt(dt)] * 3,
                                                                rel=0.02)
    out = corrupt(np.zeros((n, 3)), t, dt, "accel", g, (), rng, n * dt, False)
    assert np.std(out.rate - out.bias, axis=0) == pytest.approx([g.vrw / math.sqrt(dt)] * 3,
                                                                rel=0.02)


def test_faults_on_each_body_axis_and_noise_unchanged():
    """A fault changes exactly its sensor and axis by the catalogue's e(t); the noise streams
    are the same with and without it (one seed, independent streams)."""
    nominal = simulate3d(_cfg(grade="tactical"))
    cases = [("accel:step:t=100,mag=1mg,axis=z", "accel", 2, lambda t, r: 1e-3 * 9.80665),
             ("gyro:ramp:t=50,end=250,mag=0.01deg/h,axis=y", "gyro", 1,
              lambda t, r: 0.01 * DEG_H * (t - 50)),
             ("gyro:scale:t=10,mag=1000ppm,axis=x", "gyro", 0, lambda t, r: 1e-3 * r)]
    for spec, sensor, axis, e in cases:
        fl = simulate3d(_cfg(grade="tactical", faults=(F3(spec),)))
        f = F3(spec)
        t = fl.t[:-1]
        diff = getattr(fl, sensor).rate - getattr(nominal, sensor).rate
        ideal = (fl.ideal_dv if sensor == "accel" else fl.ideal_dtheta) / fl.dt
        want = np.where(f.active(t, 300.0), e(t, ideal[:, axis]), 0.0)
        assert np.allclose(diff[:, axis], want, rtol=1e-9, atol=1e-15), spec
        assert np.all(np.delete(diff, axis, axis=1) == 0)
        assert np.allclose(getattr(fl, sensor).fault[:, axis], want, rtol=1e-9, atol=1e-15)
        other = "gyro" if sensor == "accel" else "accel"
        assert np.array_equal(getattr(fl, other).rate, getattr(nominal, other).rate)


def test_stuck_output_is_the_stuck_value():
    fl = simulate3d(_cfg(duration=60, faults=(F3("gyro:stuck:t=20,end=40,mag=0.01,axis=z"),)))
    k = (fl.t[:-1] >= 20) & (fl.t[:-1] < 40)
    assert np.all(fl.gyro.rate[k, 2] == 0.01) and not np.any(fl.gyro.rate[~k, 2] == 0.01)


def test_quantization_keeps_the_running_sum_within_one_quantum():
    g = GRADES["mems"]
    n, dt = 5000, 0.01
    rng = np.random.default_rng(0)
    ideal = rng.normal(0, 0.1, (n, 3))
    a = corrupt(ideal, np.arange(n) * dt, dt, "gyro", g, (), np.random.default_rng(1), n * dt,
                False)
    b = corrupt(ideal, np.arange(n) * dt, dt, "gyro", g, (), np.random.default_rng(1), n * dt,
                True)
    inc = b.rate * dt / g.gyro_quantum
    assert np.allclose(inc, np.round(inc), atol=1e-6)
    run = np.cumsum((b.rate - a.rate) * dt, axis=0)
    assert np.abs(run).max() <= 0.5 * g.gyro_quantum * (1 + 1e-9)


def test_consistent_alignment_levels_out_the_accelerometer_bias():
    """Consistent alignment: the tilt cancels the initial accelerometer error, so with a
    1e-3 m/s^2 turn-on bias (no gyro error, no bias wander, no noise) the horizontal velocity
    error after 60 s straight and level is < 3 % of the b t it reaches with a perfect alignment
    (measured 1 %: the levelled tilt, ~b/g, is then turned by omega_in x phi, which the static
    levelling does not balance)."""
    tcfg = TrajectoryConfig(profile="straight", duration_s=60)
    nav = GRADES["navigation"].to_dict()
    nav.update(accel_bias=1e-3, accel_instability=0.0, vrw=0.0, gyro_bias=0.0,
               gyro_instability=0.0, arw=0.0)
    g = GRADES["navigation"].__class__(**nav)
    con = simulate3d(Sim3DConfig(trajectory=tcfg, grade=g))
    per = simulate3d(Sim3DConfig(trajectory=tcfg, grade=g, alignment="perfect"))
    e_con = np.abs(con.velocity_error()[-1, :2]).max()
    e_per = np.abs(per.velocity_error()[-1, :2]).max()
    assert e_per > 0.02 and e_con < 0.03 * e_per


def test_gyrocompassing_heading_error_from_the_east_gyro_error():
    """Navigation grade: phi_U = (Omega_U phi_N - eps_E) / Omega_N, the classical
    -eps_E / (Omega cos L) up to the tilt term; the INS starts with exactly phi0."""
    from flight_fdi.sim.rotation import qrot

    con = simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(profile="straight", duration_s=10)))
    e_n = np.array(qrot(*con.truth.nav.q[0],
                        *con.gyro.systematic(con.ideal_dtheta[:1] / con.dt, slice(0, 1))[0]))
    lat = math.radians(45.0)
    assert con.phi0[2] == pytest.approx(-e_n[0] / (earth.OMEGA_IE * math.cos(lat)), rel=0.01)
    assert abs(con.phi0[2]) > 1e-5
    assert np.allclose(con.attitude_error()[0], con.phi0, atol=1e-12)


def test_gnss_latency_noise_and_faults():
    tr = generate(TrajectoryConfig(duration_s=600))
    nav = tr.nav
    quiet = GnssConfig(vel_white_h=0, vel_white_v=0, vel_markov_h=0, vel_markov_v=0,
                       pos_white_h=0, pos_white_v=0, pos_markov_h=0, pos_markov_v=0,
                       latency_s=0.05)
    rng = np.random.default_rng(0)
    faults = (F3("ref:jump:t=100,end=200,mag=0.5,axis=y"), F3("ref:dropout:t=300,end=310"),
              F3("ref:latency:t=400,end=500,mag=50ms"))
    g = simulate_gnss(tr.t, nav.lat, nav.lon, nav.h, nav.v, quiet, faults, rng, 600.0)
    assert g.t.size == 6001 - 100
    lat_t = np.clip(g.t - g.latency, 0, None)
    want = np.stack([np.interp(lat_t, tr.t, nav.v[:, i]) for i in range(3)], 1)
    jump = (g.t >= 100) & (g.t < 200)
    want[jump, 1] += 0.5
    assert np.allclose(g.v, want, atol=1e-12)
    assert np.allclose(g.latency[(g.t >= 400) & (g.t < 500)], 0.1)
    assert np.allclose(g.latency[g.t < 400], 0.05)
    assert np.allclose(g.h, np.interp(lat_t, tr.t, nav.h), atol=1e-9)
    # noise: the defaults' white and Markov parts
    cfg = GnssConfig(latency_s=0.0)
    g = simulate_gnss(tr.t, nav.lat, nav.lon, nav.h, nav.v, cfg, (), rng, 600.0)
    err = g.v - np.stack([np.interp(g.t, tr.t, nav.v[:, i]) for i in range(3)], 1)
    white = err - g.vel_error_markov
    assert np.std(white, axis=0) == pytest.approx([0.02, 0.02, 0.04], rel=0.1)
    assert g.vel_var == pytest.approx([0.02**2 + 0.02**2] * 2 + [0.04**2 + 0.03**2])


def test_vertical_channel_modes():
    """Free: the vertical error of a tactical IMU diverges (tens of km in 30 min); baro- and
    reference-damped: bounded (the vertical accelerometer error b ~ 3e-3 m/s^2 through the
    loop makes a transient of order b tau^2 = 30 m before the integrator takes it up)."""
    out = {}
    for mode in ("free", "baro", "reference"):
        fl = simulate3d(_cfg(duration=1800, grade="tactical", vertical=mode,
                             baro=BaroConfig(5.0, 2.0, 600.0, 0.5)))
        out[mode] = np.abs(fl.ins.h - fl.truth.nav.h).max()
    assert out["free"] > 1000 and out["baro"] < 60 and out["reference"] < 60
    assert np.array_equal(held(np.array([0.0, 1.0]), np.array([5.0, 6.0]),
                               np.array([0.0, 0.5, 1.0, 3.0])), [5.0, 5.0, 6.0, 6.0])


@pytest.mark.parametrize("kw, match", [
    (dict(grade="consumer"), "unknown IMU grade"),
    (dict(vertical="sonar"), "vertical channel"),
    (dict(alignment="magic"), "alignment"),
    (dict(faults=(parse_fault("accel:step:t=1,mag=1"),)), "FaultSpec3D"),
    (dict(faults=(F3("accel:step:t=999,mag=1"),)), "after the end"),
    (dict(tau_vertical_s=0.0), "time constant"),
])
def test_bad_configuration_is_a_clear_error(kw, match):
    with pytest.raises(SimError, match=match):
        _cfg(**kw)


def test_trajectory_configuration_errors_and_profiles():
    with pytest.raises(SimError, match="latitude"):
        TrajectoryConfig(lat_deg=80.0)
    with pytest.raises(SimError, match="profile"):
        TrajectoryConfig(profile="loop")
    for name in ("survey_grid", "random", "straight"):
        tr = generate(TrajectoryConfig(profile=name, duration_s=1800, seed=1))
        v = np.linalg.norm(tr.nav.v, axis=1)
        assert 50 <= v.min() and v.max() <= 250
        assert np.isfinite(tr.nav.q).all()
    for v in (50.0, 65.0, 250.0):  # cruise_turns slows down by 30 m/s, never below 50
        s = generate(TrajectoryConfig(duration_s=3600, speed_mps=v)).controls["speed"]
        assert s.min() == pytest.approx(max(50.0, v - 30.0)) and s.max() == pytest.approx(v)
    grid = generate(TrajectoryConfig(profile="survey_grid", duration_s=1800))
    # 300 s straight, then 180-deg turns (~70 s at 80 m/s, 20 deg bank) every 480 s: three
    assert np.degrees(np.abs(np.diff(grid.controls["heading"])).sum()) == pytest.approx(540,
                                                                                        abs=1)
