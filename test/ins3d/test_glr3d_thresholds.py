"""Per-hypothesis GLR thresholds (glr3d.thresholds_for / threshold_of / length_growth) and the
decision with unequal thresholds (glr3d.isolate compares each hypothesis' excess over its own
threshold): constructed curves with known answers."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.core.ins3d import glr3d
from flight_fdi.core.ins3d.glr3d import (AMBIGUITY_MARGIN, CALIBRATED_LENGTH_S, GlrCurve,
                                         PER_HYPOTHESIS, THRESHOLDS_BY_GRADE, growth_of,
                                         hypotheses, isolate, length_growth, threshold_of,
                                         thresholds_for)

HYPS = {h.name: h for h in hypotheses(3)}
#: the 2-h navigation thresholds per kind before per-hypothesis thresholds (20 + ln 4 ...)
KIND_2H = {"step": 21.39, "ramp": 20.0, "jump": 32.77, "outliers": 34.77}


def _curve(name: str, peak: float) -> GlrCurve:
    t = np.arange(5.0)
    return GlrCurve(HYPS[name], t, np.array([0.0, 1.0, peak, 1.0, 0.0]), np.ones(5), np.ones(5))


def _curves(**peaks: float) -> dict[str, GlrCurve]:
    """Every hypothesis at 1 (noise) except the given ones."""
    return {n: _curve(n, peaks.get(n, 1.0)) for n in HYPS}


def test_threshold_of_uses_the_hypothesis_own_else_its_kind():
    thr = {"step": 21.0, "ramp": 20.0, "jump": 33.0, "outliers": 35.0, "gyro_z_step": 16.0,
           "reference_east_outliers": 1.0}
    assert threshold_of(thr, HYPS["gyro_z_step"]) == 16.0
    assert threshold_of(thr, HYPS["gyro_x_step"]) == 21.0
    assert threshold_of(thr, HYPS["gyro_z_ramp"]) == 20.0
    assert threshold_of(thr, HYPS["reference_up_jump"]) == 33.0
    # outliers: always the kind's (one threshold for every row's per-update statistic)
    assert threshold_of(thr, HYPS["reference_east_outliers"]) == 35.0


def test_thresholds_for_carries_the_navigation_hypotheses_and_falls_back_per_kind():
    nav = thresholds_for("navigation")
    for k, v in THRESHOLDS_BY_GRADE["navigation"].items():
        assert nav[k] == v
    for h, v in glr3d.HYPOTHESIS_THRESHOLDS_BY_GRADE.get("navigation", {}).items():
        assert h in PER_HYPOTHESIS and nav[h] == v
    tac = thresholds_for("tactical")          # not calibrated per hypothesis: kinds only
    assert set(tac) == set(THRESHOLDS_BY_GRADE["tactical"])
    assert thresholds_for("mems") == tac      # a grade not calibrated: tactical's
    assert threshold_of(tac, HYPS["gyro_z_step"]) == tac["step"]


def test_the_length_rule_moves_each_threshold_by_its_own_growth(monkeypatch):
    monkeypatch.setitem(glr3d.HYPOTHESIS_THRESHOLDS_BY_GRADE, "navigation",
                        {"gyro_z_step": 15.0, "reference_up_jump": 27.0})
    monkeypatch.setattr(glr3d, "HYPOTHESIS_LENGTH_GROWTH", {"gyro_z_step": 0.5})
    ln4 = math.log(4.0)
    long = thresholds_for("navigation", 4 * CALIBRATED_LENGTH_S)
    assert long["gyro_z_step"] == pytest.approx(15.0 + 0.5 * ln4)          # measured growth
    assert long["reference_up_jump"] == pytest.approx(27.0 + 2.0 * ln4)    # its kind's
    assert long["step"] == pytest.approx(20.0 + ln4)
    assert growth_of("gyro_x_ramp") == 0.0 and growth_of("jump") == 2.0
    # flights of 30 min or less keep the stated thresholds
    assert thresholds_for("navigation", 600.0)["gyro_z_step"] == 15.0
    assert length_growth(None) == {} and length_growth(CALIBRATED_LENGTH_S) == {}
    assert set(length_growth(7200.0)) == {"step", "ramp", "jump", "outliers", *PER_HYPOTHESIS}


def test_a_z_step_above_its_own_lower_threshold_is_isolated():
    """A vertical gyro step at 19: below the step kind's 21.4 (the old rule: nothing), above
    its own 16 -- isolated, though a GNSS jump fitted to the noise has a larger raw
    statistic (25, far below the jumps' 32.8)."""
    cv = _curves(gyro_z_step=19.0, reference_east_jump=25.0, accelerometer_x_step=8.0)
    assert isolate(cv, KIND_2H).isolation == "none"
    iso = isolate(cv, {**KIND_2H, "gyro_z_step": 16.0})
    assert (iso.isolation, iso.best, iso.rival) == ("single", "gyro_z_step",
                                                    "reference_east_jump")
    # the decision's gap is the raw gap minus the thresholds' offset: (19 - 25) - (16 - 32.77)
    assert iso.offset == pytest.approx(16.0 - 32.77)
    assert (19.0 - 25.0) - iso.offset == pytest.approx(10.77)
    assert isolate(cv, {**KIND_2H, "gyro_z_step": 16.0}, compare="raw").isolation == "ambiguous"


def test_the_raw_margin_against_a_noise_jump_no_longer_makes_it_ambiguous():
    """z step 24 > 21.4 with a jump of 27 (noise, 5.8 below its threshold): the raw rule says
    ambiguous (gap -3); by the excess over the own thresholds the gap is 2.6 + 5.8 = 8.4
    (kind thresholds) -- still within the margin -- and 8 + 5.8 with the z step's own 16."""
    cv = _curves(gyro_z_step=24.0, reference_east_jump=27.0)
    old = isolate(cv, {"step": 21.39, "ramp": 21.39, "jump": 21.39, "outliers": 34.77})
    assert (old.isolation, old.best) == ("ambiguous", "reference_east_jump")
    assert isolate(cv, KIND_2H).isolation == "ambiguous"         # 8.4 < 9.21
    iso = isolate(cv, {**KIND_2H, "gyro_z_step": 16.0})
    assert (iso.isolation, iso.best) == ("single", "gyro_z_step")


def test_a_rival_above_its_own_threshold_still_makes_it_ambiguous():
    thr = {**KIND_2H, "gyro_z_step": 16.0, "accelerometer_x_step": 18.0}
    cv = _curves(gyro_z_step=26.0, accelerometer_x_step=25.0)    # excess 10 and 7: 3 < 9.21
    iso = isolate(cv, thr)
    assert (iso.isolation, iso.best, iso.rival, iso.reason) == (
        "ambiguous", "gyro_z_step", "accelerometer_x_step", "margin")
    # the rival's larger raw statistic does not make it the best: its excess is smaller
    cv = _curves(gyro_z_step=26.0, accelerometer_y_step=28.0)    # excess 10 and 6.6
    iso = isolate(cv, thr)
    assert (iso.isolation, iso.best, iso.rival) == ("ambiguous", "gyro_z_step",
                                                    "accelerometer_y_step")
    cv = _curves(gyro_z_step=36.0, accelerometer_y_step=28.0)    # 20 - 6.6 >= 9.21
    assert isolate(cv, thr).isolation == "single"


def test_equal_thresholds_give_the_raw_rule_and_the_outlier_rule_is_unchanged():
    eq = {"step": 20.0, "ramp": 20.0, "jump": 20.0, "outliers": 30.0}
    rng = np.random.default_rng(5)
    main = [n for n in HYPS if not n.endswith("outliers")]
    for _ in range(200):              # the raw statistics decide as before when all are equal
        peaks = {n: float(v) for n, v in zip(main, rng.exponential(8.0, len(main)))}
        iso = isolate(_curves(**peaks), eq)
        best = max(peaks, key=peaks.get)
        if peaks[best] <= 20.0:
            assert iso.isolation == "none"
            continue
        h = HYPS[best]
        if h.kind == "ramp" and peaks[best.replace("_ramp", "_step")] > max(
                20.0, peaks[best] - AMBIGUITY_MARGIN):
            best, h = best.replace("_ramp", "_step"), HYPS[best.replace("_ramp", "_step")]
        rival = max((n for n in main if (HYPS[n].sensor, HYPS[n].axis) != (h.sensor, h.axis)),
                    key=peaks.get)
        assert iso.best == best and iso.rival == rival
        assert iso.isolation == ("single" if peaks[best] - peaks[rival] >= AMBIGUITY_MARGIN
                                 else "ambiguous")
    thr = {**KIND_2H, "gyro_z_step": 16.0}
    # spikes that explain at least as much as every detected sustained fault: a glitch
    iso = isolate(_curves(gyro_z_step=19.0, reference_north_outliers=40.0), thr)
    assert (iso.isolation, iso.best, iso.outliers) == ("single", "reference_north_outliers", 1)
    # ... raw statistics, as before: 36 < 45 -> the step, the outliers counted
    iso = isolate(_curves(gyro_z_step=45.0, reference_north_outliers=36.0), thr)
    assert (iso.isolation, iso.best, iso.outliers) == ("single", "gyro_z_step", 1)


def test_settle_judges_the_pair_by_the_same_excess_as_isolate():
    """A z step isolated by its excess over a rival whose raw statistic is the larger one (the
    rival's threshold 15.8 above the z step's). Signatures at 44 deg, the data between them in
    their plane: L_b = 40, L_r = 44, the pair L2 = |y|^2 = 49. The raw pair test (L2 - L_r = 5
    < 9.21) called it ambiguous even with an exact model; net of the same offset as isolate's
    (5 + 15.8) it stays single at eps = 0, and a model error beyond what that gap leaves makes
    it ambiguous."""
    from flight_fdi.core.ins3d.glr3d import settle

    thr = {**KIND_2H, "gyro_z_step": 20.0, "reference_east_jump": 35.8}

    def decided():
        iso = isolate(_curves(gyro_z_step=40.0, reference_east_jump=44.0), thr)
        assert (iso.isolation, iso.best, iso.rival) == ("single", "gyro_z_step",
                                                         "reference_east_jump")
        return iso

    assert decided().offset == pytest.approx(20.0 - 35.8)
    c = math.cos(math.acos(math.sqrt(40.0) / 7.0) + math.acos(math.sqrt(44.0) / 7.0))
    e, D = np.array([math.sqrt(40.0), math.sqrt(44.0)]), np.array([[1.0, c], [c, 1.0]])
    assert glr3d.pair_glr(e, D) == pytest.approx(49.0)
    assert settle(decided(), e, D, 0.0).isolation == "single"
    eps = math.asin(math.sqrt((5.0 + 15.8 - AMBIGUITY_MARGIN) / 49.0))   # the room left
    assert settle(decided(), e, D, eps - 0.01).isolation == "single"
    iso = settle(decided(), e, D, eps + 0.01)
    assert (iso.isolation, iso.reason) == ("ambiguous", "model")


def test_a_flight_reports_the_isolated_hypothesis_own_threshold_and_the_decision_gap():
    """On a simulated flight (420 s, an accelerometer x step at 150 s): the result's fault and
    glr carry the hypothesis' own threshold (navigation: 19.7, its kind's 20), and the gap over
    time whose end decides the isolation is the excess gap of isolate: at the last update
    (L_b - c_b) - (L_r - c_r) of the curves (forward signatures = backward sweep)."""
    from .test_turn_on import IN_FLIGHT, analysis

    a = analysis(IN_FLIGHT)
    pf, iso = a.post_flight_dict(), a.isolation
    assert (iso.isolation, iso.best) == ("single", "accelerometer_x_step")
    own = threshold_of(a.thresholds, HYPS["accelerometer_x_step"])
    assert own == glr3d.HYPOTHESIS_THRESHOLDS_BY_GRADE["navigation"]["accelerometer_x_step"]
    assert own != a.thresholds["step"]
    assert pf["fault"]["threshold"] == pf["glr"]["threshold"] == own
    b, r = a.glr[iso.best], a.glr[iso.rival]
    excess_gap = (b.statistic - own) - (r.statistic - threshold_of(a.thresholds, r.hypothesis))
    assert iso.gap[-1] == pytest.approx(excess_gap, rel=1e-6)
