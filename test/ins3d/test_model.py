"""Known answers of the ins3d error model: the single-axis reduction, the discretisation error
against expm / Van Loan, and the simulator's true INS errors reproduced by the linear model."""
from __future__ import annotations

import numpy as np
import pytest
from scipy.linalg import expm

from flight_fdi.bagio.ins3d_input import from_flight, truth_from_flight
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.data import nav_steps
from flight_fdi.core.ins3d.model import IBA, IBG, IPHI, IV, Ins3dModel, gravity
from flight_fdi.core.ins3d.dynamics import F_matrix, discretize, propagate

from .conftest import flight


def _level_steps(v=(0.0, 200.0, 0.0), lat=0.7, h=3000.0, yaw=0.3, n=3):
    g = float(gravity(lat, h))
    q = np.tile([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)], (n + 1, 1))
    t = 0.05 * np.arange(n + 1)
    return nav_steps(t, q, np.tile([0.0, 0.0, g], (n, 1)), np.zeros((n, 3)),
                     np.tile(v, (n + 1, 1)), np.full(n + 1, lat), np.full(n + 1, h)), g, yaw


def test_level_flight_reduces_to_the_single_axis_model():
    steps, g, yaw = _level_steps()
    m = Ins3dModel.from_grade("navigation", vertical="free")
    F = F_matrix(m, steps, 0)
    assert F[IV, IPHI + 1] == pytest.approx(-g, rel=1e-12)      # dv_E' = -g phi_N
    assert F[IV + 1, IPHI] == pytest.approx(g, rel=1e-12)       # dv_N' = +g phi_E
    assert F[IV, IPHI] == 0.0 and F[IV, IPHI + 2] == 0.0
    c, s = np.cos(yaw), np.sin(yaw)
    np.testing.assert_allclose(F[IV:IV + 3, IBA:IBA + 3], [[c, -s, 0], [s, c, 0], [0, 0, 1]],
                               atol=1e-15)                       # + (C b_a)_E
    np.testing.assert_allclose(F[IPHI:IPHI + 3, IBG:IBG + 3], -F[IV:IV + 3, IBA:IBA + 3])
    r_n, _ = __import__("flight_fdi.sim.earth", fromlist=["radii"]).radii(0.7)
    assert F[IPHI + 1, IV] == pytest.approx(1.0 / (r_n + 3000.0))   # phi_N' = dv_E / R: Schuler
    # the Schuler pair (dv_E, phi_N) alone oscillates at sqrt(g / R)
    w2 = -F[IV, IPHI + 1] * F[IPHI + 1, IV]
    assert 2 * np.pi / np.sqrt(w2) / 60 == pytest.approx(84.4, abs=0.3)


def test_damped_vertical_channel_is_cut_from_the_other_states():
    steps, _, _ = _level_steps(v=(150.0, 100.0, 5.0))
    free = F_matrix(Ins3dModel.from_grade("navigation", vertical="free", position=True), steps, 0)
    m = Ins3dModel.from_grade("navigation", position=True)
    F = F_matrix(m, steps, 0)
    assert free[IV, IV + 2] != 0.0 and free[IV + 2, IBA + 2] == 1.0
    assert np.count_nonzero(F[IV + 2]) == 1 and F[IV + 2, IV + 2] == -1.0 / m.tau_vertical_s
    assert np.count_nonzero(F[:, IV + 2]) == 2          # itself and dp_U' = dv_U
    keep = [i for i in range(15) if i != IV + 2]
    np.testing.assert_array_equal(F[np.ix_(keep, keep)], free[np.ix_(keep, keep)])
    assert m.qc()[IV + 2] * m.tau_vertical_s / 2 == pytest.approx(m.sigma_vertical**2)


def test_model_parameters_come_from_the_grade_presets():
    from flight_fdi.sim.imu3d import GRADES
    m = Ins3dModel.from_grade("tactical", position=True, rows=3)
    g = GRADES["tactical"]
    assert m.n == 15 and m.H().shape == (3, 15)
    inv_a, inv_g, qa, qg = m.bias_params()
    # stationary variance of the bias state = turn-on^2 + GM^2, wander q = 2 sigma^2 / tau
    assert qa / (2 * inv_a) == pytest.approx(g.accel_bias**2 + g.accel_instability**2)
    assert qg == pytest.approx(2 * g.gyro_instability**2 / g.gyro_tau_s)
    assert m.qc()[IV] == g.vrw**2 and m.qc()[IPHI] == g.arw**2
    with pytest.raises(CoreError):
        Ins3dModel.from_grade("consumer")
    with pytest.raises(CoreError):
        Ins3dModel.from_grade("navigation", rows=4)


