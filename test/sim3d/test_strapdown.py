"""The strapdown mechanization and its inverse: known answers, round trip, perfect IMU."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.sim import earth
from flight_fdi.sim.errors import SimError
from flight_fdi.sim.gnss import BaroConfig
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.rotation import attitude_error_array, dcm_array, qexp, qlog
from flight_fdi.sim.strapdown import inverse, mechanize
from flight_fdi.sim.trajectory import TrajectoryConfig, generate


def test_earth_model_known_values():
    """WGS-84 normal gravity at the equator and pole (NIMA TR8350.2: 9.7803253359 and
    9.8321849378 m/s^2), radii at the equator (a and a(1 - e^2)), and the free-air gradient
    -0.3086 mGal/m at the equator."""
    assert earth.gravity(0.0, 0.0) == pytest.approx(9.7803253359, abs=1e-10)
    assert earth.gravity(math.pi / 2, 0.0) == pytest.approx(9.8321849378, abs=1e-9)
    r_n, r_m = earth.radii(0.0)
    assert r_n == earth.A and r_m == pytest.approx(earth.A * (1 - earth.E2), rel=1e-15)
    grad = (earth.gravity(0.0, 1.0) - earth.gravity(0.0, 0.0))
    assert grad == pytest.approx(-3.086e-6, rel=2e-3)
    assert earth.schuler_period(0.0, 0.0) / 60 == pytest.approx(84.4, abs=0.3)


def test_quaternion_exp_log_are_inverse():
    """Within the principal range (|v| < pi) and in the small-angle series branch."""
    rng = np.random.default_rng(1)
    vs = rng.normal(size=(20, 3))
    vs *= (rng.uniform(0, 3.1, 20) / np.linalg.norm(vs, axis=1))[:, None]
    for v in list(vs) + [np.array([1e-9, -2e-8, 3e-7])]:
        q = qexp(*v)
        assert np.allclose(qlog(*q), v, rtol=1e-12, atol=1e-18)
        assert abs(np.linalg.norm(q) - 1) < 1e-15


def test_stationary_imu_senses_earth_rate_and_gravity():
    """Known answer: a level, stationary body facing East senses omega_ie = Omega (0, cos L,
    sin L) and f = (0, 0, g(L, h)) in ENU = body axes (yaw 0, x East, y North, z Up)."""
    lat = math.radians(52.0)
    tr = generate(TrajectoryConfig(profile="straight", duration_s=10, speed_mps=0.0,
                                   lat_deg=52.0, alt_m=500.0, heading_deg=90.0, aoa_deg=0.0))
    assert np.allclose(tr.nav.q, [1, 0, 0, 0], atol=1e-15)
    dth, dv = inverse(tr.nav, tr.dt)
    w = dth / tr.dt
    f = dv / tr.dt
    assert np.allclose(w, [0, earth.OMEGA_IE * math.cos(lat), earth.OMEGA_IE * math.sin(lat)],
                       rtol=0, atol=1e-17)
    assert np.allclose(f, [0, 0, earth.gravity(lat, 500.0)], rtol=0, atol=1e-12)


def test_coordinated_turn_matches_the_continuous_specific_force_and_rate():
    """Known answer for the inverse mechanization: in a steady level turn (bank 30 deg, 150 m/s)
    the increments / dt equal the continuous-time f^b = C^T (dv/dt + (2 omega_ie + omega_en) x v
    - g^n) and omega_ib^b = C^T (omega_in^n + (0, 0, -chi')) at mid-interval, to O(dt^2)
    (1e-7 m/s^2, 1e-11 rad/s: an IMU delivering the exact continuous values would move the INS
    by < 4e-4 m/s in an hour even if the difference never averaged out); and f^b is ~
    (g sin(alpha), Coriolis only, g / cos(bank)) as for a coordinated turn."""
    cfg = TrajectoryConfig(profile="cruise_turns", duration_s=330, speed_mps=150.0, lat_deg=30.0,
                           aoa_deg=0.0)
    tr = generate(cfg)
    dth, dv = inverse(tr.nav, tr.dt)
    c = tr.controls
    k = np.flatnonzero((np.abs(c["bank"] - math.radians(25)) < 1e-12))[5:-5]
    assert k.size > 1000  # the 90-deg right turn at 25 deg bank (first turn of cruise_turns)
    V = 150.0
    t_mid = tr.t[k] + 0.5 * tr.dt
    chi = np.interp(t_mid, tr.t, c["heading"])
    lat = np.interp(t_mid, tr.t, tr.nav.lat)
    h = np.interp(t_mid, tr.t, tr.nav.h)
    chi_dot = 9.80665 * math.tan(math.radians(25)) / V
    v = V * np.stack([np.sin(chi), np.cos(chi), 0 * chi], 1)
    a = V * chi_dot * np.stack([np.cos(chi), -np.sin(chi), 0 * chi], 1)
    r_n, r_m = earth.radii(lat)
    w_ie = earth.OMEGA_IE * np.stack([0 * lat, np.cos(lat), np.sin(lat)], 1)
    w_en = np.stack([-v[:, 1] / (r_m + h), v[:, 0] / (r_n + h),
                     v[:, 0] * np.tan(lat) / (r_n + h)], 1)
    earth_g = np.stack([0 * lat, 0 * lat, -earth.gravity(lat, h)], 1)
    f_n = a + np.cross(2 * w_ie + w_en, v) - earth_g
    from flight_fdi.sim.rotation import euler_from_quat_array, quat_from_euler_array
    ypr = euler_from_quat_array(tr.nav.q[k])
    q_mid = quat_from_euler_array(0.5 * np.pi - chi, ypr[:, 1], ypr[:, 2])
    C = dcm_array(q_mid)
    f_b = np.einsum("kji,kj->ki", C, f_n)
    w_b = np.einsum("kji,kj->ki", C, w_ie + w_en + np.array([0, 0, -chi_dot]))
    assert np.abs(dv[k] / tr.dt - f_b).max() < 1e-7  # measured 3.2e-8 m/s^2
    assert np.abs(dth[k] / tr.dt - w_b).max() < 1e-11  # measured 1.1e-12 rad/s
    g = earth.gravity(lat, h)
    assert np.allclose(f_b[:, 2], g / math.cos(math.radians(25)), atol=0.05)
    assert np.abs(f_b[:, 1]).max() < 0.05 and np.abs(f_b[:, 0]).max() < 1e-3


def test_round_trip_forward_of_inverse_is_the_trajectory():
    """Inverse then forward mechanization (second order) returns the trajectory -- velocity to
    1e-9 m/s, attitude to 1e-12 rad, position to 1e-6 m -- on a 20-min seeded random flight with
    turns, climbs and speed changes."""
    tr = generate(TrajectoryConfig(profile="random", duration_s=1200, seed=5, lat_deg=-35.0))
    dth, dv = inverse(tr.nav, tr.dt)
    nav = mechanize(dth, dv, tr.dt, tr.nav.initial())
    assert np.abs(nav.v - tr.nav.v).max() < 1e-9
    # position: one ulp of the latitude (1e-16 rad = 0.7 nm) per step, summed over 120 000 steps
    assert np.abs(nav.lat - tr.nav.lat).max() * earth.A < 1e-6
    assert np.abs(nav.lon - tr.nav.lon).max() * earth.A < 1e-6
    assert np.abs(nav.h - tr.nav.h).max() < 1e-6
    assert np.abs(attitude_error_array(nav.q, tr.nav.q)).max() < 1e-12
    # and the inverse of the forward solution gives the increments back
    dth2, dv2 = inverse(nav, tr.dt)
    assert np.abs(dth2 - dth).max() < 1e-15 and np.abs(dv2 - dv).max() < 1e-9


def test_perfect_imu_one_hour_of_turns_and_climbs():
    """Perfect IMU, perfect alignment, free vertical channel: after an hour of cruise_turns
    (four turns, two 600-m climbs/descents, speed changes) the INS velocity error stays below
    1 mm/s (measured: ~1e-9 m/s, rounding)."""
    cfg = Sim3DConfig(trajectory=TrajectoryConfig(duration_s=3600), grade="perfect",
                      alignment="perfect", vertical="free")
    fl = simulate3d(cfg)
    c = fl.truth.controls
    assert np.degrees(np.abs(np.diff(c["heading"])).sum()) > 500 and np.ptp(fl.truth.nav.h) > 500
    assert np.abs(fl.velocity_error()).max() < 1e-3
    assert np.abs(fl.velocity_error()).max() < 1e-7  # in fact: rounding error only


def test_perfect_baro_leaves_the_perfect_flight_untouched():
    cfg = Sim3DConfig(trajectory=TrajectoryConfig(duration_s=600), grade="perfect",
                      alignment="perfect", baro=BaroConfig(0, 0, 600, 0))
    fl = simulate3d(cfg)
    assert np.abs(fl.velocity_error()).max() < 1e-9


def test_bad_mechanize_input_is_a_clear_error():
    with pytest.raises(SimError, match="scheme"):
        mechanize(np.zeros((3, 3)), np.zeros((3, 3)), 0.01, (0, 0, 0, np.zeros(3),
                                                             np.array([1, 0, 0, 0.0])), "rk4")
    with pytest.raises(SimError, match="shape"):
        mechanize(np.zeros((3, 2)), np.zeros((3, 2)), 0.01, (0, 0, 0, np.zeros(3),
                                                             np.array([1, 0, 0, 0.0])))
