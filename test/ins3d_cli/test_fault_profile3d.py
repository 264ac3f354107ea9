"""The report's fault profile after the nonlinear check of a large gyro fault: the result's fault
record carries the exact fit's onset and magnitude (``result3d.fault_record(exact=)``), and the
figure and ``Ins3dAnalysis.bias_estimates`` draw that record, not the linear GLR's estimate
(before: ``bias_estimates`` took the linear onset and magnitude, the figure drew steps only).

On the real excerpt (Xsens DOT unit 1 of straight/path_2, test/ins3d_eval/data; ~1 s per
analysis), as test/ins3d_eval/test_nonlinear_real.py makes its large gyro faults."""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.core.ins3d_result import ins3d_result
from flight_fdi.eval import real3d as R
from flight_fdi.report import figures3d

EXCERPT = Path(__file__).resolve().parents[1] / "ins3d_eval" / "data" / "mimu_straight_2"


@pytest.fixture(scope="module")
def excerpt():
    """(recording, gyro bias, accelerometer bias) of the excerpt."""
    rec = R.read_recording(EXCERPT.parent, EXCERPT.name, 1)
    doc = json.loads((EXCERPT / "calibration.json").read_text())
    return rec, np.array(doc["gyro_bias_rad_s"]), np.array(doc["accel_bias_m_s2"])


def _with_gyro(rec, axis: str, onset: float, rate=None, step=None):
    """The recording with a gyro step (rad/s) or ramp (rad/s^2) on ``axis`` from ``onset``."""
    g, t = rec.gyro.copy(), rec.t - rec.t[0]
    on = t >= onset
    g[on, "xyz".index(axis)] += step if step is not None else rate * (t[on] - onset)
    return R.Recording(rec.name, rec.unit, rec.t, g, rec.accel, rec.gt, rec.dropped)


def _drawn(analysis, res, axis, monkeypatch, tmp_path) -> dict:
    """{label: (xdata, ydata)} of the fault lines the axis figure draws (its two panels)."""
    figs = []
    monkeypatch.setattr(figures3d, "save", lambda fig, path: figs.append(fig) or path)
    figures3d.axis_figure(analysis, res, axis, tmp_path / f"axis_{axis}.png")
    (fig,) = figs
    out = {}
    for panel, scale in zip(fig.axes, (figures3d.MG, figures3d.DEG_PER_HOUR)):
        for line in panel.get_lines():
            if line.get_label().startswith(("isolated", "candidate")):
                out[(panel.get_ylabel().split()[0], line.get_label())] = (
                    np.asarray(line.get_xdata(), float), np.asarray(line.get_ydata()) * scale)
    return out


def test_an_exact_fit_is_what_the_figure_and_the_series_draw(excerpt, monkeypatch, tmp_path):
    """A 5 deg/s gyro y step at 5 s: the check names it with the exact fit's onset (5.1 s) and
    magnitude; the linear GLR put the onset at 5.5 s. The smoothed series' fault profile and
    the figure's line are the record's, to the last bit."""
    rec, bg, ba = excerpt
    an = R.analyze(_with_gyro(rec, "y", 5.0, step=math.radians(5.0)), bg, ba)
    res = ins3d_result(an, "excerpt")
    f = res["post_flight"]["fault"]
    assert an.nonlinear is not None and an.isolation.reason == "nonlinear"
    assert (f["hypothesis"], res["post_flight"]["verdict"]) == ("gyro_y_step", "failure")
    fit = an.nonlinear.fit_of("gyro_y_step")
    assert (f["onset_s"], f["magnitude"]) == (fit.onset, fit.magnitude)
    lin = an.decision_glr["gyro_y_step"]
    assert abs(float(lin.t[lin.best]) - fit.onset) > 0.2          # the two estimates differ
    assert abs(float(lin.mag[lin.best]) / fit.magnitude - 1.0) > 5e-3   # measured: 1 %

    b = an.bias_estimates()
    after = b["t"] >= f["onset_s"]
    assert np.any(after) and np.any(~after)
    assert np.all(b["gyro_fault"][after, 1] == f["magnitude"])
    assert np.all(b["gyro_fault"][~after, 1] == 0.0)
    assert not b["gyro_fault"][:, [0, 2]].any() and not b["accelerometer_fault"].any()

    lines = _drawn(an, res, "y", monkeypatch, tmp_path)
    assert list(lines) == [("gyro", f"isolated step {f['magnitude_eng']:+.3g} deg/h")]
    (t, y), = lines.values()
    assert t[1] == t[2] == f["onset_s"]
    assert y[:2] == pytest.approx([0.0, 0.0]) and y[2:] == pytest.approx([f["magnitude"]] * 2)


def test_ambiguous_ramps_are_drawn_with_their_exact_fits(excerpt, monkeypatch, tmp_path):
    """A 1 deg/s^2 gyro y ramp at 5 s: ambiguous after the check (gyro y ramp or accelerometer
    z ramp), each candidate with its exact fit; the figures draw both ramps from the records
    (before: only steps were drawn), and no isolated fault profile exists. (With the 0.33-rad
    model-error allowance of sessions 11-14; with the grade's, the default now, gyro y is named.)"""
    rec, bg, ba = excerpt
    an = R.analyze(_with_gyro(rec, "y", 5.0, rate=math.radians(1.0)), bg, ba,
                   R.Settings(signature_error=0.33))
    res = ins3d_result(an, "excerpt")
    post = res["post_flight"]
    assert post["verdict"] == "ambiguous" and an.nonlinear is not None
    drawn = {}
    for axis in "xyz":
        drawn.update(_drawn(an, res, axis, monkeypatch, tmp_path))
    assert len(drawn) == len(post["candidates"]) == 2
    for c in post["candidates"]:
        assert c["kind"] == "ramp"
        fit = an.nonlinear.fit_of(c["hypothesis"])
        assert (c["onset_s"], c["magnitude"]) == (fit.onset, fit.magnitude)
        panel = "accelerometer" if c["sensor"] == "accelerometer" else "gyro"
        (t, y), = [v for k, v in drawn.items()
                   if k == (panel, f"candidate ramp {c['magnitude_eng']:+.3g} {c['unit_eng']}")]
        assert t[1] == c["onset_s"]
        assert y[2] == pytest.approx(c["magnitude"] * (t[2] - t[1]), rel=1e-12)
    b = an.bias_estimates()
    assert not b["gyro_fault"].any() and not b["accelerometer_fault"].any()
