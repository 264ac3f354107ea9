"""A reference glitch and an IMU fault in the same flight (core/ins3d/glitch.py): the glitch's
updates are removed one at a time and the flight decided again on the rest, so both are
reported; a glitch alone stays a glitch; a flight whose decision names no outliers is left as
it was."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.glitch import MAX_ROUNDS, glitch_records, without
from flight_fdi.cli.ins3d import format_result
from flight_fdi.core.ins3d_result import fault_line, ins3d_result
from flight_fdi.report.figures3d import _page

from .conftest import flight
from .test_postflight import validate

GLITCH = "ref:outliers:t=300,end=500,mag=1.0,freq=0.02,axis=y"     # north spikes of 1 m/s
STEP = "accel:step:t=200,mag=0.3mg,axis=x"


def _spikes(fl) -> np.ndarray:
    """The simulator's spike times (its GNSS outlier flags)."""
    return fl.gnss.t[fl.gnss.outlier.any(axis=1)]


@pytest.fixture(scope="module")
def both():
    """600 s of cruise_turns, navigation grade: three 1-m/s north spikes in 300-500 s (the
    seed's draw: 367.8, 381.1, 415.5 s) and a 0.3-mg accelerometer x step at 200 s."""
    fl = flight("cruise_turns", 600.0, "navigation", "baro", 4, faults=(GLITCH, STEP))
    inp = from_flight(fl)
    return fl, inp, analyze_ins3d(inp.steps, inp.refs, with_observability=False)


def test_the_old_rule_names_the_glitch_only(both):
    """The decision before (``glitch_rounds=0``; also ``Ins3dAnalysis.isolation``, the
    first decision): the spikes' outlier statistic (~2500) beats the step's, so the verdict is
    ``glitch`` and the step is not reported at all."""
    fl, inp, a = both
    assert (a.isolation.isolation, a.isolation.best) == ("single", "reference_north_outliers")
    old = analyze_ins3d(inp.steps, inp.refs, with_observability=False,
                        glitch_rounds=0).post_flight_dict()
    validate(old)
    assert (old["verdict"], old["fault"]["kind"], old["glitches"]) == ("glitch", "outliers", [])
    assert "accelerometer" not in old["headline"]


def test_glitch_and_step_are_both_reported(both):
    fl, _, a = both
    pf = a.post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], pf["isolation"], f["sensor"], f["axis"], f["kind"]) == (
        "failure", "single", "accelerometer", "x", "step")
    assert abs(f["onset_s"] - 200.0) < 10.0
    assert f["magnitude_eng"] == pytest.approx(0.3, abs=0.03)
    spikes = _spikes(fl)
    assert spikes.size == 3                                  # the seed's draw
    (g,) = pf["glitches"]
    assert (g["sensor"], g["axis"], g["kind"], g["count"], g["rounds"]) == (
        "reference", "north", "outliers", 3, [1, 2, 3])
    assert np.allclose(g["times_s"], spikes, atol=0.1)       # the updates at the spikes
    assert g["statistic"] > g["threshold"] and abs(g["magnitude"]) == pytest.approx(1.0, abs=0.1)
    assert pf["headline"].startswith("accelerometer x: bias step") and \
        "reference glitch" in pf["headline"] and "3 outliers from 367.8 s" in pf["headline"]
    line = fault_line({"post_flight": pf})
    assert line.startswith("isolated: accelerometer x step") and \
        "reference glitch: north, 3 updates at 367.8, 381.1, 415.5 s" in line
    # the text of `analyze --model ins3d` and the HTML report show both
    res = ins3d_result(a, "sim")
    text = format_result(res)
    assert text.startswith("FAILURE: accelerometer x: bias step") and line in text
    page = _page(res, [], [])
    assert "accelerometer x: bias step" in page and \
        "reference glitch: north, 3 updates at 367.8, 381.1, 415.5 s" in page
    # the decision on the rest: the flight without those three updates, the same path
    seq = a.sequential
    assert len(seq.removals) == 3 <= MAX_ROUNDS and seq.found and a.decided is seq.rest
    assert seq.rest.refs.t.size == a.refs.t.size - 3
    assert not np.isin(np.round(seq.rest.refs.t, 6), np.round(spikes, 6)).any()
    assert seq.rest.glr["accelerometer_x_step"].statistic > 10 * f["threshold"]


