"""The ins3d post-flight result on the bundled sample bags and on a straight leg: the failed
sensor and body axis, its magnitude and onset; no fault on the nominal flight; "ambiguous"
(not a confident wrong sensor) where the flight cannot separate two sensors."""
from __future__ import annotations

import json
from pathlib import Path

import jsonschema
import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.data import RefRows

from .conftest import flight, sample_input

ROOT = Path(__file__).resolve().parents[2]


def validate(pf: dict) -> None:
    schema = json.loads((ROOT / "flight_fdi/schema/result-v1.schema.json").read_text())
    sub = dict(schema["properties"]["post_flight"], **{"$defs": schema["$defs"]})
    jsonschema.validate(pf, sub)
    json.dumps(pf)


@pytest.fixture(scope="module")
def bag_results():
    out = {}
    for name in ("ins3d_nominal", "ins3d_accel_y_step", "ins3d_gyro_x_step"):
        inp = sample_input(name)                # read_ins3d of bags/<name>, decoded once
        out[name] = analyze_ins3d(inp.steps, inp.refs, with_observability=False)
    return out


@pytest.mark.slow
def test_sample_gyro_x_step(bag_results):
    """1 deg/h on body x at 480 s, turns at ~980 s and ~1650 s after it."""
    a = bag_results["ins3d_gyro_x_step"]
    pf = a.post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], pf["isolation"]) == ("failure", "single")
    assert (f["sensor"], f["axis"], f["kind"]) == ("gyro", "x", "step")
    assert f["unit_eng"] == "deg/h" and f["magnitude_eng"] == pytest.approx(1.0, abs=0.1)
    assert abs(f["onset_s"] - 480.0) < 20.0
    assert f["onset_interval_s"][0] <= f["onset_s"] <= f["onset_interval_s"][1]
    assert f["statistic"] > 10 * f["threshold"]
    assert pf["ambiguity_resolved_s"] is not None
    assert pf["headline"].startswith("gyro x: drift step of +0.9")
    # the series the figures use
    b = a.bias_estimates()
    assert b["gyro"].shape == b["gyro_sd"].shape == (b["t"].size, 3)
    late = b["t"] > 1700.0
    assert np.degrees(b["gyro"][late, 0].mean()) * 3600 > 0.3     # the bias state lags
    fx = b["gyro_fault"][:, 0]
    assert np.all(fx[b["t"] < f["onset_s"] - 1e-9] == 0.0)
    assert np.degrees(fx[-1]) * 3600 == pytest.approx(f["magnitude_eng"])
    assert not b["accelerometer_fault"].any()
    assert a.J.shape == a.t_J.shape and a.turns()


@pytest.mark.slow
def test_sample_accel_y_step(bag_results):
    """0.5 mg on body y at 480 s."""
    pf = bag_results["ins3d_accel_y_step"].post_flight_dict(t0=0.0)
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], f["sensor"], f["axis"], f["kind"]) == (
        "failure", "accelerometer", "y", "step")
    assert f["unit_eng"] == "mg" and f["magnitude_eng"] == pytest.approx(0.5, abs=0.05)
    assert abs(f["onset_s"] - 480.0) < 10.0
    assert f["magnitude_std"] < 0.1 * abs(f["magnitude"])


@pytest.mark.slow
def test_sample_nominal_has_no_fault(bag_results):
    a = bag_results["ins3d_nominal"]
    pf = a.post_flight_dict()
    validate(pf)
    assert (pf["verdict"], pf["isolation"], pf["fault"]) == ("no_fault", "none", None)
    assert pf["glr"]["statistic"] < pf["glr"]["threshold"]
    assert pf["seed_method"]["verdict"] == "no_fault"
    assert a.sequential is None and pf["glitches"] == []


@pytest.mark.parametrize("fault,pair,rows", [
    ("gyro:step:t=300,mag=0.3deg/h,axis=y", {"gyro y", "accelerometer"}, 3),
    ("accel:step:t=300,mag=0.3mg,axis=x", {"accelerometer x", "accelerometer z"}, 2),
])
def test_straight_leg_is_ambiguous_not_confidently_wrong(fault, pair, rows):
    """On one straight level leg a gyro drift step on the pitch axis and an accelerometer ramp
    make the same velocity error, and -- without the vertical reference row -- the forward
    accelerometer and the (slightly forward, angle of attack) vertical one see the same
    specific-force direction: both named."""
    inp = from_flight(flight("straight", 1200.0, "navigation", "baro", 11, faults=(fault,)))
    vertical = {"vertical": "damped"} if rows == 2 else inp.vertical()
    pf = analyze_ins3d(inp.steps, inp.refs, rows=rows, with_observability=False,
                       **vertical).post_flight_dict()
    validate(pf)
    assert (pf["verdict"], pf["isolation"], pf["fault"]) == ("ambiguous", "ambiguous", None)
    named = {f"{c['sensor']} {c['axis']}" for c in pf["candidates"]}
    truth = "gyro y" if fault.startswith("gyro") else "accelerometer x"
    assert truth in named
    assert any(n.startswith(p) for n in named for p in pair - {truth})
    assert pf["ambiguity_resolved_s"] is None
    assert "ambiguous" in pf["headline"]


