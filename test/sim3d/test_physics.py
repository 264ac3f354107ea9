"""Known answers of free-inertial navigation (Schuler loop) and equality with the independent
``inu`` library."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.sim import earth
from flight_fdi.sim.faults import FaultSpec3D, parse_fault
from flight_fdi.sim.gnss import BaroConfig
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.rotation import dcm_array
from flight_fdi.sim.strapdown import NavSolution, inverse, mechanize
from flight_fdi.sim.trajectory import TrajectoryConfig, generate

DPH = math.pi / 180 / 3600
ALT = 1000.0


def _equator_north(fault: str, duration_s: float):
    """A straight leg due North along the equator at 100 m/s, perfect IMU and alignment, perfect
    baro, plus one fault from t = 0. At the equator the Foucault coupling Omega sin L and the
    transport-rate term v_E tan L / R vanish, so each horizontal channel is a plain Schuler
    loop (the remaining couplings are Omega and v/R against omega_s: < 1-2 %)."""
    cfg = Sim3DConfig(trajectory=TrajectoryConfig(profile="straight", duration_s=duration_s,
                                                  lat_deg=0.0, alt_m=ALT, speed_mps=100.0),
                      grade="perfect", alignment="perfect", baro=BaroConfig(0, 0, 600, 0),
                      faults=(parse_fault(fault, FaultSpec3D),))
    return simulate3d(cfg)


def _zero_crossings(t, y):
    i = np.flatnonzero(np.sign(y[1:]) != np.sign(y[:-1]))
    i = i[t[i] > 60]  # ignore the start at zero
    return t[i] - y[i] * (t[i + 1] - t[i]) / (y[i + 1] - y[i])


@pytest.mark.slow
def test_schuler_period_and_amplitude_of_an_accelerometer_bias():
    """Step accelerometer bias a = 100 ug on the forward (North) axis from t = 0: the north
    velocity error is (a / omega_s) sin(omega_s t) with omega_s^2 = g / (R_M + h). Measured:
    the period (from the zero crossings at T/2 and T) equals 2 pi sqrt((R_M + h) / g) -- 84.3 min
    here, the textbook 84.4 min -- to 0.1 %, and the peak is a / omega_s (0.79 m/s) to 1 %."""
    a = 100e-6 * 9.80665
    T = earth.schuler_period(0.0, ALT, "north")
    fl = _equator_north(f"accel:step:t=0,mag={a!r},axis=x", 1.1 * T)
    dv_n = fl.velocity_error()[:, 1]
    t1, t2 = _zero_crossings(fl.t, dv_n)[:2]
    assert t2 == pytest.approx(T, rel=1e-3) and 2 * t1 == pytest.approx(T, rel=1e-3)
    assert T / 60 == pytest.approx(84.4, abs=0.3)
    w_s = 2 * math.pi / T
    assert np.abs(dv_n).max() == pytest.approx(a / w_s, rel=0.01)
    assert np.abs(dv_n - a / w_s * np.sin(w_s * fl.t)).max() < 0.01 * a / w_s
    assert np.abs(fl.velocity_error()[:, 0]).max() < 0.02 * a / w_s  # the east channel stays


@pytest.mark.slow
def test_gyro_drift_gives_the_2_R_epsilon_velocity_amplitude():
    """Gyro drift eps = 0.3 deg/h on the North-pointing (forward) axis from t = 0. The Schuler
    loop phi_N' = dv_E / R - eps, dv_E' = -g phi_N gives dv_E = R eps (1 - cos(omega_s t)): the
    east velocity error swings between 0 and 2 R eps (18.6 m/s with R = R_N + h at the equator)
    with the Schuler period. Tested: max |dv_E| over one period = 2 R eps to 1 %, reached at
    T/2 (+-1 %), and the whole curve within 2 % of 2 R eps of the formula."""
    eps = 0.3 * DPH
    T = earth.schuler_period(0.0, ALT, "east")
    fl = _equator_north("gyro:step:t=0,mag=0.3deg/h,axis=x", T)
    r_n, _ = earth.radii(0.0)
    R = r_n + ALT
    dv_e = fl.velocity_error()[:, 0]
    assert 2 * R * eps == pytest.approx(18.6, abs=0.05)
    assert dv_e.max() == pytest.approx(2 * R * eps, rel=0.01)
    assert fl.t[np.argmax(dv_e)] == pytest.approx(T / 2, rel=0.01)
    w_s = 2 * math.pi / T
    assert np.abs(dv_e - R * eps * (1 - np.cos(w_s * fl.t))).max() < 0.02 * 2 * R * eps


def test_equal_to_inu_on_the_same_imu_data():
    """The mechanization equals the independent ``inu`` package (inu.mech, pure Python).

    inu works in NED with a forward-right-down body, integrates with explicit (forward) Euler
    steps from the state at t_k, updates the DCM with the Rodrigues rotation of
    (omega_ib - C^T omega_in) dt and re-orthonormalises it (modified Gram-Schmidt), and uses the
    same WGS-84 constants and Somigliana gravity with the free-air correction as ``earth``. So
    our mechanization runs in its ``euler`` scheme (the same steps, in ENU / forward-left-up,
    quaternion attitude) and the data are transformed exactly: v_NED = T v_ENU, body FRD =
    D body FLU with T = [[0,1,0],[1,0,0],[0,0,-1]], D = diag(1, -1, -1), C_NED = T C_ENU D.
    The IMU record: the ideal increments of 2 min of cruise_turns with the roll-in, the first
    90-deg turn at 25 deg bank and the roll-out, plus white noise, so neither side follows a
    trajectory it could have been built from. Agreement:
    velocity 1e-9 m/s, height 1e-9 m, latitude/longitude 1e-8 m (one ulp of the angle is
    1.4e-9 m), DCM 1e-12.
    """
    inu = pytest.importorskip("inu")
    r3f = pytest.importorskip("r3f")
    tr = generate(TrajectoryConfig(duration_s=420, speed_mps=150.0, lat_deg=60.0))
    k0 = 29000  # from 290 s: the turn starts at 300 s
    nav = NavSolution(tr.nav.lat[k0:], tr.nav.lon[k0:], tr.nav.h[k0:], tr.nav.v[k0:],
                      tr.nav.q[k0:])
    assert np.degrees(np.ptp(tr.controls["heading"][k0:])) > 89
    dth, dv = inverse(nav, tr.dt)
    rng = np.random.default_rng(0)
    dth = dth + 1e-6 * rng.standard_normal(dth.shape)
    dv = dv + 1e-3 * rng.standard_normal(dv.shape)
    ours = mechanize(dth, dv, tr.dt, nav.initial(), scheme="euler")
    T = np.array([[0, 1, 0], [1, 0, 0], [0, 0, -1.0]])
    D = np.diag([1.0, -1, -1])
    C0 = T @ dcm_array(nav.q[:1])[0] @ D
    llh0 = np.array([nav.lat[0], nav.lon[0], nav.h[0]])
    llh, vne, rpy = inu.mech(dv / tr.dt @ D.T, dth / tr.dt @ D.T, llh0, T @ nav.v[0],
                             r3f.dcm_to_rpy(C0.T), tr.dt, show_progress=False)
    n = llh.shape[0]  # inu returns the states before each input: ours[0 .. n-1]
    assert np.abs(vne @ T.T - ours.v[:n]).max() < 1e-9
    # latitude, longitude: a few ulps of the angle (1 ulp of 0.12 rad = 1.4e-17 rad... 2e-16)
    assert np.abs(llh[:, 0] - ours.lat[:n]).max() * earth.A < 1e-8
    assert np.abs(llh[:, 1] - ours.lon[:n]).max() * earth.A < 1e-8
    assert np.abs(llh[:, 2] - ours.h[:n]).max() < 1e-9
    C_inu = np.array([r3f.rpy_to_dcm(r).T for r in rpy])
    assert np.abs(C_inu - T @ dcm_array(ours.q[:n]) @ D).max() < 1e-12
    # the comparison can tell schemes apart: second order differs from Euler by ~1e-3 m/s
    second = mechanize(dth, dv, tr.dt, nav.initial())
    assert np.abs(second.v[:n] - ours.v[:n]).max() > 1e-5
