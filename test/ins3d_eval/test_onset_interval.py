"""The stated onset interval of an ins3d fault (core/ins3d/result3d.py): the onsets within the
calibrated drop of the peak, with the kind (step / ramp) of the same sensor and axis profiled
out -- known answers on hand-made GLR curves."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.core.ins3d.glr3d import GlrCurve, Hypothesis
from flight_fdi.core.ins3d.result3d import ONSET_DROP, onset_drop, onset_interval

T = np.arange(0.0, 100.0, 10.0)   # onsets 0, 10, ..., 90 s


def curve(sensor, axis, kind, stat):
    h = Hypothesis(f"{sensor}_{axis}_{kind}", sensor, axis, kind, 0)
    z = np.zeros(T.size)
    return GlrCurve(h, T, np.asarray(stat, float), z, z + 1.0)


def test_drop_per_sensor_and_kind():
    assert onset_drop("accelerometer", "step") == ONSET_DROP[("accelerometer", "step")]
    assert onset_drop("gyro", "ramp") == ONSET_DROP[("gyro", "ramp")]
    assert onset_drop("reference", "jump") == ONSET_DROP["reference"]
    assert onset_drop("nonsense", "step") == 3.84


def test_interval_alone_is_the_region_within_the_drop_around_the_peak():
    step = curve("gyro", "x", "step", [0, 1, 27, 29, 30, 28, 20, 29, 1, 0])
    # within 3 of 30: 27..28 contiguous around the peak (50 s); 29 at 70 s is cut off by 20
    assert onset_interval(step, drop=3.0) == (20.0, 50.0)
    assert onset_interval(step, drop=10.5) == (20.0, 70.0)


def test_the_other_kind_of_the_same_sensor_and_axis_widens_the_interval():
    step = curve("gyro", "x", "step", [0, 0, 0, 0, 10, 20, 30, 20, 10, 0])
    ramp = curve("gyro", "x", "ramp", [0, 5, 27, 28, 10, 0, 0, 0, 0, 0])   # onsets earlier
    far = curve("gyro", "y", "ramp", [29, 29, 29, 29, 29, 29, 29, 29, 29, 29])  # other axis
    weak = curve("accelerometer", "x", "ramp", [26, 0, 0, 0, 0, 0, 0, 0, 0, 0])
    cv = {c.hypothesis.name: c for c in (step, ramp, far, weak)}
    assert onset_interval(step, drop=3.0) == (60.0, 60.0)
    assert onset_interval(step, cv, drop=3.0) == (20.0, 60.0)       # ramp's 27, 28 >= 27
    assert onset_interval(step, cv, drop=1.0) == (60.0, 60.0)       # ramp's peak 28 < 29
    assert onset_interval(ramp, cv, drop=3.0) == (20.0, 60.0)       # 27, 28 and the step 30
    jump = curve("reference", "east", "jump", [0, 0, 40, 0, 0, 0, 0, 0, 0, 0])
    assert onset_interval(jump, {**cv, "j": jump}, drop=3.0) == (20.0, 20.0)
    assert onset_interval(curve("gyro", "z", "step", []), cv) is None
