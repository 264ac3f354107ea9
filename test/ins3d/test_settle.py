"""The decision against the rival fitted together with the best (glr3d.pair_glr, settle):
known answers from least squares on constructed signatures -- nearly collinear signatures with
a model error -> ambiguous, distinct ones -> confident -- and on a simulated flight the pair's
statistics from the forward signatures equal the two-column regression."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.core.ins3d.glr3d import (AMBIGUITY_MARGIN, Isolation, hypotheses, isolate,
                                         pair_glr, settle)
from flight_fdi.core.ins3d.postflight import fused_forward, signature

from .test_backward import short_analysis


def _pair(s_b: np.ndarray, s_r: np.ndarray, y: np.ndarray):
    """e, D of two signatures (columns of whitened innovations) for the data y."""
    S = np.stack([s_b, s_r], axis=1)
    return S.T @ y, S.T @ S


def _signatures(cos: float, n: int = 40) -> tuple[np.ndarray, np.ndarray]:
    """Two unit signatures in R^n at the angle acos(cos) (seeded)."""
    rng = np.random.default_rng(3)
    a = rng.standard_normal(n)
    a /= np.linalg.norm(a)
    o = rng.standard_normal(n)
    o -= (o @ a) * a
    o /= np.linalg.norm(o)
    return a, cos * a + math.sqrt(1.0 - cos * cos) * o


def test_pair_glr_is_the_two_column_regression():
    rng = np.random.default_rng(1)
    s_b, s_r = rng.standard_normal(30), rng.standard_normal(30)
    y = 3.0 * s_b - 1.0 * s_r + rng.standard_normal(30)
    e, D = _pair(s_b, s_r, y)
    S = np.stack([s_b, s_r], axis=1)
    fit = S @ np.linalg.lstsq(S, y, rcond=None)[0]
    assert pair_glr(e, D) == pytest.approx(fit @ fit, rel=1e-12)
    # the same signature twice carries the GLR of one (pseudo-inverse)
    e1, D1 = _pair(s_b, s_b, y)
    assert pair_glr(e1, D1) == pytest.approx((s_b @ y) ** 2 / (s_b @ s_b), rel=1e-9)


def _iso() -> Isolation:
    return Isolation("single", "accelerometer_y_ramp", "gyro_x_step", 0)


def test_nearly_collinear_signatures_with_a_model_error_are_ambiguous():
    """The rival (s_r) is the true fault, its real effect off its signature by 0.28 rad toward
    the best's (s_b, at cos 0.9 from it): the best wins by far more than the margin, so the
    gap rule alone names the wrong one with confidence; allowed a model error of 0.3 rad the
    rival stays a candidate -> ambiguous, reason ``model``."""
    s_b, s_r = _signatures(0.9)
    o = s_b - (s_b @ s_r) * s_r
    o /= np.linalg.norm(o)
    b = 25.0                                    # GLR of the fault 625
    y = b * (math.cos(0.28) * s_r + math.sin(0.28) * o)
    e, D = _pair(s_b, s_r, y)
    L_b, L_r = e[0] ** 2, e[1] ** 2
    assert L_b - L_r > AMBIGUITY_MARGIN + 10.0       # the old rule: confident, wrong
    assert settle(_iso(), e, D, 1e-5).isolation == "single"
    iso = settle(_iso(), e, D, 0.3)
    assert (iso.isolation, iso.reason) == ("ambiguous", "model")
    assert iso.similarity == pytest.approx(0.9, abs=1e-12)
    assert iso.pair == pytest.approx(b * b, rel=1e-12)     # y lies in the pair's plane


def test_distinct_signatures_stay_confident():
    """The best is the true fault (GLR 400), the rival's signature at cos 0.3 from it: the
    rival, even allowed a 0.3-rad model error, explains far less -> single."""
    s_b, s_r = _signatures(0.3)
    rng = np.random.default_rng(5)
    y = 20.0 * s_b + 0.5 * rng.standard_normal(s_b.size)
    iso = settle(_iso(), *_pair(s_b, s_r, y), 0.3)
    assert iso.isolation == "single" and iso.reason is None
    assert iso.rival_gain < AMBIGUITY_MARGIN


def test_settle_leaves_other_isolations_and_the_gap_rule_as_they_were():
    """Without a model error the check is the gap rule: a single isolation from ``isolate``
    (gap >= margin) stays single; ambiguous / none are not touched."""
    s_b, s_r = _signatures(0.95)
    y = 10.0 * s_b
    e, D = _pair(s_b, s_r, y)
    assert e[0] ** 2 - e[1] ** 2 >= AMBIGUITY_MARGIN
    assert settle(_iso(), e, D, 1e-5).isolation == "single"
    amb = Isolation("ambiguous", "accelerometer_y_ramp", "gyro_x_step", 0, reason="margin")
    assert settle(amb, e, D, 0.3).reason == "margin"
    assert settle(Isolation("none", None, None, 0), e, D, 0.3).isolation == "none"


def test_the_pair_of_a_simulated_flight_from_the_forward_signatures():
    """On a simulated flight (gyro x step, navigation grade: the default model error is the
    grade's misalignment) the isolation stays single and its recorded pair statistic is the
    GLR of the two forward signatures fitted together (e' D^-1 e of their e, d and cross
    term), at least the best's alone."""
    a = short_analysis(faults=("gyro:step:t=200,mag=0.5deg/h,axis=x",), seed=6)
    iso = a.isolation
    assert iso.isolation == "single" and iso.rival is not None and iso.reason is None
    fwd = fused_forward(a.model, a.steps, a.refs, a.forward)
    e_b, d_b, r_b = signature(a.model, a.steps, a.refs, fwd, a.glr[iso.best])
    e_r, d_r, r_r = signature(a.model, a.steps, a.refs, fwd, a.glr[iso.rival])
    x = float(np.einsum("mi,mij,mj->", r_b, fwd.S_inv, r_r))
    D = np.array([[d_b[-1], x], [x, d_r[-1]]])
    e = np.array([e_b[-1], e_r[-1]])
    assert iso.pair == pytest.approx(float(e @ np.linalg.solve(D, e)), rel=1e-9)
    assert iso.pair >= a.glr[iso.best].statistic * (1 - 1e-9)
    assert 0.0 <= iso.similarity <= 1.0
    pf = a.post_flight_dict()["glr"]
    assert pf["runner_up_gain"] == pytest.approx(iso.rival_gain)
    assert pf["signature_similarity"] == pytest.approx(iso.similarity)


def test_isolate_marks_the_margin_reason():
    hyps = {h.name: h for h in hypotheses(2)}
    from flight_fdi.core.ins3d.glr3d import GlrCurve
    t = np.arange(3.0)

    def cv(name, peak):
        return GlrCurve(hyps[name], t, np.array([0.0, peak, 0.0]), np.ones(3), np.ones(3))
    base = {n: cv(n, 1.0) for n in hyps}
    two = dict(base, gyro_x_step=cv("gyro_x_step", 100.0),
               accelerometer_y_ramp=cv("accelerometer_y_ramp", 95.0))
    thr = {"step": 20.0, "ramp": 20.0, "jump": 20.0, "outliers": 30.0}
    iso = isolate(two, thr)
    assert (iso.isolation, iso.reason) == ("ambiguous", "margin")
