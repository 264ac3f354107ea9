"""tools/ins3d_glitch_study.py's judge (the counts of docs/ins3d.md, "Measured on the strapdown
simulator"): the IMU fault named, the glitch on its row near the spikes, the spikes removed,
and what counts as a confident wrong answer."""
from __future__ import annotations

import numpy as np
from repo_scripts import load_script

T = load_script("tools/ins3d_glitch_study.py")
SPIKES = np.array([300.2, 301.0, 312.5])


def _case(scenario="accel_step", axis="x"):
    return T.M.Case3D(1, scenario, 11, 12, axis=axis, level=1.0, magnitude=0.01, onset_s=200.0)


def _glitch(axis="north", times=(300.2, 301.0, 312.5)):
    return {"axis": axis, "times_s": list(times)}


def _post(verdict, isolation, sensor=None, axis=None, kind=None, onset=None, glitches=()):
    fault = None if sensor is None else {"sensor": sensor, "axis": axis, "kind": kind,
                                         "onset_s": onset}
    return {"verdict": verdict, "isolation": isolation, "fault": fault,
            "glitches": list(glitches)}


def test_the_step_and_the_glitch_both_found():
    j = T.judge(_post("failure", "single", "accelerometer", "x", "step", 201.0, [_glitch()]),
                _case(), SPIKES, "north")
    assert (j["right"], j["wrong"], j["glitch"], j["spikes_found"]) == (True, False, True, 3)


def test_a_glitch_on_another_row_or_away_from_the_spikes_is_not_the_glitch():
    other_row = T.judge(_post("glitch", "single", "reference", "east", "outliers", 300.2),
                        _case("nominal", None), SPIKES, "north")
    assert (other_row["glitch"], other_row["wrong"]) == (False, True)
    far = T.judge(_post("glitch", "single", "reference", "north", "outliers", 250.0),
                  _case("nominal", None), SPIKES, "north")
    assert (far["glitch"], far["wrong"]) == (False, True)
    # a glitch verdict's first outlier next to the first spike (within 2 s) is the glitch
    near = T.judge(_post("glitch", "single", "reference", "north", "outliers", 299.4),
                   _case("nominal", None), SPIKES, "north")
    assert (near["glitch"], near["wrong"], near["spikes_found"]) == (True, False, 0)


def test_a_wrong_imu_sensor_or_axis_is_confident_wrong_and_ambiguous_is_not():
    wrong = T.judge(_post("failure", "single", "gyro", "y", "step", 201.0), _case(), SPIKES)
    assert (wrong["right"], wrong["wrong"]) == (False, True)
    amb = T.judge(_post("ambiguous", "ambiguous"), _case(), SPIKES)
    assert (amb["right"], amb["wrong"], amb["ambiguous"], amb["glitch"]) == (
        False, False, True, False)


def test_the_glitch_draw_is_seeded_per_flight():
    a, b = T.glitch_spec(_case(), 900.0), T.glitch_spec(_case(), 900.0)
    assert a == b and a[0].startswith("ref:outliers:t=") and a[2] in ("east", "north", "up")
