"""The report: PNG figures that decode to real images, an HTML page that shows the verdict and
references every figure, and the ``flight-fdi report`` command on a bag and a result JSON."""
from __future__ import annotations

import argparse
import json
import re

import numpy as np
import pytest

from flight_fdi.cli.errors import CliError
from flight_fdi.core.analysis import run_analysis
from flight_fdi.eval.errors import EvalError
from flight_fdi.report import Truth, write_report
from flight_fdi.sim import SimConfig, parse_fault, simulate, simulate_to_bag


@pytest.fixture(scope="module")
def analysed():
    flight = simulate(SimConfig(duration_s=300.0, seed=5,
                                faults=(parse_fault("accel:step:t=150,mag=3mg"),)))
    res = run_analysis(flight.model, flight.t, flight.v_ins[:, 0], flight.t_ref,
                       flight.v_ref[:, 0], t0=0.0)
    truth = Truth(flight.t, flight.x_true[0], flight.model.state_names)
    return flight, res, truth


def check_png(path):
    import matplotlib.image as mpimg

    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    img = mpimg.imread(str(path))
    h, w = img.shape[:2]
    assert w > 300 and h > 300
    gray = img[..., :3].mean(axis=2)
    # not blank: a real spread of intensity, many grey levels, ink in every quarter
    assert gray.std() > 0.05
    assert np.unique((gray * 255).astype(np.uint8)).size > 20
    for part in (gray[: h // 2, : w // 2], gray[: h // 2, w // 2:], gray[h // 2:, : w // 2],
                 gray[h // 2:, w // 2:]):
        assert part.min() < 0.5
    return w, h


def test_write_report_files_decode_and_the_page_references_them(analysed, tmp_path):
    flight, res, truth = analysed
    index = write_report(res, tmp_path / "rep", truth=truth)
    assert index == tmp_path / "rep" / "index.html"
    pngs = sorted(p.name for p in index.parent.glob("*.png"))
    names = flight.model.state_names
    assert pngs == sorted([f"element_{k + 1}_{nm}.png" for k, nm in enumerate(names)]
                          + ["gate.png", "chi2.png", "glr.png"])
    sizes = {check_png(index.parent / p) for p in pngs}
    assert len(sizes) == 1  # all the same figure size
    page = index.read_text()
    assert set(re.findall(r"<img src='([^']+)'", page)) == set(pngs)
    # the verdict comes first, before any figure
    post = res.summary["post_flight"]
    assert post["verdict"] == "failure" and post["element"] == "accel_bias"
    assert page.index("FAILURE") < page.index("<img")
    assert "accel_bias" in page[:page.index("<img")]
    # summary.json is the analysis summary (the schema of flight-fdi analyze --json)
    assert json.loads((index.parent / "summary.json").read_text()) == \
        json.loads(json.dumps(res.summary))


def test_truth_is_drawn_only_when_given(analysed, tmp_path):
    from flight_fdi.report import figures

    flight, res, truth = analysed
    a = figures.element_figure(res, 2, tmp_path / "a.png", truth=truth)
    b = figures.element_figure(res, 2, tmp_path / "b.png")
    check_png(a)
    assert a.read_bytes() != b.read_bytes()
    # the truth's line is black (the estimates are coloured): it adds dark pixels
    import matplotlib.image as mpimg

    def black(p):
        img = mpimg.imread(str(p))[..., :3]
        return int(np.sum(img.max(axis=2) < 0.1))

    assert black(a) > black(b) + 500


def test_write_report_rejects_what_is_not_an_analysis(analysed, tmp_path):
    _, res, _ = analysed
    with pytest.raises(EvalError, match="AnalysisResult"):
        write_report(res.summary, tmp_path)
    with pytest.raises(EvalError, match="truth"):
        write_report(res, tmp_path, truth=(np.zeros(3), np.zeros((3, 4))))
    with pytest.raises(EvalError, match="names"):
        Truth(np.zeros(3), np.zeros((3, 4)), ("a", "b"))


def report_parser():
    from flight_fdi.cli import report

    parser = argparse.ArgumentParser(prog="flight-fdi")
    sub = parser.add_subparsers(dest="command")
    report.register(sub)
    return parser


def test_report_command_on_a_bag_and_on_a_result_json(tmp_path, capsys):
    bag = tmp_path / "flight"
    flight, _ = simulate_to_bag(SimConfig(duration_s=200.0, seed=2, truth_rate_hz=10.0,
                                          faults=(parse_fault("gyro:step:t=80,mag=20deg/h"),)),
                                str(bag))
    parser = report_parser()
    args = parser.parse_args(["report", str(bag), "--out", str(tmp_path / "r1"), "--json"])
    assert args.func(args) == 0
    out = json.loads(capsys.readouterr().out)
    post = out["summary"]["post_flight"]  # a gyro step and an accelerometer ramp: both named
    assert post["verdict"] == "ambiguous" and "gyro x: drift step" in post["headline"]
    page = (tmp_path / "r1" / "index.html").read_text()
    assert "true error" in page  # the simulated bag's /sim/truth is drawn
    assert len(list((tmp_path / "r1").glob("*.png"))) == 7
    # a result JSON naming the bag: analysed again from the bag
    result = tmp_path / "result_x.json"
    result.write_text(json.dumps(out["summary"]))
    args = parser.parse_args(["report", str(result), "--out", str(tmp_path / "r2")])
    assert args.func(args) == 0
    assert "gyro x: drift step" in capsys.readouterr().out
    assert json.loads((tmp_path / "r2" / "summary.json").read_text())["post_flight"] == \
        out["summary"]["post_flight"]


def test_report_command_errors_are_one_line(tmp_path):
    parser = report_parser()
    args = parser.parse_args(["report", str(tmp_path / "missing"), "--out", str(tmp_path / "r")])
    with pytest.raises(CliError, match="does not exist"):
        args.func(args)
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps({"post_flight": {}, "bag": str(tmp_path / "gone")}))
    args = parser.parse_args(["report", str(bad), "--out", str(tmp_path / "r")])
    with pytest.raises(CliError, match="does not exist"):
        args.func(args)
    (tmp_path / "notes.txt").write_text("x")
    args = parser.parse_args(["report", str(tmp_path / "notes.txt"), "--out", str(tmp_path / "r")])
    with pytest.raises(CliError, match="neither a bag"):
        args.func(args)


# ------------------------------------------------------------------------------ figure content

@pytest.fixture()
def drawn(monkeypatch, analysed, tmp_path):
    """The matplotlib Figure of each figure function (captured as it is saved)."""
    from flight_fdi.report import figures

    got = {}
    save = figures.save

    def keep(fig, path):
        got[path.stem] = fig
        return save(fig, path)

    monkeypatch.setattr(figures, "save", keep)
    _, res, truth = analysed
    figures.element_figure(res, 2, tmp_path / "element.png", truth=truth)
    figures.gate_figure(res, tmp_path / "gate.png")
    figures.chi2_figure(res, tmp_path / "chi2.png")
    figures.glr_figure(res, tmp_path / "glr.png")
    return res, got


def test_every_line_is_labelled_and_every_axis_has_a_unit(drawn):
    _, figs = drawn
    for name, fig in figs.items():
        for ax in fig.axes:
            assert re.search(r"\[[^\]]+\]", ax.get_ylabel()), (name, ax.get_ylabel())
            for line in ax.get_lines():
                assert not line.get_label().startswith("_"), (name, line.get_label())
        assert "[s]" in fig.axes[-1].get_xlabel()
    assert figs["gate"].axes[0].get_ylabel() == "innovation nu [m/s]"


def test_chi2_is_shaded_only_where_j_exceeds_gamma2(drawn):
    from flight_fdi.report.figures import exceed_intervals

    res, figs = drawn
    seed = res.seed
    t = np.asarray(seed.t) - res.t0
    over = np.asarray(seed.valid, bool) & (seed.J > seed.gamma2)
    spans = exceed_intervals(t, over)
    assert spans and len(figs["chi2"].axes[0].patches) == len(spans)
    for a, b in spans:
        assert np.all(over[(t >= a) & (t <= b)])  # nothing shaded where J <= gamma^2
    assert exceed_intervals(np.arange(6.0), [0, 1, 1, 0, 1, 0]) == [(1.0, 2.0), (4.0, 4.0)]


def test_alarm_spans_are_visible_at_flight_scale(drawn):
    from flight_fdi.report.figures import MIN_SPAN_FRACTION

    res, figs = drawn
    ax = figs["gate"].axes[1]
    assert res.fwd.alarms() and len(ax.patches) == len(res.fwd.alarms())
    figs["gate"].canvas.draw()
    width = ax.get_window_extent().width
    for p in ax.patches:
        assert p.get_window_extent().width >= 0.9 * MIN_SPAN_FRACTION * width


def test_hypotheses_have_distinct_styles_none_in_the_thresholds_red(drawn):
    from flight_fdi.core.glr import DEFAULT_HYPOTHESES
    from flight_fdi.report.figures import THRESHOLD_COLOR, hypothesis_style

    styles = [tuple(hypothesis_style(h).values()) for h in DEFAULT_HYPOTHESES]
    assert len(set(styles)) == len(styles)
    assert all(c != THRESHOLD_COLOR for c, _ in styles)
    _, figs = drawn
    colors = {ln.get_label(): ln.get_color() for ln in figs["glr"].axes[0].get_lines()}
    assert colors["reference_outlier"] != colors[next(k for k in colors if k.startswith("thr"))]
