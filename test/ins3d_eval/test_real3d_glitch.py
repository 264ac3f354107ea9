"""A reference glitch beside an injected IMU fault on the real excerpt (straight/path_2 unit 1,
1-Hz RTK reference; core/ins3d/glitch.py), and how the evaluation judges glitches
(``real3d_record.judge``; docs/ins3d_real.md, "A reference glitch and a fault in the same
flight")."""
from __future__ import annotations

import pytest

from flight_fdi.eval import real3d as R

STEP = R.Fault("accelerometer", "y", 1.0, 6.0)


def _analyze(monkeypatch, rec, cal, spike: float, update: int = 9):
    """``real3d.analyze`` of the excerpt with the accelerometer y step and ``spike`` m/s added
    to the east row of reference update ``update`` (9: 9.5 s) of the decoded contract."""
    build = R.build_contract

    def spiked(*args, **kw):
        inp = build(*args, **kw)
        inp.refs.z[update, 0] += spike
        return inp
    monkeypatch.setattr(R, "build_contract", spiked)
    return R.analyze(STEP.apply(rec), *cal, reference_of=rec)


def test_glitch_beside_a_real_step_both_named(monkeypatch, rec, cal):
    """A 3-m/s east spike (z + 3: the reference reads 3 m/s low) at 9.5 s: its outlier
    statistic (2048; its neighbours, pulled by it, 55-98) beats the step's (350), so the old
    rule names the glitch only; removing the spike's update alone (not its neighbours) and
    deciding again finds the step as on the flight without the spike (0.862 m/s^2 at 5.5 s)."""
    a = _analyze(monkeypatch, rec, cal, 3.0)
    assert (a.isolation.isolation, a.isolation.best) == ("single", "reference_east_outliers")
    east = a.glr["reference_east_outliers"]
    assert int((east.stat > 32.0).sum()) >= 4                # the spike and its neighbours
    out = R.record(a)
    assert (out["verdict"], out["sensor"], out["axis"], out["kind"]) == (
        "failure", "accelerometer", "y", "step")
    assert out["onset_s"] == pytest.approx(5.5) and out["magnitude"] == pytest.approx(0.86,
                                                                                      abs=0.03)
    assert out["glitch_rounds"] == 1 and out["glitch_rest_named"] is True
    (g,) = out["glitches"]
    assert g["axis"] == "east" and g["times_s"] == [pytest.approx(9.5)]
    # judged: right only when the glitch is the recording's own (here it was added)
    assert R.judge(out, STEP, (9.5,)) == "right"
    assert R.judge(out, STEP) == "wrong"


def test_outliers_beside_the_decision_are_left_alone(monkeypatch, rec, cal):
    """Without the spike the step is named, and the north outlier statistic at its onset
    (44 > 32: the step's own first update) is counted but nothing is removed: the result is
    the decision as before."""
    a = _analyze(monkeypatch, rec, cal, 0.0)
    pf = a.post_flight_dict()
    assert a.sequential is None and pf["glitches"] == []
    assert pf["glr"]["outliers_above_threshold"] >= 1
    assert (pf["fault"]["sensor"], pf["fault"]["axis"]) == ("accelerometer", "y")


def _rec(verdict, sensor=None, axis=None, glitch_times=()):
    return {"verdict": verdict, "sensor": sensor, "axis": axis,
            "glitch_times_s": list(glitch_times)}


@pytest.mark.parametrize("out,fault,expect", [
    (_rec("glitch", "reference", "east", [26.5]), STEP, "glitch"),   # own glitch, fault missed
    (_rec("glitch", "reference", "east", [20.5]), STEP, "wrong"),    # not the recording's
    (_rec("failure", "accelerometer", "y", [26.5]), STEP, "right"),  # both found
    (_rec("failure", "accelerometer", "y", [20.5]), STEP, "wrong"),  # right + a false glitch
    (_rec("failure", "accelerometer", "y"), STEP, "right"),
    (_rec("failure", "accelerometer", "x", [26.5]), STEP, "wrong"),
    (_rec("ambiguous", None, None, [26.5]), STEP, "ambiguous"),
    (_rec("glitch", "reference", "east", [26.5]), None, "glitch"),    # nominal run
    (_rec("glitch", "reference", "east", [20.5]), None, "reference"),
])
def test_judge_counts_the_recordings_own_glitch(out, fault, expect):
    assert R.judge(out, fault, R.REFERENCE_GLITCHES["vertical/path_14"]) == expect
