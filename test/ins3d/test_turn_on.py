"""A turn-on bias (a bias step best at the flight's first update) told apart from an in-flight
step (core/ins3d/turn_on.py): on short simulated flights (cruise_turns, 420 s, navigation
grade) with an accelerometer y bias of 0.3 mg (10 prior sigmas) present from the start -- put
in after the simulator's alignment (t = 0.05 s, before the first GNSS update at 0.1 s), so the
levelled tilt does not cancel it, as on the real recordings aligned from the ground truth's
attitude (docs/ins3d_real.md) -- alone, with an in-flight step on another sensor, and the
nominal flight and an in-flight step of the same sensor beside them."""
from __future__ import annotations

import functools

import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.glr3d import GlrCurve, hypotheses, pair_glr
from flight_fdi.core.ins3d.postflight import fused_forward, signature
from flight_fdi.core.ins3d.turn_on import Given

from .conftest import flight
from .test_postflight import validate

TURN_ON = "accel:step:t=0.05,mag=0.3mg,axis=y"
IN_FLIGHT = "accel:step:t=150,mag=0.3mg,axis=x"


@functools.lru_cache(maxsize=4)
def analysis(*faults: str):
    inp = from_flight(flight("cruise_turns", 420.0, "navigation", "baro", 5, faults=faults))
    return analyze_ins3d(inp.steps, inp.refs, with_observability=False)


def _turn_on_is_the_injected_one(pf: dict) -> None:
    (r,) = pf["turn_on_bias"]
    assert (r["sensor"], r["axis"], r["unit_eng"]) == ("accelerometer", "y", "mg")
    assert r["onset_s"] == pytest.approx(0.1)                # the first update
    sd_mg = r["magnitude_std"] * r["magnitude_eng"] / r["magnitude"]
    assert abs(r["magnitude_eng"] - 0.3) < 2.0 * sd_mg and sd_mg < 0.05
    assert r["prior_sigmas"] == pytest.approx(0.3 / 0.03, rel=0.1)   # grade: 30 ug
    assert r["statistic"] > 10 * r["threshold"] and r["statistic_given_others"] > r["threshold"]
    assert "accelerometer y turn-on bias of +0.3" in pf["headline"]


def test_turn_on_bias_and_an_in_flight_step_of_another_sensor():
    """The in-flight accelerometer x step is the fault (right axis, onset, magnitude), the
    accelerometer y bias from the start is reported beside it, not as the fault."""
    pf = analysis(TURN_ON, IN_FLIGHT).post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], pf["isolation"]) == ("failure", "single")
    assert (f["sensor"], f["axis"], f["kind"]) == ("accelerometer", "x", "step")
    assert abs(f["onset_s"] - 150.0) < 15.0
    assert f["magnitude_eng"] == pytest.approx(0.3, abs=3 * f["magnitude_std"] * 1e3 / 9.80665)
    assert pf["headline"].startswith("accelerometer x: bias step")
    assert pf["glr"]["given_turn_on"] == ["accelerometer_y_step"]
    _turn_on_is_the_injected_one(pf)


def test_turn_on_bias_alone_is_not_an_in_flight_fault():
    """Before, the bias from the start was the isolated fault (a step at 0.1 s): now no
    in-flight fault is named and the turn-on bias is the finding."""
    a = analysis(TURN_ON)
    c = a.glr["accelerometer_y_step"]
    assert c.best == 0 and c.statistic > a.thresholds["step"]      # what the old answer named
    pf = a.post_flight_dict()
    validate(pf)
    assert (pf["fault"], pf["isolation"], pf["candidates"]) == (None, "none", [])
    assert pf["verdict"] != "failure"
    assert "GLR finds no in-flight fault" in pf["headline"] or \
        pf["headline"].startswith("no in-flight fault; ")
    _turn_on_is_the_injected_one(pf)
    assert not a.bias_estimates()["accelerometer_fault"].any()


def test_nominal_flight_has_neither():
    a = analysis()
    pf = a.post_flight_dict()
    assert (pf["verdict"], pf["fault"], pf["turn_on_bias"]) == ("no_fault", None, [])
    assert a.turn_on is None and pf["headline"] == "no fault"


def test_in_flight_step_is_not_a_turn_on_bias():
    """A step at 150 s whose GLR at the first update is above the threshold too (the bias is
    there for 64 % of the flight) but best at its own onset: the fault, no turn-on bias (the
    rule is the best onset, not an onset interval or a statistic reaching the first update)."""
    a = analysis("accel:step:t=150,mag=0.3mg,axis=y")
    c = a.glr["accelerometer_y_step"]
    assert c.stat[0] > a.thresholds["step"] and c.best > 0
    pf = a.post_flight_dict()
    f = pf["fault"]
    assert (pf["verdict"], f["sensor"], f["axis"]) == ("failure", "accelerometer", "y")
    assert abs(f["onset_s"] - 150.0) < 20.0
    assert pf["turn_on_bias"] == [] and a.turn_on is None


def test_conditional_statistic_is_the_pair_fit_minus_the_turn_on_alone():
    """Known answer: the conditional GLR of h at an onset given the turn-on bias (one backward
    sweep with the turn-on signature as the innovations) equals the two-column fit of the
    forward signatures of h there and of the turn-on step, minus the turn-on step alone."""
    a = analysis(TURN_ON, IN_FLIGHT)
    fwd = fused_forward(a.model, a.steps, a.refs, a.forward)
    ccv = a.turn_on.curves
    T = a.glr["accelerometer_y_step"]
    e_T, d_T, rho_T = signature(a.model, a.steps, a.refs, fwd, T)
    h = next(x for x in hypotheses(a.model.rows) if x.name == "gyro_x_ramp")
    for name, k in (("accelerometer_x_step", ccv["accelerometer_x_step"].best),
                    ("gyro_x_ramp", 40)):
        c = ccv[name]
        one = GlrCurve(c.hypothesis if name != "gyro_x_ramp" else h, c.t[k:k + 1],
                       np.ones(1), np.ones(1), np.ones(1))
        e_h, d_h, rho_h = signature(a.model, a.steps, a.refs, fwd, one)
        x = float(np.einsum("mi,mij,mj->", rho_h, fwd.S_inv, rho_T))
        brute = pair_glr(np.array([e_h[-1], e_T[-1]]),
                         np.array([[d_h[-1], x], [x, d_T[-1]]])) - e_T[-1] ** 2 / d_T[-1]
        assert brute > 1.0 and c.stat[k] == pytest.approx(brute, rel=1e-6)
    # Given: the joint fit's GLR of each given the other
    g = Given.of(["T", "h"], [(e_T, d_T, rho_T), (e_h, d_h, rho_h)], fwd.S_inv)
    b, P, stat = g.fit()
    assert stat[1] == pytest.approx(brute, rel=1e-6)
