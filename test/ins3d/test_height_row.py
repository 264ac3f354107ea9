"""A height reference as the third row (``Ins3dModel.height_row``, ``data.with_height``):
the measurement, its checks, the names, and on a simulated strapdown flight whose barometer has
its own turn-on bias, Gauss-Markov error and white noise (``sim.gnss.simulate_baro``), the
vertical accelerometer named with its onset and size."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.data import RefRows, with_height
from flight_fdi.core.ins3d.filter import scaled_H
from flight_fdi.core.ins3d.glr3d import hypotheses
from flight_fdi.core.ins3d.model import IP, IV, Ins3dModel
from flight_fdi.core.ins3d_result import ins3d_result
from flight_fdi.sim.gnss import BaroConfig, simulate_baro

from .conftest import flight


@pytest.mark.parametrize("kw", [dict(position=True, latency=True),
                                dict(position=True, ref_markov=(0.01, 0.4, 5.0)),
                                dict(vertical="loop")])
def test_the_third_row_measures_the_height_error(kw):
    m = Ins3dModel.from_grade("tactical", rows=3, height_row=True, **kw)
    a = np.array([0.3, -0.2, 1.7])          # the latency column: the rate of each row
    H = m.H(a)
    assert H[2, m.ih] == 1.0 and H[2, IV + 2] == 0.0
    assert H[0, IV] == H[1, IV + 1] == 1.0
    if m.latency:
        assert H[2, m.il] == a[2]
    if m.ref_markov:
        assert H[2, m.im + 2] == 1.0
    # the kernels' H (unscaled) is the model's
    assert np.array_equal(scaled_H(np.ones(m.n), a, *m.row_args()), H)
    v = Ins3dModel.from_grade("tactical", rows=3, **kw)
    assert v.H(a)[2, IV + 2] == 1.0 and v.hu == IV + 2
    assert np.array_equal(scaled_H(np.ones(v.n), a, *v.row_args()), v.H(a))


def test_the_height_row_s_markov_state_has_its_own_time_constant():
    """ref_markov (sigma_h, sigma_v, tau, tau_third): the third row's Markov state decays with
    its own tau in F and gets q = 2 sigma^2 / tau from it; the horizontal ones keep tau; three
    values give every row tau (as before); a fifth value or a non-positive one is refused."""
    from flight_fdi.core.ins3d.dynamics import fill_F
    m = Ins3dModel.from_grade("tactical", rows=3, position=True, height_row=True,
                              ref_markov=(0.02, 0.4, 30.0, 5.0))
    F = np.empty((m.n, m.n))
    fill_F(F, np.eye(3), np.array([0.0, 0.0, 9.8]), np.array([100.0, 0.0, 0.0]), 0.8, 1000.0,
           m.kernel_params())
    im = m.im
    assert [F[im + i, im + i] for i in range(3)] == [-1 / 30.0, -1 / 30.0, -1 / 5.0]
    assert np.allclose(m.qc()[im:im + 3], [2 * 0.02**2 / 30, 2 * 0.02**2 / 30, 2 * 0.4**2 / 5])
    same = Ins3dModel.from_grade("tactical", rows=3, position=True, height_row=True,
                                 ref_markov=(0.02, 0.4, 30.0))
    fill_F(F, np.eye(3), np.array([0.0, 0.0, 9.8]), np.array([100.0, 0.0, 0.0]), 0.8, 1000.0,
           same.kernel_params())
    assert [F[im + i, im + i] for i in range(3)] == [-1 / 30.0] * 3
    for bad in ((0.02, 0.4, 30.0, 5.0, 1.0), (0.02, 0.4, 30.0, 0.0)):
        with pytest.raises(CoreError, match="ref_markov"):
            Ins3dModel.from_grade("tactical", rows=3, position=True, ref_markov=bad)


@pytest.mark.parametrize("kw", [dict(rows=2, position=True), dict(rows=3)])
def test_a_height_row_needs_three_rows_and_a_height_state(kw):
    with pytest.raises(CoreError, match="height reference row needs rows=3"):
        Ins3dModel.from_grade("tactical", height_row=True, **kw)


def test_with_height_known_answer_and_bad_input():
    t_ins = np.array([0.0, 1.0, 2.0, 3.0])
    h_ins = np.array([100.0, 101.0, 103.0, 106.0])
    v_up = np.array([1.0, 1.5, 2.5, 3.0])
    refs = RefRows(np.array([0.5, 2.0]), np.ones((2, 3)), np.full((2, 3), 0.01),
                   np.array([1, 2]), np.zeros((2, 3)))
    out = with_height(refs, t_ins, h_ins, v_up, np.array([100.0, 102.5]), 0.25)
    assert np.allclose(out.z[:, 2], [0.5, 0.5]) and np.allclose(out.r[:, 2], 0.25)
    assert np.allclose(out.a[:, 2], [1.25, 2.5])
    assert np.array_equal(out.z[:, :2], refs.z[:, :2]) and np.all(refs.z[:, 2] == 1.0)
    with pytest.raises(CoreError, match="1 heights for 2 reference stamps"):
        with_height(refs, t_ins, h_ins, v_up, np.array([1.0]), 0.25)
    with pytest.raises(CoreError, match="finite"):
        with_height(refs, t_ins, h_ins, v_up, np.array([1.0, np.nan]), 0.25)
    with pytest.raises(CoreError, match="variances > 0"):
        with_height(refs, t_ins, h_ins, v_up, np.array([1.0, 2.0]), 0.0)


def test_the_height_hypotheses_are_named_in_metres():
    names = {h.name: h for h in hypotheses(3, height_row=True)}
    jump = names["reference_height_jump"]
    assert jump.unit == "m" and jump.element == "dp_u"
    assert "reference_up_jump" not in names and "reference_height_outliers" in names
    assert {h.name: h for h in hypotheses(3)}["reference_up_jump"].unit == "m/s"


def _with_baro(fl, seed: int):
    """The flight's inputs with a barometric height row (turn-on bias 5 m, Gauss-Markov 2 m
    over 600 s, white 0.5 m: ``BaroConfig``'s defaults)."""
    inp = from_flight(fl)
    baro = simulate_baro(fl.truth.nav.h, fl.dt, BaroConfig(), np.random.default_rng(seed))
    refs = with_height(inp.refs, fl.t, fl.ins.h, fl.ins.v[:, 2],
                       np.interp(inp.refs.t, fl.t, baro), 0.5**2 + 2.0**2)
    return inp.steps, refs


