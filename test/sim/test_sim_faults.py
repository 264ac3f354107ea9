"""The fault catalogue: parsing the command-line form, validation and the error signals."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.sim import FaultSpec, SimError, parse_fault

G = 9.80665
DPH = math.pi / 180 / 3600


@pytest.mark.parametrize("text,want", [
    ("accel:step:t=500,mag=0.015", dict(target="accel", type="step", start_s=500.0,
                                        magnitude=0.015)),
    ("accel:step:t=500,mag=1.5mg", dict(magnitude=1.5e-3 * G)),
    ("accel:step:t=500s,mag=20ug,axis=y", dict(magnitude=20e-6 * G, axis="y")),
    ("accel:ramp:start=10,end=20,magnitude=0.1mg/s", dict(magnitude=0.1e-3 * G, end_s=20.0)),
    ("accel:ramp:t=10,mag=1e-3m/s^2", dict(magnitude=1e-3)),
    ("gyro:step:t=500,mag=10deg/h", dict(target="gyro", magnitude=10 * DPH)),
    ("gyro:square:t=20,mag=20dph,freq=5Hz", dict(type="square", magnitude=20 * DPH, freq_hz=5.0)),
    ("gyro:sine:t=0,mag=0.1deg/s,f=2", dict(magnitude=0.1 * math.pi / 180, freq_hz=2.0)),
    ("gyro:stuck:t=300,mag=0", dict(type="stuck", magnitude=0.0)),
    ("ACCEL:Scale:t=300,mag=1", dict(target="accel", type="scale", magnitude=1.0)),
    ("accel:scale:t=300,mag=500ppm", dict(magnitude=5e-4)),
    ("ref:jump:t=100,mag=-2", dict(target="ref", type="jump", magnitude=-2.0)),
    ("ref:outliers:t=100,end=900,mag=3,freq=0.05", dict(type="outliers", freq_hz=0.05)),
    ("ref:dropout:t=300,end=330", dict(type="dropout", start_s=300.0, end_s=330.0,
                                       magnitude=0.0)),
])
def test_parse(text, want):
    f = parse_fault(text)
    for key, val in want.items():
        got = getattr(f, key)
        ok = math.isclose(got, val, rel_tol=1e-12) if isinstance(val, float) else got == val
        assert ok, key


@pytest.mark.parametrize("text,match", [
    ("accel", "expected TARGET:TYPE"),
    ("magnet:step:t=1,mag=1", "unknown target"),
    ("accel:jump:t=1,mag=1", "unknown accel fault type"),
    ("ref:step:t=1,mag=1", "unknown ref fault type"),
    ("accel:step:mag=1", "start time t=... is required"),
    ("accel:step:t=1", "magnitude must be non-zero"),
    ("accel:step:t=1,mag=0", "magnitude must be non-zero"),
    ("accel:step:t=-1,mag=1", "start must be a time >= 0"),
    ("accel:step:t=5,end=5,mag=1", "must be after the start"),
    ("accel:step:t=abc,mag=1", "not a number"),
    ("accel:step:t=1,mag=nan", "not a finite number|does not start with a number"),
    ("accel:step:t=1,mag=2deg/h", "unknown unit 'deg/h'"),
    ("gyro:step:t=1,mag=2mg", "unknown unit 'mg'"),
    ("accel:step:t=1,mag=1,freq=3", "freq applies only"),
    ("gyro:sine:t=1,mag=1", "positive frequency"),
    ("gyro:square:t=1,mag=1,freq=-1", "positive frequency"),
    ("ref:dropout:t=300", "needs an end time"),
    ("ref:dropout:t=300,end=310,mag=1", "no magnitude"),
    ("accel:step:t=1,mag=1,axis=z", "axis must be x or y"),
    ("accel:step:t=1,mag=1,colour=red", "unknown key 'colour'"),
    ("accel:step:t=1,t=2,mag=1", "given twice"),
    ("accel:step:t=1,mag", "is not key=value"),
])
def test_parse_errors(text, match):
    with pytest.raises(SimError, match=match):
        parse_fault(text)


def test_against_the_flight():
    with pytest.raises(SimError, match="after the end of the 100-s flight"):
        parse_fault("accel:step:t=100,mag=1").check_against(100, 50, 10)
    with pytest.raises(SimError, match="ends at 120 s, after the end"):
        parse_fault("accel:step:t=10,end=120,mag=1").check_against(100, 50, 10)
    with pytest.raises(SimError, match="below half the INS rate"):
        parse_fault("gyro:sine:t=1,mag=1,freq=25").check_against(100, 50, 10)
    with pytest.raises(SimError, match="exceeds the reference rate"):
        parse_fault("ref:outliers:t=1,mag=1,freq=11").check_against(100, 50, 10)
    parse_fault("gyro:sine:t=1,mag=1,freq=24.9").check_against(100, 50, 10)


def test_instrument_error_signals_closed_form():
    t = np.arange(0, 10, 0.01)
    truth = np.sin(t) + 2.0
    dur = 10.0

    def err(text):
        return parse_fault(text).instrument_error(t, truth, dur)

    on = (t >= 2) & (t < 6)
    assert np.array_equal(err("accel:step:t=2,end=6,mag=0.5"), np.where(on, 0.5, 0.0))
    assert np.allclose(err("accel:ramp:t=2,end=6,mag=0.5"), np.where(on, 0.5 * (t - 2), 0.0))
    assert np.allclose(err("gyro:sine:t=2,end=6,mag=3,freq=0.5"),
                       np.where(on, 3 * np.sin(np.pi * (t - 2)), 0.0))
    sq = err("gyro:square:t=2,end=6,mag=3,freq=0.5")  # period 2 s: + on [2,3), - on [3,4) ...
    first_half = np.floor((t - 2)).astype(int) % 2 == 0
    assert np.array_equal(sq, np.where(on, np.where(first_half, 3.0, -3.0), 0.0))
    assert np.allclose(err("accel:stuck:t=2,end=6,mag=0.25"), np.where(on, 0.25 - truth, 0.0))
    assert np.allclose(err("accel:scale:t=2,end=6,mag=1"), np.where(on, truth, 0.0))
    assert np.array_equal(err("accel:step:t=2,mag=1"), np.where(t >= 2, 1.0, 0.0))
    with pytest.raises(SimError, match="not an instrument fault"):
        err("ref:jump:t=2,mag=1")


def test_dict_round_trip_and_descriptions():
    f = parse_fault("gyro:step:t=500,mag=10deg/h")
    d = f.to_dict("x")
    assert d["axis"] == "x" and d["element"] == "gyro_drift" and d["unit"] == "rad/s"
    assert d["hypothesis"] == "gyro_drift_step"
    assert FaultSpec.from_dict(d) == FaultSpec("gyro", "step", 500.0, None, 10 * DPH, None, "x")
    assert parse_fault("accel:step:t=1,mag=1").hypothesis == "accel_bias_step"
    assert parse_fault("ref:jump:t=1,mag=1").hypothesis == "reference_jump"
    assert parse_fault("accel:ramp:t=1,mag=1").hypothesis is None
    assert parse_fault("accel:ramp:t=1,mag=1").to_dict()["unit"] == "m/s^2/s"
    assert "(10 deg/h)" in f.describe()
    assert "1.53 mg" in parse_fault("accel:step:t=5,mag=0.015").describe()
    with pytest.raises(SimError, match="incomplete"):
        FaultSpec.from_dict({"target": "accel"})
