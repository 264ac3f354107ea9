"""The offline analysis end to end on seeded synthetic flights: 50 Hz INS, 10 Hz reference."""
from __future__ import annotations

import json

import numpy as np
import pytest

from flight_fdi.core.analysis import (AnalysisConfig, analyze_flight, glr_element,
                                      run_analysis)
from flight_fdi.core.errors import CoreError
from flight_fdi.core.models import ins_channel

SIGMA_REF = 0.1


def make_flight(simulate, step, seed, duration=1000.0, fault=None, start=1_700_000_000.0):
    """INS velocity = truth + simulated INS error (50 Hz); reference = truth + noise (10 Hz,
    stamped in between the INS samples so that alignment really interpolates)."""
    model = ins_channel()
    rng = np.random.default_rng(seed)
    t_ins = np.arange(int(duration * 50)) * 0.02
    X = simulate(model, t_ins, rng)
    if fault is not None:
        X = X + step(model, t_ins, *fault)
    v_true = 40.0 * np.sin(2 * np.pi * t_ins / 300.0) + 0.01 * t_ins
    v_ins = v_true + X[:, 0]
    t_ref = np.arange(0.05, duration - 0.1, 0.1)
    v_true_ref = 40.0 * np.sin(2 * np.pi * t_ref / 300.0) + 0.01 * t_ref
    v_ref = v_true_ref + rng.normal(0, SIGMA_REF, t_ref.size)
    r_ref = np.full(t_ref.size, SIGMA_REF ** 2)
    return model, start + t_ins, v_ins, start + t_ref, v_ref, r_ref


def check_schema(d):
    """Every result follows the versioned JSON Schema shipped with the package."""
    from flight_fdi.schema import validate_result

    validate_result(d)
    assert d["schema"] == "flight-fdi/result/v1"


@pytest.fixture(scope="module")
def accel_flight(simulate, step):
    return make_flight(simulate, step, 31, fault=("accel_bias", 500.0, 0.02))


def test_accelerometer_bias_step_end_to_end(accel_flight):
    model, t_ins, v_ins, t_ref, v_ref, r_ref = accel_flight
    t0 = t_ins[0]
    res = run_analysis(model, t_ins, v_ins, t_ref, v_ref, r_ref, bag="synthetic.mcap")
    s = res.summary
    check_schema(s)
    json.dumps(s, allow_nan=False)  # strictly JSON
    assert s["bag"] == "synthetic.mcap" and s["channel"] == "x"
    assert s["samples"] == t_ref.size
    assert s["input"] == {
        "ins": {"role": "ins", "messages": t_ins.size, "used": t_ins.size, "dropped": {}},
        "reference": {"role": "reference", "messages": t_ref.size, "used": t_ref.size,
                      "dropped": {"outside_ins_record": 0, "ins_gap": 0,
                                  "invalid_covariance_replaced": 0}}}
    assert s["duration_s"] == pytest.approx(t_ref[-1] - t_ref[0])
    # in flight: the gate alarms only after the fault
    inf = s["in_flight"]
    assert inf["first_alarm_s"] is not None and 500.0 < inf["first_alarm_s"] < 600.0
    assert all(a["start_s"] > 500.0 for a in inf["alarms"])
    assert inf["alarms"][0]["start_s"] == inf["first_alarm_s"]
    assert inf["alarms"][0]["peak_beta2"] > inf["gate_threshold"]
    # post flight, seed method: J far over its bound, peaking right after the fault; which
    # element it blames depends on the UDU^T order (the SPEC warns it may be the wrong one)
    pf = s["post_flight"]
    seed = pf["seed_method"]
    assert seed["verdict"] in ("failure", "glitch", "ambiguous")
    assert 500.0 <= res.seed.onset_t - t0 <= 515.0
    assert [e["name"] for e in seed["elements"]] == list(model.state_names)
    acc = seed["elements"][model.index("accel_bias")]
    assert acc["J_peak"] > 10 * acc["gamma2"] and acc["dof"] == 3
    assert seed["elements"][model.index("gyro_drift")]["F_peak"] is None  # no information
    # GLR isolates the accelerometer, its onset and magnitude
    glr = pf["glr"]
    assert glr["hypothesis"] == "accel_bias_step"
    assert glr["statistic"] > glr["threshold"]
    assert abs(glr["onset_s"] - 500.0) < 3.0
    assert glr["magnitude"] == pytest.approx(0.02, rel=0.1)
    # combined: GLR's element, onset and magnitude; a step is a failure
    assert pf["verdict"] == "failure" and pf["element"] == "accel_bias"
    assert pf["onset_s"] == glr["onset_s"] and pf["magnitude"] == glr["magnitude"]
    assert pf["methods_agree"] == (seed["element"] == "accel_bias")
    # arrays for plots / ROS
    assert res.fwd.t.size == s["samples"] and res.bwd.x_s.shape == (s["samples"], 4)
    assert res.seed.J.shape == (s["samples"],) and res.glr.curves["accel_bias_step"][0].size