#: the baro's Markov error as the third row's reference Markov state; a free vertical channel
HEIGHT = dict(grade="tactical", rows=3, position=True, vertical="free", height_row=True,
              ref_markov=(1e-4, 2.0, 600.0), v0_sigma_up=0.5)


@pytest.mark.parametrize("seed,onset,mg", [(3, 300.0, 1.0), (4, 200.0, -0.5)])
def test_vertical_accelerometer_named_through_the_height_row(seed, onset, mg):
    fl = flight("cruise_turns", 600.0, "tactical", "free", seed, ideal_gnss=True,
                faults=(f"accel:step:t={onset:g},mag={mg:g}mg,axis=z",))
    an = analyze_ins3d(*_with_baro(fl, seed), **HEIGHT)
    iso = an.isolation
    assert iso.isolation == "single" and iso.best == "accelerometer_z_step", iso
    c = an.decision_glr[iso.best]
    assert abs(float(c.t[c.best]) - onset) <= 5.0
    assert abs(float(c.mag[c.best]) / (mg * 9.80665e-3) - 1.0) < 0.1
    res = ins3d_result(an, "sim")
    assert res["channel"] == "en_height"
    assert set(res["in_flight"]["row_exceed_fraction"]) == {"east", "north", "height"}


def test_nominal_flight_with_a_height_row_names_nothing():
    fl = flight("cruise_turns", 600.0, "tactical", "free", 3, ideal_gnss=True)
    an = analyze_ins3d(*_with_baro(fl, 3), **HEIGHT)
    assert an.isolation.isolation == "none"
    assert 0.3 < an.forward.beta2_row[:, 2].mean() < 1.5
    assert an.forward.x.shape[1] == an.model.n and an.model.names[IP + 2] == "dp_u"


def test_the_initial_height_error_prior_of_a_datum():
    """``h0_sigma`` (``bagio.height_input``'s datum "first") sets the height error's prior
    variance and nothing else; it needs a height state."""
    base = Ins3dModel.from_grade("tactical", rows=3, position=True, height_row=True)
    m = Ins3dModel.from_grade("tactical", rows=3, position=True, height_row=True, h0_sigma=0.4)
    p, p_base = m.p0(), base.p0()
    assert p[m.ih] == pytest.approx(0.16) and p_base[m.ih] == pytest.approx(25.0)
    assert np.array_equal(np.delete(p, m.ih), np.delete(p_base, m.ih))
    loop = Ins3dModel.from_grade("tactical", rows=3, vertical="loop", h0_sigma=0.4)
    assert loop.p0()[loop.ih] == pytest.approx(0.16)
    for bad in (dict(h0_sigma=0.0, position=True), dict(h0_sigma=1.0)):
        with pytest.raises(CoreError, match="h0_sigma must be > 0, with a height state"):
            Ins3dModel.from_grade("tactical", **bad)
