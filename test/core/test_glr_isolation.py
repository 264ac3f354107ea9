"""GLR on flights from the project's simulator (its fault catalogue, not the GLR signature):
ramps beside steps, ambiguity, the second pass on the residual, onset estimates, and the
result built from them (post_flight.fault)."""
from __future__ import annotations

import pytest

from flight_fdi.core.analysis import run_analysis
from flight_fdi.core.glr import GlrConfig
from flight_fdi.schema import validate_result
from flight_fdi.sim import SimConfig, simulate
from flight_fdi.sim.faults import parse_fault


def analyse(faults, seed=0, duration=1000.0, **glr):
    fl = simulate(SimConfig(duration_s=duration, seed=seed,
                            faults=tuple(parse_fault(f) for f in faults)))
    kw = {}
    if glr:
        from flight_fdi.core.analysis import AnalysisConfig

        kw["config"] = AnalysisConfig(**glr)
    res = run_analysis(fl.model, fl.t, fl.v_ins[:, 0], fl.t_ref, fl.v_ref[:, 0], t0=0.0, **kw)
    validate_result(res.summary)
    return res


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_accelerometer_ramp_of_the_issue_is_never_a_confident_gyro_step(seed):
    # 2e-5 m/s^2 per s from 300 s: once "FAILURE gyro_drift step ... statistic 410"
    res = analyse(["accel:ramp:t=300,mag=2e-5"], seed)
    post = res.summary["post_flight"]
    assert post["verdict"] in ("failure", "ambiguous")
    if post["verdict"] == "failure":
        assert post["fault"]["sensor"] == "accelerometer" and post["fault"]["kind"] == "ramp"
    else:
        assert post["fault"] is None
        ramp = next(c for c in post["candidates"] if c["hypothesis"] == "accel_bias_ramp")
        assert ramp["sensor"] == "accelerometer" and ramp["kind"] == "ramp"
        assert ramp["unit"] == "m/s^3" and ramp["unit_eng"] == "mg/h"
        assert ramp["magnitude"] == pytest.approx(2e-5, rel=0.1)
        assert ramp["magnitude_eng"] == pytest.approx(2e-5 * 3600 / 9.80665e-3, rel=0.1)
        assert abs(ramp["onset_s"] - 300.0) < 25.0
        assert "accelerometer x: bias ramp of +" in post["headline"]
        assert "identical velocity signatures" in post["headline"]


def test_gyro_ramp_is_isolated_as_a_gyro_ramp():
    res = analyse(["gyro:ramp:t=300,mag=1e-8"], seed=0)
    post = res.summary["post_flight"]
    assert post["verdict"] == "failure" and post["isolation"] == "single"
    f = post["fault"]
    assert (f["sensor"], f["kind"], f["unit"], f["unit_eng"]) == ("gyro", "ramp", "rad/s^2",
                                                                  "deg/h^2")
    assert f["magnitude"] == pytest.approx(1e-8, rel=0.1)
    assert abs(f["onset_s"] - 300.0) < 20.0
    assert f["runner_up"]["hypothesis"] == "gyro_drift_step"
    assert f["statistic"] - f["runner_up"]["statistic"] > GlrConfig().ambiguity_margin


@pytest.mark.parametrize("fault, sensor, kind, onset, tol, magnitude, unit_eng, factor", [
    ("accel:step:t=500,mag=1mg", "accelerometer", "step", 500.0, 2.0, 9.80665e-3, "mg",
     1e3 / 9.80665),
    ("ref:jump:t=400,mag=0.5", "reference", "jump", 400.0, 0.5, 0.5, "m/s", 1.0),
])
def test_steps_and_jumps_name_the_sensor_with_units_and_onset(fault, sensor, kind, onset, tol,
                                                              magnitude, unit_eng, factor):
    res = analyse([fault], seed=1)
    post = res.summary["post_flight"]
    f = post["fault"]
    assert post["verdict"] == "failure" and post["isolation"] == "single"
    assert (f["sensor"], f["axis"], f["kind"], f["unit_eng"]) == (sensor, "x", kind, unit_eng)
    assert abs(f["onset_s"] - onset) <= tol  # a reference jumping by +0.5 m/s reads +0.5
    assert f["magnitude"] == pytest.approx(magnitude, rel=0.1)
    assert f["magnitude_eng"] == pytest.approx(f["magnitude"] * factor, rel=1e-12)
    lo, hi = f["onset_interval_s"]
    assert lo <= f["onset_s"] <= hi and hi - lo < 10.0
    assert f["end_s"] is None  # lasts to the end of the record
    assert f["statistic"] > f["threshold"] and f["runner_up"]["statistic"] < f["statistic"]
    assert post["headline"].startswith(f"{sensor} x: ")


def test_two_faults_are_unexplained_by_one_and_the_second_is_named():
    res = analyse(["accel:step:t=200,mag=0.005", "ref:jump:t=600,mag=0.5"], seed=0)
    post = res.summary["post_flight"]
    assert post["verdict"] == "ambiguous" and post["isolation"] == "unexplained"
    assert post["fault"] is None
    assert [c["hypothesis"] for c in post["candidates"]] == ["reference_jump"]
    resid = post["glr"]["residual"]
    assert resid["hypothesis"] == "accel_bias_step" and abs(resid["onset_s"] - 200.0) < 5.0
    assert resid["statistic"] > post["glr"]["threshold"]
    assert post["headline"].startswith("unexplained: ")


def test_a_single_fault_passes_the_residual_test():
    res = analyse(["accel:step:t=500,mag=0.015"], seed=0)
    glr = res.summary["post_flight"]["glr"]
    assert glr["isolation"] == "single"
    assert glr["residual"]["statistic"] < glr["threshold"]


def test_two_hypotheses_within_the_margin_are_ambiguous_both_named():
    # the accelerometer step beats the reference jump by far; with a margin wider than the gap
    # between them, the same flight is reported as ambiguous between the two
    res = analyse(["accel:step:t=500,mag=0.015"], seed=0)
    stats = res.summary["post_flight"]["glr"]["statistics"]
    gap = stats["accel_bias_step"] - stats["reference_jump"]
    wide = analyse(["accel:step:t=500,mag=0.015"], seed=0, glr_ambiguity_margin=gap + 1.0)
    post = wide.summary["post_flight"]
    assert post["verdict"] == "ambiguous" and post["isolation"] == "ambiguous"
    assert [c["sensor"] for c in post["candidates"]] == ["accelerometer", "reference"]
    assert " or reference x: jump of " in post["headline"]


def test_outliers_are_one_glitch_with_their_count():
    res = analyse(["ref:outliers:t=100,end=900,mag=3,freq=0.01"], seed=0)
    post = res.summary["post_flight"]
    assert post["verdict"] == "glitch" and post["isolation"] == "single"
    f = post["fault"]
    assert f["kind"] == "outliers" and f["sensor"] == "reference" and f["count"] >= 3
    assert 100.0 <= f["onset_s"] <= f["end_s"] <= 900.0
