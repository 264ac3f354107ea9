"""Monte Carlo evaluation: the error-rate and confusion bookkeeping on crafted records, and a tiny
seeded study run end to end."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.models import DEG_PER_HOUR, G0
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.montecarlo import (StudyConfig, by_level, confusion_matrix, declared,
                                        error_rates, plan_study, run_study, smallest_isolated,
                                        summarize, type_errors)


def record(index, kind, *, onset=None, level=None, magnitude=None, alarms=(),
           seed_verdict="no_fault", seed_element=None, glr="none", glr_onset=None, glr_mag=None, samples=1000, exceeded=0):
    """A per-flight record in the shape run_case produces."""
    true = {"nominal": "none", "accel": "accel_bias", "gyro": "gyro_drift"}[kind]
    after = [a for a in alarms if onset is not None and a >= onset]
    before = [a for a in alarms if onset is None or a < onset]
    return {"index": index, "kind": kind, "sim_seed": index, "level": level,
            "magnitude": magnitude, "onset_s": onset, "true_element": true,
            "samples": samples, "exceeded": exceeded, "alarms": list(alarms),
            "false_alarms": len(before), "first_alarm_after_onset_s": after[0] if after else None,
            "seed": {"verdict": seed_verdict, "element": seed_element, "onset_s": None,
                     "J_exceeded": 0, "J_valid": samples},
            "glr": {"hypothesis": glr, "onset_s": glr_onset, "magnitude": glr_mag,
                    "statistic": 0.0, "threshold": 30.0},
            "verdict": "no_fault", "element": None}


# --------------------------------------------------------------------------- crafted cases

def test_type_errors_counts_rejections_of_a_true_and_acceptances_of_a_false_hypothesis():
    # H0 = healthy: 1 of 4 nominal flights rejected (type I), 1 of 5 faulty accepted (type II)
    e = type_errors([True, False, False, False], [True, True, False, True, True])
    assert e == {"nominal": 4, "false_alarms": 1, "type_I": 0.25,
                 "faulty": 5, "missed": 1, "type_II": 0.2}
    assert type_errors([], [False])["type_I"] is None
    assert type_errors([False], [])["type_II"] is None


def crafted_records():
    return [
        record(0, "nominal"),
        record(1, "nominal", alarms=[120.0], seed_verdict="glitch", seed_element="tilt"),
        record(2, "nominal", glr="reference_outlier", glr_onset=10.0, glr_mag=1.0),
        record(3, "nominal"),
        # accelerometer: GLR right, seed names velocity_error; the in-flight alarm came *before*
        # the onset, so it is a false alarm and not a detection
        record(4, "accel", onset=300.0, level=1.0, magnitude=1e-3 * G0, alarms=[250.0],
               seed_verdict="failure", seed_element="velocity_error", glr="accel_bias_step",
               glr_onset=301.0, glr_mag=1.1e-3 * G0),
        # accelerometer, missed by everybody
        record(5, "accel", onset=200.0, level=0.1, magnitude=-1e-4 * G0),
        # gyro: GLR confuses it with the accelerometer, the seed method is right
        record(6, "gyro", onset=100.0, level=1.0, magnitude=DEG_PER_HOUR, alarms=[160.0],
               seed_verdict="ambiguous", seed_element="gyro_drift", glr="accel_bias_step",
               glr_onset=90.0, glr_mag=1e-4),
        # gyro: everything right
        record(7, "gyro", onset=400.0, level=1.0, magnitude=-DEG_PER_HOUR, alarms=[430.0],
               seed_verdict="glitch", seed_element="gyro_drift", glr="gyro_drift_step",
               glr_onset=396.0, glr_mag=-0.9 * DEG_PER_HOUR),
    ]


def test_error_rates_of_each_detector_on_crafted_records():
    recs = crafted_records()
    # in flight: nominal flight 1 alarms (1/4); faulty: 4 (alarm before onset) and 5 missed
    assert error_rates(recs, "in_flight") == {"nominal": 4, "false_alarms": 1, "type_I": 0.25,
                                              "faulty": 4, "missed": 2, "type_II": 0.5}
    seed = error_rates(recs, "seed")
    assert (seed["false_alarms"], seed["missed"], seed["wrong_isolation"]) == (1, 1, 1)
    glr = error_rates(recs, "glr")
    assert (glr["false_alarms"], glr["missed"], glr["wrong_isolation"]) == (1, 1, 1)
    assert glr["type_I"] == 0.25 and glr["type_II"] == 0.25
    assert not declared(recs[4], "in_flight") and declared(recs[6], "in_flight")


def test_confusion_matrices_on_crafted_records():
    recs = crafted_records()
    glr = confusion_matrix(recs, "glr")
    assert glr["true"] == ["none", "accel_bias", "gyro_drift"]
    assert glr["predicted"] == ["none", "accel_bias", "gyro_drift", "reference_outlier"]
    assert glr["counts"] == [[3, 0, 0, 1],
                             [1, 1, 0, 0],
                             [0, 1, 1, 0]]
    seed = confusion_matrix(recs, "seed")
    assert seed["predicted"] == ["none", "accel_bias", "gyro_drift", "tilt", "velocity_error"]
    assert seed["counts"] == [[3, 0, 0, 1, 0],
                              [1, 0, 0, 0, 1],
                              [0, 0, 2, 0, 0]]


def test_summary_of_crafted_records():
    m = summarize(crafted_records())
    assert m["flights"] == {"nominal": 4, "accel": 2, "gyro": 2}
    assert m["false_alarms"]["in_flight"]["per_flight_rate"] == 0.25
    assert m["false_alarms"]["in_flight"]["faulty_flights_alarm_before_onset"] == 1
    # delays: gyro 160-100 = 60 s and 430-400 = 30 s; accel: none after the onset
    assert m["detection_delay_s"]["gyro"]["n"] == 2
    assert m["detection_delay_s"]["gyro"]["median"] == pytest.approx(45.0)
    assert m["detection_delay_s"]["accel"]["n"] == 0
    # GLR onset error over correctly isolated flights: accel +1 s, gyro -4 s
    assert m["onset_error_s"]["glr"]["accel"]["mean"] == pytest.approx(1.0)
    assert m["onset_error_s"]["glr"]["gyro"]["mean"] == pytest.approx(-4.0)
    assert m["magnitude_error_relative"]["glr"]["accel"]["mean"] == pytest.approx(0.1)
    assert m["magnitude_error_relative"]["glr"]["gyro"]["mean"] == pytest.approx(-0.1)
    rows = {r["level"]: r for r in m["by_level"]["gyro"]}
    assert rows[1.0]["seed_isolated"] == 1.0 and rows[1.0]["glr_isolated"] == 0.5


def test_smallest_isolated_needs_every_larger_level_too():
    rows = [{"level": 0.1, "glr_isolated": 0.97}, {"level": 0.2, "glr_isolated": 0.90},
            {"level": 0.5, "glr_isolated": 0.96}, {"level": 1.0, "glr_isolated": 1.0}]
    assert smallest_isolated(rows, "glr") == 0.5  # 0.1 passes but 0.2 does not
    assert smallest_isolated(rows, "glr", level=0.9) == 0.1
    assert smallest_isolated([{"level": 1.0, "glr_isolated": 0.5}], "glr") is None


# --------------------------------------------------------------------------- the study

def test_plan_is_seeded_balanced_and_inside_the_onset_window():
    cfg = StudyConfig(nominal=5, per_fault=6, accel_levels_mg=(1.0, 0.5, 2.0),
                      gyro_levels_deg_h=(3.0, 1.0), duration_s=500.0, onset_window=(0.2, 0.6),
                      seed=7)
    cases = plan_study(cfg)
    assert [c.kind for c in cases] == ["nominal"] * 5 + ["accel"] * 6 + ["gyro"] * 6
    assert cfg.accel_levels_mg == (0.5, 1.0, 2.0)  # sorted
    acc = [c for c in cases if c.kind == "accel"]
    assert sorted(c.level for c in acc) == [0.5, 0.5, 1.0, 1.0, 2.0, 2.0]
    for c in cases[5:]:
        assert 100.0 - 0.05 <= c.onset_s <= 300.0 + 0.05
        unit = 1e-3 * G0 if c.kind == "accel" else DEG_PER_HOUR
        assert abs(c.magnitude) == pytest.approx(c.level * unit)
        assert c.fault().start_s == c.onset_s
    assert plan_study(cfg) == cases
    assert plan_study(StudyConfig(**{**cfg.__dict__, "seed": 8})) != cases
    assert len({c.sim_seed for c in cases}) == len(cases)


@pytest.mark.parametrize("kwargs, words", [
    ({"onset_window": (0.8, 0.2)}, "onset_window"),
    ({"nominal": 0, "per_fault": 0}, "no flights"),
    ({"accel_levels_mg": (1.0, -1.0)}, "accel_levels_mg"),
    ({"accel_levels_mg": (1.0, 1.0)}, "duplicate"),
    ({"channel": "z"}, "channel"),
])
def test_study_config_rejects_bad_settings(kwargs, words):
    with pytest.raises(EvalError, match=words) as info:
        StudyConfig(**kwargs)
    assert isinstance(info.value, CoreError)  # the CLI prints it as one line


@pytest.fixture(scope="module")
def tiny_study():
    cfg = StudyConfig(nominal=3, per_fault=4, accel_levels_mg=(2.0, 10.0),
                      gyro_levels_deg_h=(5.0, 30.0), duration_s=300.0, onset_window=(0.3, 0.6),
                      seed=11)
    return cfg, run_study(cfg, jobs=1)


def test_tiny_study_glr_isolates_every_fault_and_stays_quiet_on_nominal(tiny_study):
    _, res = tiny_study
    cm = res.metrics["confusion"]["glr"]
    assert cm["true"] == ["none", "accel_bias", "gyro_drift"]
    counts = np.array(cm["counts"])
    # large faults: GLR's matrix is diagonal; nominal flights -> none
    # (a gyro drift step and an accelerometer ramp are the same on one velocity channel: GLR
    # reports every gyro step as ambiguous, naming both, never as a confident wrong sensor)
    assert cm["predicted"] == ["none", "accel_bias", "gyro_drift", "ambiguous"]
    assert counts.tolist() == [[3, 0, 0, 0], [0, 4, 0, 0], [0, 0, 0, 4]]
    onset = res.metrics["onset_error_glr"]
    assert onset["accel"]["all"]["isolated"] == 4 and onset["gyro"]["all"]["named"] == 4
    assert onset["all"]["named"] == 8 and onset["all"]["median_abs_s"] < 2.0
    seed = np.array(res.metrics["confusion"]["seed"]["counts"])
    assert seed.sum() == 11 and seed[0, 0] == 3  # no seed-method false alarm either
    rates = res.metrics["error_rates"]["glr"]
    assert rates["type_I"] == 0.0 and rates["type_II"] == 0.0
    from flight_fdi.eval.montecarlo import format_metrics

    text = format_metrics(res.metrics)
    assert "| gyro | all | 4 | 0 | 4 |" in text and "median |onset error|" in text


def test_tiny_study_onset_magnitude_and_gate_rates_are_physical(tiny_study):
    cfg, res = tiny_study
    faulty = [r for r in res.records if r["kind"] != "nominal"]
    from flight_fdi.eval.onset import named_onset

    for r in faulty:
        # named onsets within a few seconds, magnitudes within 10 % (large steps)
        assert abs(named_onset(r) - r["onset_s"]) < 10.0
        true = next(c for c in r["glr"]["candidates"] or [r["glr"]]
                    if c["hypothesis"] in ("accel_bias_step", "gyro_drift_step"))
        assert true["magnitude"] / r["magnitude"] == pytest.approx(1.0, abs=0.1)
    # the gate's per-sample false-alarm rate on nominal flights is its probability (1e-3):
    # 3 flights x 3000 samples -> 9 expected exceedances
    fa = res.metrics["false_alarms"]["in_flight"]
    assert 1e-4 < fa["per_sample_exceed_rate"] < 3e-3
    assert fa["per_flight_rate"] == 0.0
    # the largest steps (10 mg, 30 deg/h) are caught in flight, after the onset
    for r in faulty:
        if r["level"] in (10.0, 30.0):
            assert r["first_alarm_after_onset_s"] is not None
            delay = r["first_alarm_after_onset_s"] - r["onset_s"]
            assert 0.0 <= delay < 120.0
    # 10 mg ramps the velocity error by 0.1 m/s per s against a 0.1 m/s reference: quicker
    # than a 30 deg/h gyro, which needs the tilt to grow first
    d = res.metrics["detection_delay_s"]
    accel10 = [r["first_alarm_after_onset_s"] - r["onset_s"] for r in faulty if r["level"] == 10]
    gyro30 = [r["first_alarm_after_onset_s"] - r["onset_s"] for r in faulty if r["level"] == 30]
    assert max(accel10) < min(gyro30)
    assert d["accel"]["n"] >= 2 and d["gyro"]["n"] >= 2
    small = smallest_isolated(by_level(res.records, "accel"), "glr")
    assert small == 2.0
    assert res.metrics["smallest_isolated_95"]["glr"]["gyro"]["level"] is None  # ambiguous


def test_study_result_does_not_depend_on_the_number_of_processes(tiny_study):
    cfg, res = tiny_study
    small = StudyConfig(**{**cfg.__dict__, "nominal": 1, "per_fault": 2})
    one = run_study(small, jobs=1)
    two = run_study(small, jobs=2)
    assert two.jobs == 2
    assert one.records == two.records
    assert one.metrics == two.metrics
    # the first records of the bigger study are the same flights (same plan prefix)
    assert one.records[0]["sim_seed"] == res.records[0]["sim_seed"]


def test_onset_errors_over_isolated_and_ambiguous_named_faults():
    from flight_fdi.eval.onset import named_onset, onset_errors

    def with_glr(r, isolation, candidates=()):
        r["glr"]["isolation"] = isolation
        r["glr"]["candidates"] = [{"hypothesis": h, "onset_s": o, "magnitude": None}
                                  for h, o in candidates]
        return r

    recs = [
        with_glr(record(0, "accel", onset=100.0, level=1.0, magnitude=0.01,
                        glr="accel_bias_step", glr_onset=101.0, glr_mag=0.01), "single"),
        with_glr(record(1, "accel", onset=100.0, level=1.0, magnitude=0.01,
                        glr="accel_bias_step", glr_onset=97.0, glr_mag=0.01), "single"),
        # ambiguous, the true step among the candidates: named, its own onset counts
        with_glr(record(2, "gyro", onset=200.0, level=5.0, magnitude=1e-5,
                        glr="accel_bias_ramp", glr_onset=190.0, glr_mag=1e-4), "ambiguous",
                 [("accel_bias_ramp", 190.0), ("gyro_drift_step", 204.0)]),
        # unexplained with only another sensor named: not named
        with_glr(record(3, "gyro", onset=200.0, level=5.0, magnitude=1e-5,
                        glr="reference_jump", glr_onset=150.0, glr_mag=1.0), "unexplained",
                 [("reference_jump", 150.0)]),
        with_glr(record(4, "gyro", onset=200.0, level=5.0, magnitude=1e-5), "none"),
        record(5, "nominal"),
    ]
    assert [named_onset(r) for r in recs] == [101.0, 97.0, 204.0, None, None, None]
    t = onset_errors(recs)
    assert t["accel"]["all"] == {"n": 2, "isolated": 2, "named": 2, "median_abs_s": 2.0,
                                 "p95_abs_s": pytest.approx(2.9), "median_s": -1.0}
    g = t["gyro"]["by_level"][0]
    assert (g["level"], g["n"], g["isolated"], g["named"], g["median_abs_s"]) == \
        (5.0, 3, 0, 1, 4.0)
    assert t["all"] == {"named": 3, "median_abs_s": 3.0}
    cm = confusion_matrix(recs, "glr")
    assert cm["predicted"] == ["none", "accel_bias", "gyro_drift", "ambiguous"]