def test_nominal_flight_end_to_end(simulate, step):
    model, t_ins, v_ins, t_ref, v_ref, r_ref = make_flight(simulate, step, 32, duration=600.0)
    s = analyze_flight(model, t_ins, v_ins, t_ref, v_ref, r_ref, channel="y")
    check_schema(s)
    assert s["channel"] == "y"
    assert s["in_flight"]["alarms"] == [] and s["in_flight"]["first_alarm_s"] is None
    assert s["in_flight"]["exceed_fraction"] < 0.01
    pf = s["post_flight"]
    assert pf["verdict"] == "no_fault" and pf["element"] is None and pf["onset_s"] is None
    assert pf["seed_method"]["verdict"] == "no_fault"
    assert pf["glr"]["hypothesis"] == "none" and pf["glr"]["onset_s"] is None
    assert pf["methods_agree"] is True


def test_invalid_covariance_gaps_and_time_origin(simulate, step):
    model, t_ins, v_ins, t_ref, v_ref, r_ref = make_flight(simulate, step, 33, duration=200.0)
    r = r_ref * 4.0
    r[10:20] = np.nan                  # invalid covariance in 10 messages
    keep = (t_ins - t_ins[0] < 50.0) | (t_ins - t_ins[0] > 53.0)  # a 3 s INS dropout
    t0 = t_ins[0] - 100.0
    res = run_analysis(model, t_ins[keep], v_ins[keep], t_ref, v_ref, r, t0=t0)
    inp = res.summary["input"]["reference"]["dropped"]
    assert inp["invalid_covariance_replaced"] == 10
    gap = (t_ref - t_ins[0] > 50.0 - 0.02) & (t_ref - t_ins[0] < 53.0 + 0.02)
    assert inp["ins_gap"] == int(gap.sum()) > 0 and inp["outside_ins_record"] == 0
    assert res.summary["samples"] == t_ref.size - inp["ins_gap"]
    np.testing.assert_array_equal(res.aligned, ~gap)
    # the model's R where the covariance was invalid, the message's elsewhere
    R = res.fwd.R[:, 0, 0]
    t_used = t_ref[res.aligned]
    bad = np.isin(t_used, t_ref[10:20])
    assert np.all(R[bad] == model.R[0, 0]) and np.all(R[~bad] == 4.0 * SIGMA_REF ** 2)
    assert res.t0 == t0
    # times are relative to t0
    assert res.fwd.t[0] - t0 == pytest.approx(100.05)