def test_glitch_records_group_per_row():
    """One record per row of the removed updates' largest statistic: times sorted, the count,
    the largest statistic and its magnitude as the reference's error (-offset)."""
    from flight_fdi.core.ins3d.glitch import Removal
    rs = [Removal(1, 7, 30.0, "east", "reference_east_outliers", 50.0, 0.4, 0.05, 32.0,
                  ("east",)),
          Removal(2, 3, 12.0, "east", "reference_east_outliers", 80.0, -0.6, 0.05, 32.0,
                  ("east", "north")),
          Removal(3, 9, 40.0, "north", "reference_north_outliers", 40.0, 0.3, 0.05, 32.0,
                  ("north",))]
    east, north = glitch_records(rs, t0=2.0)
    assert (east["axis"], east["count"], east["times_s"], east["rounds"]) == (
        "east", 2, [10.0, 28.0], [2, 1])
    assert (east["onset_s"], east["end_s"], east["statistic"], east["magnitude"]) == (
        10.0, 28.0, 80.0, 0.6)
    assert east["rows_above"] == ["east", "north"] and north["count"] == 1


def test_without_drops_one_update():
    from flight_fdi.core.ins3d.data import RefRows
    r = RefRows(np.arange(4.0), np.arange(12.0).reshape(4, 3), np.ones((4, 3)),
                np.arange(4), np.zeros((4, 3)))
    w = without(r, 1)
    assert w.t.tolist() == [0.0, 2.0, 3.0] and w.z[1].tolist() == [6.0, 7.0, 8.0]
    assert w.step.tolist() == [0, 2, 3] and w.z.flags.c_contiguous


def test_glitch_beside_a_larger_step_is_reported_too():
    """One 0.3-m/s north spike (367.8 s) beside a 1-mg accelerometer x step at 200 s: the
    step's statistic beats the spike's (~240), so the decision names the step with the outlier
    counted beside it. With the step removed exactly the spike's update stays above the
    threshold (a glitch of its own, not the step's effect): it is removed and the flight
    decided again -- the step and the glitch both reported."""
    fl = flight("cruise_turns", 600.0, "navigation", "baro", 4,
                faults=("ref:outliers:t=350,end=375,mag=0.3,freq=0.02,axis=y",
                        "accel:step:t=200,mag=1mg,axis=x"))
    inp = from_flight(fl)
    a = analyze_ins3d(inp.steps, inp.refs, with_observability=False)
    assert (a.isolation.isolation, a.isolation.best) == ("single", "accelerometer_x_step")
    assert a.isolation.outliers >= 1 and a.sequential.beside
    pf = a.post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], f["sensor"], f["axis"], f["kind"]) == (
        "failure", "accelerometer", "x", "step")
    assert abs(f["onset_s"] - 200.0) < 5.0 and f["magnitude_eng"] == pytest.approx(1.0, abs=0.05)
    (g,) = pf["glitches"]
    assert (g["axis"], g["count"]) == ("north", 1)
    assert g["times_s"][0] == pytest.approx(_spikes(fl)[0], abs=0.1) and \
        abs(g["magnitude"]) == pytest.approx(0.3, abs=0.05)
    assert "and a reference glitch" in pf["headline"]


def test_a_burst_of_spikes_beside_a_step_is_removed_and_the_step_reported():
    """A GNSS glitch is often a burst of epochs: six 2-m/s north spikes in 30 s beside a 1-mg
    accelerometer x step. Every spike's update is removed (one per round, more than the first
    version's 3 rounds) and the step reported; with at most 3 rounds outliers are still named
    after the third and the step is lost (the strapdown study: 9 of 40 steps, docs/ins3d.md)."""
    fl = flight("cruise_turns", 600.0, "navigation", "baro", 4,
                faults=("ref:outliers:t=300,end=330,mag=2.0,freq=0.2,axis=y",
                        "accel:step:t=200,mag=1mg,axis=x"))
    spikes = _spikes(fl)
    assert 3 < spikes.size <= MAX_ROUNDS                      # the seed's draw
    inp = from_flight(fl)
    a = analyze_ins3d(inp.steps, inp.refs, with_observability=False)
    pf = a.post_flight_dict()
    validate(pf)
    f = pf["fault"]
    assert (pf["verdict"], pf["isolation"], f["sensor"], f["axis"], f["kind"]) == (
        "failure", "single", "accelerometer", "x", "step")
    (g,) = pf["glitches"]
    assert g["axis"] == "north" and g["count"] == spikes.size
    assert np.allclose(sorted(g["times_s"]), spikes, atol=0.1)
    three = analyze_ins3d(inp.steps, inp.refs, with_observability=False,
                          glitch_rounds=3).post_flight_dict()
    assert (three["verdict"], three["fault"]["kind"]) == ("glitch", "outliers")
    assert "accelerometer" not in three["headline"]
