"""The 3-D study's metrics on hand-made records (known answers): a wrong axis is wrong, an
ambiguous result is not a false isolation but is counted, the single-axis model is scored on the
sensor only for body-axis faults, onset and magnitude errors, the smallest level isolated in
95 %, and how the two single-axis channels make one flight result."""
from __future__ import annotations

import json

import pytest

from flight_fdi.eval.metrics3d import (format_metrics, named, nominal_rates, outcome, rates,
                                       smallest_isolated, summarize)
from flight_fdi.eval.montecarlo3d import combine_channels, decision


def dec(verdict="no_fault", isolation="none", sensor=None, axis=None, kind=None, onset=None,
        mag=None, candidates=(), statistic=None, threshold=None):
    return {"verdict": verdict, "isolation": isolation, "sensor": sensor, "axis": axis,
            "kind": kind, "onset_s": onset, "magnitude": mag, "statistic": statistic,
            "threshold": threshold, "candidates": list(candidates)}


def single(sensor, axis, kind="step", onset=100.0, mag=1.0):
    return dec("failure", "single", sensor, axis, kind, onset, mag)


def rec(i, scenario, ins3d, single_axis=None, sensor=None, axis=None, kind=None, level=None,
        mag=None, onset=None, in_turn=False):
    return {"index": i, "scenario": scenario, "sensor": sensor, "axis": axis, "kind": kind,
            "level": level, "magnitude": mag, "onset_s": onset, "onset_in_turn": in_turn,
            "next_turn_s": None, "ins3d": ins3d,
            "single_axis": single_axis if single_axis is not None else dec()}


def accel(i, ins3d, axis="y", level=0.5, mag=2.0, onset=100.0, single_axis=None, in_turn=False):
    return rec(i, "accel_step", ins3d, single_axis, "accelerometer", axis, "step", level, mag,
               onset, in_turn)


def test_outcomes_wrong_axis_is_wrong_and_ambiguous_is_counted():
    assert outcome(accel(0, single("accelerometer", "y")), "ins3d") == "right"
    assert outcome(accel(0, single("accelerometer", "x")), "ins3d") == "wrong"
    assert outcome(accel(0, single("gyro", "y")), "ins3d") == "wrong"
    amb = dec("ambiguous", "ambiguous", candidates=[
        {"sensor": "gyro", "axis": "x"}, {"sensor": "accelerometer", "axis": "y"}])
    assert outcome(accel(0, amb), "ins3d") == "ambiguous"
    assert named(accel(0, amb), "ins3d")
    assert not named(accel(0, amb, axis="z"), "ins3d")
    assert outcome(accel(0, dec()), "ins3d") == "none"
    # a verdict without a fault is 'none' whatever the isolation field says
    assert outcome(accel(0, dec("insufficient_data", "single", "gyro", "x")), "ins3d") == "none"
    # the seed method's episode without a GLR sensor: declared, nothing named
    assert outcome(accel(0, dec("failure", "none")), "ins3d") == "unnamed"


def test_single_axis_is_scored_on_the_sensor_for_body_axis_faults_only():
    sa = single("accelerometer", "east")
    r = accel(0, dec(), single_axis=sa, axis="y")
    assert outcome(r, "single_axis") == "right"         # the body axis cannot be named
    x = rates([r], "single_axis")
    assert x["right_rate"] is None and x["right_sensor_rate"] == 1.0
    jump = rec(1, "ref_jump", dec(), single("reference", "north", "jump"), "reference", "east",
               "jump", 0.5, 0.5, 100.0)
    assert outcome(jump, "single_axis") == "wrong"      # the GNSS axis is its channel: scored


def test_rates_on_a_hand_made_set():
    true_mag = 2.0
    rs = [accel(0, single("accelerometer", "y", onset=103.0, mag=2.2)),   # right, +3 s, +10 %
          accel(1, single("accelerometer", "y", "ramp", onset=94.0, mag=1.8)),  # right, ramp
          accel(2, single("accelerometer", "x")),                          # wrong axis
          accel(3, dec("ambiguous", "unexplained")),                      # ambiguous
          accel(4, dec())]                                                # missed
    x = rates(rs, "ins3d")
    assert (x["n"], x["right"], x["wrong"], x["ambiguous"], x["none"]) == (5, 2, 1, 1, 1)
    assert x["right_rate"] == pytest.approx(0.4)
    assert x["right_sensor_rate"] == pytest.approx(0.6)  # the wrong axis had the right sensor
    assert x["wrong_rate"] == pytest.approx(0.2) and x["ambiguous_rate"] == pytest.approx(0.2)
    assert x["right_kind"] == 1 and x["right_kind_rate"] == pytest.approx(0.2)
    assert x["onset_error_s"]["n"] == 2
    assert x["onset_error_s"]["median"] == pytest.approx(-1.5)       # (+3, -6)
    assert x["onset_error_s"]["median_abs"] == pytest.approx(4.5)
    # the ramp reported for a step has a magnitude in other units: left out
    assert x["magnitude_error"]["n"] == 1
    assert x["magnitude_error"]["median"] == pytest.approx(2.2 / true_mag - 1.0)
    assert x["onset_interval_n"] == 0 and x["onset_coverage"] is None