def _van_loan(F, qc, dt):
    n = F.shape[0]
    M = np.zeros((2 * n, 2 * n))
    M[:n, :n] = -F
    M[:n, n:] = np.diag(qc)
    M[n:, n:] = F.T
    E = expm(M * dt)
    Phi = E[n:, n:].T
    return Phi, Phi @ E[:n, n:]


@pytest.mark.parametrize("vertical", ["free", "damped"])
@pytest.mark.parametrize("dt", [0.05, 0.1])
def test_discretisation_error_against_expm_and_van_loan(dt, vertical):
    fl = flight("cruise_turns", 600.0, "tactical", "free", 1)
    inp = from_flight(fl)
    m = Ins3dModel.from_grade("tactical", position=True, vertical=vertical)
    # the largest specific force of the flight (in a turn) and the highest speed
    k = int(np.argmax(np.linalg.norm(inp.steps.f_n[:, :2], axis=1)))
    F = F_matrix(m, inp.steps, k)
    qc = m.qc()
    Phi, Qd = np.empty_like(F), np.empty_like(F)
    discretize(F, dt, qc, Phi, Qd)
    Phi_x, Qd_x = _van_loan(F, qc, dt)
    # scaled to typical state sizes (the states differ by orders of magnitude)
    s = np.sqrt(m.p0())
    err_phi = np.max(np.abs((Phi - Phi_x) * s[None, :] / s[:, None]))
    err_q = np.max(np.abs(Qd - Qd_x) / np.sqrt(np.outer(np.diag(Qd_x), np.diag(Qd_x))))
    assert err_phi < 1e-6, err_phi          # third-order remainder (|F dt|^3 / 6)
    print(f"dt={dt} {vertical}: scaled Phi error {err_phi:.2e}, normalised Qd error {err_q:.2e}")
    assert err_q < 1e-2 * dt, err_q         # Van Loan series to dt^3: O(dt^4) left


def _relative_error(x_lin, x_true, cols):
    return np.max(np.abs(x_lin[:, cols] - x_true[:, cols])) / np.max(np.abs(x_true[:, cols]))


@pytest.mark.parametrize("grade,tol", [("tactical", 0.03), ("navigation", 0.005)])
def test_linear_model_predicts_the_true_ins_errors_through_turns(grade, tol):
    """From the true initial errors with the true sensor errors as the bias states (no noise
    otherwise: the white noise is off), the 15-state model reproduces the simulator's INS errors
    over 25 min with the first two turns, the climb and the speed change; free vertical channel
    (tactical: 36 m/s and 18 km of vertical error by the end, the residual is its nonlinearity)."""
    fl = flight("cruise_turns", 1500.0, grade, "free", 1, noise=False)
    inp = from_flight(fl)
    tr = truth_from_flight(fl, inp)
    assert np.ptp(np.degrees(np.unwrap(np.arctan2(inp.steps.v[:, 1], inp.steps.v[:, 0])))) > 130
    m = Ins3dModel.from_grade(grade, position=True, vertical="free")
    x = propagate(m, inp.steps, tr["x"][0], tr["u_a"], tr["u_g"])
    out = {}
    for name, cols in (("dv_h", [0, 1]), ("dv_u", [2]), ("phi_h", [3, 4]), ("phi_u", [5]),
                       ("dp_h", [12, 13]), ("dp_u", [14])):
        out[name] = _relative_error(x, tr["x"], cols)
    print(grade, {k: f"{v:.2%}" for k, v in out.items()})
    assert max(out.values()) < tol, out


def test_a_wrong_sign_is_caught_by_the_truth_test():
    """The truth comparison has teeth: flipping the gyro-bias coupling breaks it."""
    fl = flight("cruise_turns", 1500.0, "tactical", "free", 1, noise=False)
    inp = from_flight(fl)
    tr = truth_from_flight(fl, inp)
    m = Ins3dModel.from_grade("tactical", position=True, vertical="free")
    x = propagate(m, inp.steps, tr["x"][0], tr["u_a"], -tr["u_g"])
    assert _relative_error(x, tr["x"], [3, 4, 5]) > 0.5