def test_straight_leg_vertical_row_separates_the_forward_and_vertical_accelerometers():
    """With the vertical row and the INS's height loop in the model a vertical accelerometer
    error shows as the loop's vertical velocity transient, a forward one does not: the step
    of the test above is isolated on a straight leg (right axis, onset within 10 s)."""
    inp = from_flight(flight("straight", 1200.0, "navigation", "baro", 11,
                             faults=("accel:step:t=300,mag=0.3mg,axis=x",)))
    pf = analyze_ins3d(inp.steps, inp.refs, with_observability=False,
                       **inp.vertical()).post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["isolation"], f["sensor"], f["axis"], f["kind"]) == (
        "single", "accelerometer", "x", "step")
    assert abs(f["onset_s"] - 300.0) < 10.0
    assert 300.0 < pf["ambiguity_resolved_s"] < 400.0      # told from gyro y within ~25 s


@pytest.mark.parametrize("fault,expect", [
    ("ref:jump:t=300,mag=0.3,axis=x", ("failure", "east", "jump")),
    ("ref:outliers:t=300,end=500,mag=1.0,freq=0.02,axis=y", ("glitch", "north", "outliers")),
])
def test_reference_jump_and_outliers(fault, expect):
    """A GNSS velocity jump of +0.3 m/s east reads +0.3 (the reference's error); 1-m/s
    spikes on north are outliers (a glitch), not a jump starting at one of them -- and with
    their updates removed the rest of the flight shows no other fault, so the verdict stays
    ``glitch`` (core/ins3d/glitch.py). The jump's decision names no outliers: nothing is
    removed (its own updates exceed the outlier threshold beside it)."""
    fl = flight("cruise_turns", 600.0, "navigation", "baro", 4, faults=(fault,))
    inp = from_flight(fl)
    a = analyze_ins3d(inp.steps, inp.refs, with_observability=False)
    pf = a.post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], f["sensor"], f["axis"], f["kind"]) == ("glitch" if expect[0] ==
                                                                 "glitch" else "failure",
                                                                 "reference", *expect[1:])
    if f["kind"] == "jump":
        assert f["magnitude"] == pytest.approx(0.3, abs=0.03) and abs(f["onset_s"] - 300) < 1
        assert a.sequential is None and pf["glitches"] == []
        assert pf["glr"]["outliers_above_threshold"] >= 1
    else:
        assert 300.0 <= f["onset_s"] <= f["end_s"] <= 500.0 and f["count"] >= 2
        spikes = fl.gnss.t[fl.gnss.outlier.any(axis=1)]
        (g,) = pf["glitches"]
        assert g["axis"] == "north" and np.allclose(g["times_s"], spikes, atol=0.1)
        assert not a.sequential.found and a.decided is a
        assert pf["headline"].endswith("(no other fault without the glitch's updates)")


def test_too_few_updates_are_insufficient_data_or_a_clear_error():
    inp = from_flight(flight("cruise_turns", 120.0, "navigation", "baro", 2))
    r = inp.refs
    few = RefRows(r.t[:40], r.z[:40], r.r[:40], r.step[:40], r.a[:40])
    pf = analyze_ins3d(inp.steps, few, with_observability=False).post_flight_dict()
    validate(pf)
    assert (pf["verdict"], pf["fault"]) == ("insufficient_data", None)
    none = RefRows(r.t[:0], r.z[:0], r.r[:0], r.step[:0], r.a[:0])
    with pytest.raises(CoreError, match="no reference update"):
        analyze_ins3d(inp.steps, none)


def test_post_flight_needs_the_post_flight_part():
    inp = from_flight(flight("cruise_turns", 120.0, "navigation", "baro", 2))
    a = analyze_ins3d(inp.steps, inp.refs, post=False, with_observability=False)
    assert a.backward is None
    with pytest.raises(CoreError, match="post-flight"):
        a.post_flight_dict()