def test_analysis_bad_input(simulate, step):
    model, t_ins, v_ins, t_ref, v_ref, r_ref = make_flight(simulate, step, 34, duration=30.0)
    with pytest.raises(CoreError, match="no reference sample"):
        analyze_flight(model, t_ins, v_ins, t_ref + 1000.0, v_ref)
    bad = v_ref.copy()
    bad[3] = np.nan
    with pytest.raises(CoreError, match="v_ref contains NaN"):
        analyze_flight(model, t_ins, v_ins, t_ref, bad)
    with pytest.raises(CoreError, match="r_ref is negative"):
        analyze_flight(model, t_ins, v_ins, t_ref, v_ref, -r_ref)
    with pytest.raises(CoreError, match="strictly increasing"):
        analyze_flight(model, t_ins[::-1], v_ins, t_ref, v_ref)
    with pytest.raises(CoreError, match="strictly increasing"):
        analyze_flight(model, t_ins, v_ins, t_ref[::-1], v_ref[::-1])
    with pytest.raises(CoreError, match="one variance per reference message"):
        analyze_flight(model, t_ins, v_ins, t_ref, v_ref, r_ref[:-1])


@pytest.mark.parametrize("kwargs, field", [
    ({"fisher_window": 3}, "fisher window"), ({"max_gap_s": 0.0}, "AnalysisConfig.max_gap_s"),
    ({"glr_p_false_alarm": 1.5}, "AnalysisConfig.glr_p_false_alarm"),
    ({"persistence_s": -1.0}, "AnalysisConfig.persistence_s"),
    ({"gate": "chi2"}, "AnalysisConfig.gate"),
    ({"glr_hypotheses": ()}, "AnalysisConfig.glr_hypotheses"),
])
def test_analysis_config_validation(kwargs, field):
    with pytest.raises(CoreError, match=field):
        AnalysisConfig(**kwargs)


def test_glr_element_mapping():
    model = ins_channel()
    assert glr_element(model, "accel_bias_step") == "accel_bias"
    assert glr_element(model, "gyro_drift_step") == "gyro_drift"
    assert glr_element(model, "reference_jump") == "velocity_error"
    assert glr_element(model, "reference_outlier") == "velocity_error"
    assert glr_element(model, "step:tilt") == "tilt"
    assert glr_element(model, "none") is None


def test_analyze_forward_on_a_rebuilt_record_equals_run_analysis(accel_flight):
    """The ROS smoother's path: the forward pass rebuilt from what FilterState messages carry,
    then the post-flight analysis -- the same summary as the offline analysis."""
    from flight_fdi.core.analysis import analyze_forward
    from flight_fdi.core.kalman import ForwardResult

    model, t_ins, v_ins, t_ref, v_ref, r_ref = accel_flight
    a = run_analysis(model, t_ins, v_ins, t_ref, v_ref, r_ref, bag="b", t0=t_ins[0])
    f = a.fwd
    rec = ForwardResult.from_record(model, f.t, f.dt, f.z, f.R, f.H, f.fused, f.u, f.x, f.P)
    b = analyze_forward(model, rec, AnalysisConfig(), bag="b", t0=t_ins[0])
    expected = dict(a.summary)
    del expected["input"]
    assert b.summary["post_flight"]["verdict"] == expected["post_flight"]["verdict"]
    assert b.summary["post_flight"]["glr"]["hypothesis"] == "accel_bias_step"
    assert b.summary["post_flight"]["onset_s"] == pytest.approx(
        expected["post_flight"]["onset_s"])
    assert b.summary["post_flight"]["magnitude"] == pytest.approx(
        expected["post_flight"]["magnitude"], rel=1e-6)
    bi, ei = b.summary["in_flight"], expected["in_flight"]
    assert bi["first_alarm_s"] == ei["first_alarm_s"] and len(bi["alarms"]) == len(ei["alarms"])
    for x, y in zip(bi["alarms"], ei["alarms"]):
        assert x["start_s"] == y["start_s"] and x["end_s"] == y["end_s"]
        assert x["peak_beta2"] == pytest.approx(y["peak_beta2"], rel=1e-8)
    assert np.max(np.abs(b.bwd.x_s - a.bwd.x_s) / model.scale) < 1e-8


def test_core_package_exports_every_listed_name_lazily():
    import subprocess
    import sys

    import flight_fdi.core as core

    for name in core.__all__:
        assert getattr(core, name).__name__ == name
    code = ("import sys, flight_fdi.core.forked\n"
            "print('scipy' in sys.modules, 'flight_fdi.core.kalman' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]