def _baro_flight(seed=3, onset=400.0):
    """Navigation grade, no white IMU noise, a constant baro error (the loop's input is then
    known: b = h_baro - h_true), a 0.3-mg vertical accelerometer step at ``onset``."""
    import dataclasses

    from flight_fdi.sim.faults import G0, FaultSpec3D
    from flight_fdi.sim.gnss import BaroConfig
    from flight_fdi.sim.imu3d import GRADES
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    g = dataclasses.replace(GRADES["navigation"], arw=0.0, vrw=0.0)
    cfg = Sim3DConfig(TrajectoryConfig(profile="cruise_turns", duration_s=900.0, rate_hz=100.0),
                      grade=g, seed=seed, baro=BaroConfig(bias=5.0, instability=0.0, white=0.0),
                      faults=(FaultSpec3D(target="accel", type="step", start_s=onset,
                                          magnitude=0.3e-3 * G0, axis="z"),))
    return simulate3d(cfg)


@pytest.mark.parametrize("position", [False, True])
def test_vertical_loop_reproduces_the_simulators_baro_damped_channel(position):
    """The INS's own height loop in F (``vertical="loop"``, gains from the flight's metadata):
    with the true sensor errors and the true baro error as inputs the model reproduces the
    simulator's vertical velocity and height errors -- the 0.3-mg vertical accelerometer step's
    transient of 0.25 m/s that the loop's integrator then absorbs -- to 0.1 %."""
    from flight_fdi.core.ins3d.vertical import VerticalLoop

    fl = _baro_flight()
    inp = from_flight(fl)
    tr = truth_from_flight(fl, inp)
    loop = VerticalLoop.from_description(fl.description(), float(fl.truth.nav.lat[0]),
                                         float(fl.truth.nav.h[0]))
    assert loop.tau_s == 100.0 and loop.white == 0.0 and loop.bias == 5.0
    m = Ins3dModel.from_grade(fl.config.imu_grade, position=position, vertical="loop",
                              loop=loop)
    assert m.n == 15 + 2 * position and m.names[-2:] == ("int_dh", "b_aid")
    assert m.ih == (14 if position else 12)
    x0 = np.zeros(m.n)
    x0[:12] = tr["x"][0, :12]
    x0[m.ih] = tr["x"][0, 14]
    x0[m.im - 1] = fl.aid_h[0] - fl.truth.nav.h[0]
    x = propagate(m, inp.steps, x0, tr["u_a"], tr["u_g"])
    dv_u, dh = tr["x"][:, 2], tr["x"][:, 14]
    assert 0.2 < np.max(np.abs(dv_u)) < 0.3
    assert abs(dv_u[-1]) < 0.3 * np.max(np.abs(dv_u))          # the integrator absorbs it
    assert np.max(np.abs(x[:, 2] - dv_u)) < 1e-3 * np.max(np.abs(dv_u))
    assert np.max(np.abs(x[:, m.ih] - dh)) < 1e-3 * np.max(np.abs(dh))
    # the damped stand-in (dv_U a Markov state of its own) does not see the step at all
    damped = Ins3dModel.from_grade(fl.config.imu_grade, position=position)
    xd = propagate(damped, inp.steps, np.zeros(damped.n), tr["u_a"], tr["u_g"])
    assert np.max(np.abs(xd[:, 2])) == 0.0


def test_vertical_loop_parameters():
    from flight_fdi.core.ins3d.vertical import VerticalLoop, loop_gains
    from flight_fdi.sim.strapdown import vertical_gains

    assert loop_gains(100.0, 0.8, 2000.0) == pytest.approx(vertical_gains(100.0, 0.8, 2000.0),
                                                           rel=1e-15)
    assert VerticalLoop.from_description({"vertical": "free"}) is None
    with pytest.raises(CoreError):
        VerticalLoop(tau_s=0.0)
    m = Ins3dModel.from_grade("navigation", rows=3, vertical="loop", latency=True)
    k1, k2, k3 = m.loop.gains()
    F = F_matrix(m, _level_steps()[0], 0)
    ih, js, jb = 12, 13, 14
    assert F[ih, IV + 2] == 1.0 and F[ih, ih] == -k1 and F[ih, jb] == k1
    assert F[IV + 2, js] == -k3 and F[js, ih] == 1.0 and F[js, jb] == -1.0
    assert F[IV + 2, IBA + 2] == 1.0                     # level: ba_z drives dv_U
    # the stationary variance of the aiding error is the baro's turn-on^2 + GM^2
    inv, q = m.aid_params()
    assert q / (2 * inv) == pytest.approx(5.0**2 + 2.0**2)
    assert m.H().shape == (3, m.n) and m.il == m.n - 1