def test_onset_interval_coverage_over_the_right_flights():
    def iv(onset, a, b, axis="y"):
        d = single("accelerometer", axis, onset=onset)
        d["onset_interval_s"] = [a, b]
        return d
    rs = [accel(0, iv(103.0, 95.0, 110.0)),              # covers 100
          accel(1, iv(104.0, 101.0, 108.0)),             # misses 100 (too narrow)
          accel(2, iv(100.0, 100.0, 100.0)),             # exact, zero width: covers
          accel(3, iv(90.0, 50.0, 150.0, axis="x")),     # wrong axis: not scored
          accel(4, single("accelerometer", "y"))]        # right, no interval: not scored
    x = rates(rs, "ins3d")
    assert (x["onset_interval_n"], x["onset_covered"]) == (3, 2)
    assert x["onset_coverage"] == pytest.approx(2 / 3)
    assert x["onset_interval_width_s"]["median"] == pytest.approx(7.0)    # 15, 7, 0


def test_nominal_flights_false_isolation_versus_declaration():
    nom = [rec(i, "nominal", d) for i, d in enumerate(
        [dec(), dec(), single("gyro", "z"), dec("ambiguous", "ambiguous"),
         dec("ambiguous", "unexplained"), dec("glitch", "none")])]
    x = nominal_rates(nom, "ins3d")
    assert x["n"] == 6 and x["false_isolations"] == 1
    assert x["false_isolation_rate"] == pytest.approx(1 / 6)
    assert x["ambiguous"] == 2 and x["unnamed"] == 1
    assert x["false_declaration_rate"] == pytest.approx(4 / 6)
    assert x["isolated_as"] == {"gyro": 1}
    lo, hi = x["false_isolation_interval"]         # exact: P(>= 1 of 6) = 0.025 at lo
    assert 1 - (1 - lo) ** 6 == pytest.approx(0.025) and (1 - hi) ** 6 + 6 * hi * (
        1 - hi) ** 5 == pytest.approx(0.025)
    assert json.loads(json.dumps(x)) == x          # JSON-able as it is (a list, not a tuple)


def test_smallest_level_isolated_in_95_percent():
    rows = [{"level": 0.1, "right_rate": 1.0}, {"level": 0.2, "right_rate": 0.9},
            {"level": 0.4, "right_rate": 0.95}, {"level": 0.8, "right_rate": 1.0}]
    assert smallest_isolated(rows) == 0.4        # 0.1 passes but 0.2 above it does not
    assert smallest_isolated(rows[:2]) is None
    assert smallest_isolated([{"level": 1.0, "right_rate": None}]) is None


def test_summarize_and_format_split_turns_and_levels():
    rs = [rec(0, "nominal", dec()),
          accel(1, single("accelerometer", "y"), level=0.3, in_turn=True),
          accel(2, single("accelerometer", "y"), level=0.3),
          accel(3, dec("ambiguous", "ambiguous"), level=0.3),
          accel(4, single("accelerometer", "y"), level=0.6)]
    m = summarize(rs)
    s = m["ins3d"]["scenarios"]["accel_step"]
    assert s["in_turn"]["n"] == 1 and s["in_turn"]["right_rate"] == 1.0
    assert s["straight"]["n"] == 3
    assert s["straight"]["right_rate"] == pytest.approx(2 / 3)
    assert m["ins3d"]["smallest_isolated_95"]["accel_step"] == {"y": 0.6}
    text = format_metrics(m)
    assert "| accel_step | ins3d | 4 | 75.0 % |" in text
    assert "accel_step: y 0.6 mg" in text


def test_decision_and_channel_combination():
    post = {"verdict": "failure", "isolation": "single", "candidates": [],
            "fault": {"sensor": "reference", "axis": "north", "kind": "jump", "onset_s": 5.0,
                      "magnitude": 0.4, "statistic": 90.0, "threshold": 30.0}}
    d = decision(post)
    assert (d["sensor"], d["axis"], d["onset_s"], d["statistic"]) == ("reference", "north",
                                                                       5.0, 90.0)
    east = dec("ambiguous", "unexplained", statistic=400.0, threshold=100.0)   # 4x
    north = dict(d)                                                          # 3x
    assert combine_channels({"east": east, "north": north})["channel"] == "east"
    assert combine_channels({"east": dec(), "north": north})["channel"] == "north"
    none = combine_channels({"east": dec(), "north": dec()})
    assert none["channel"] is None and none["verdict"] == "no_fault"
