"""The real excerpt (Xsens DOT unit 1 of straight/path_2) with the recording's barometric height
as a third reference row (``real3d.Contract.height_sigma``, setting (i) of
tools/ins3d_real_eval.py; docs/ins3d_real.md "A height reference row"): the vertical
accelerometer, invisible to the two horizontal rows on a straight leg, is named, and the
along-track accelerometer is told from it."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.core.ins3d.grades import DEG_H
from flight_fdi.eval import real3d as R

#: setting (i): the DJI height (0.1-m steps) white 0.05 m plus a 0.4-m, 5-s Markov error
HEIGHT = R.Settings(contract=R.Contract(height_sigma=float(np.hypot(0.05, 0.4))),
                    v0_sigma_up=1.0, ref_markov=(1e-3, 0.4, 5.0))


def test_nominal_with_the_height_row(rec, cal):
    a = R.analyze(rec, *cal, HEIGHT)
    out = R.record(a)
    assert out["verdict"] == "no_fault" and R.judge(out, None) == "none"
    assert set(out["beta2_rows"]) == {"east", "north", "height"}
    assert out["beta2_rows"]["height"] < 1.5
    assert a.model.height_row and a.model.position


def test_vertical_accelerometer_named_only_with_the_height_row(rec, cal):
    fault = R.Fault("accelerometer", "z", 1.0, 6.0)
    faulty = fault.apply(rec)
    without = R.record(R.analyze(faulty, *cal, reference_of=rec))
    assert R.judge(without, fault) == "none"          # measured: nothing above threshold
    out = R.record(R.analyze(faulty, *cal, HEIGHT, reference_of=rec))
    assert R.judge(out, fault) == "right", out
    assert abs(out["onset_s"] - 6.0) <= 1.0 and abs(out["magnitude"] - 1.0) < 0.1


def test_the_height_row_tells_the_along_track_accelerometer_from_the_vertical(rec, cal):
    # without it: ambiguous between x and z (test_real3d.py, the 15-deg nose-down airframe)
    fault = R.Fault("accelerometer", "x", 1.0, 6.0)
    out = R.record(R.analyze(fault.apply(rec), *cal, HEIGHT, reference_of=rec))
    assert R.judge(out, fault) == "right", out
    assert abs(out["magnitude"] - 1.0) < 0.15


def _cli(capsys, bag, *opts) -> dict:
    from flight_fdi.cli.main import main
    from flight_fdi.eval.real3d_grade import GRADE_FILE
    capsys.readouterr()
    assert main(["analyze", str(bag), "--model", "ins3d", "--grade", str(GRADE_FILE), "--json",
                 "--jobs", "1", "--height-topic", R.HEIGHT_TOPIC, *opts]) in (0, 3)
    return json.loads(capsys.readouterr().out)


@pytest.mark.parametrize("fault", [None, R.Fault("accelerometer", "z", 1.0, 6.0)])
def test_the_contract_bag_carries_the_height_and_analyze_is_real3d_analyze(rec, cal, tmp_path,
                                                                            capsys, fault):
    """``write_contract_bag`` with ``Contract.height_sigma`` writes the GT height as
    NavSatFix on ``HEIGHT_TOPIC``; ``analyze --height-topic`` with the datum ``absolute`` (the
    INS starts at the GT height, as ``build_contract`` has it) gives ``real3d.analyze``'s
    decision and numbers, and with the default datum ``first`` the same decision."""
    r = fault.apply(rec) if fault else rec
    bag = tmp_path / "bag"
    counts = R.write_contract_bag(r, *cal, bag, settings=HEIGHT, reference_of=rec)
    assert counts[R.HEIGHT_TOPIC] == rec.gt["time"].size
    an = R.analyze(r, *cal, HEIGHT, reference_of=rec)
    py = R.record(an, t0=float(an.steps.t[0]))
    res = _cli(capsys, bag, "--height-datum", "absolute")
    post, f = res["post_flight"], res["post_flight"]["fault"]
    assert post["verdict"] == py["verdict"] and res["channel"] == "en_height"
    assert R.judge(py, fault) == ("right" if fault else "none"), py
    if fault:
        assert (f["sensor"], f["axis"], f["kind"]) == (py["sensor"], py["axis"], py["kind"])
        for k in ("onset_s", "magnitude", "statistic"):
            assert f[k] == pytest.approx(py[k], rel=1e-9), k
    stats = post["glr"]["statistics"]
    for kind in ("step", "ramp", "jump", "outliers"):
        assert stats[py[f"max_{kind}_hyp"]] == pytest.approx(py[f"max_{kind}"], rel=1e-9)
    assert res["ins3d"]["beta2_mean"] == pytest.approx(py["beta2"], rel=1e-6)
    first = _cli(capsys, bag)
    assert first["post_flight"]["verdict"] == post["verdict"]
    g = first["post_flight"]["fault"]
    assert (g and (g["sensor"], g["axis"])) == (f and (f["sensor"], f["axis"]))
    assert abs(first["input"][R.HEIGHT_TOPIC]["offset_m"]) < 0.2   # the INS starts at the GT


#: straight/path_1, unit 1 (the second excerpt): the real evaluation's run with a gyro y step of
#: 3000 deg/h (tools/ins3d_real_eval.py, setting (i), seed 1)
PATH_1 = Path(__file__).parent / "data" / "mimu_straight_1"


def test_a_gyro_step_is_not_named_its_tilt_twin_with_confidence():
    """A gyro y step of 3000 deg/h at 11.6 s, 7 s before the end of a straight leg: the tilt
    identity (a gyro y drift = an accelerometer x ramp of g times it) leaves the two alike. The
    nonlinear check's refits, started from the prior of a relinearisation about the *faulty*
    flight's smoothed errors (which the fault itself moved), named the accelerometer x ramp with
    confidence (gap 29 against 9.2); started from the flight's own beginning, each corrected
    flight relinearised about its own errors, the two stay within the margin."""
    rec = R.read_recording(PATH_1.parent, PATH_1.name, 1)
    doc = json.loads((PATH_1 / "calibration.json").read_text())
    cal = np.array(doc["gyro_bias_rad_s"]), np.array(doc["accel_bias_m_s2"])
    fault = R.Fault("gyro", "y", 3000.0 * DEG_H, 11.645)
    out = R.record(R.analyze(fault.apply(rec), *cal, HEIGHT, reference_of=rec))
    assert out["reason"] == "nonlinear" and out["relinearised"]
    assert R.judge(out, fault) in ("right", "ambiguous"), out
    assert "gyro y step" in out["candidates"] or (out["sensor"], out["axis"]) == ("gyro", "y")
