"""``flight-fdi calibrate --model ins3d --grade FILE``: a small calibration through the command
(20 flights of 60 s) writes the file back with the thresholds the calibration rule gives on the
flights' maxima -- per kind and per hypothesis (``--per-kind``: per kind only) -- and its
record; ``analyze --grade`` then isolates with the file's per-hypothesis thresholds; bad input
is one line on stderr, exit 1, the file untouched."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from flight_fdi.cli.main import main
from flight_fdi.core.ins3d.grade_file import KINDS, load_grade
from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS, thresholds_for
from flight_fdi.eval.calibrate3d import (OUTLIER_SHARE, calibrate, calibrate_hypotheses,
                                         calibrate_seed, exceeded, exceeded_hypotheses,
                                         seed_declared)

GRADE = """\
# a navigation unit with noisier gyros (kept by the calibration)
name: noisy_nav
base: navigation
gyro_arw_deg_rth: 0.004
thresholds: {step: 99}
"""


@pytest.fixture(scope="module")
def calibrated(tmp_path_factory):
    d = tmp_path_factory.mktemp("calib")
    src = d / "noisy.yaml"
    src.write_text(GRADE)
    out = d / "noisy_cal.yaml"
    argv = ["calibrate", "--model", "ins3d", "--grade", str(src), "--flights", "20",
            "--seed", "300", "--duration", "60", "--false-isolation", "0.1", "--profile",
            "cruise_turns,random", "--seed-declaration", "0.05", "--jobs", "1", "--no-progress", "--json", "-o", str(out)]
    return src, out, argv


def test_calibrate_writes_the_thresholds_of_the_rule(calibrated, capsys):
    src, out, argv = calibrated
    assert main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    rows = doc["flights"]
    assert [r["seed"] for r in rows] == list(range(300, 320))
    assert [r["profile"] for r in rows[:3]] == ["cruise_turns", "random", "cruise_turns"]
    assert src.read_text() == GRADE                      # -o: the source is not touched
    g = load_grade(out)
    # per kind (a quarter of 0.1 each) and per hypothesis (0.075 / 15 each): calibrate3d's
    # rules on the same maxima, called directly
    expect = {**calibrate(rows, 0.1), **calibrate_hypotheses(rows, 0.1)}
    assert set(expect) == {*KINDS, *PER_HYPOTHESIS}
    assert dict(g.thresholds) == pytest.approx(expect, abs=0.005)
    assert doc["thresholds"] == expect
    assert g.name == "noisy_nav" and g.arw == load_grade(src).arw
    rec = yaml.safe_load(out.read_text())["calibration"]
    assert rec["flights"] == 20 and rec["seeds"] == [300, 319] and rec["target"] == 0.1
    assert rec["exceeded"] == exceeded_hypotheses(rows, expect) and rec["duration_s"] == 60.0
    assert rec["rule"] == "per_hypothesis" and rec["shares"] == {
        "outliers": pytest.approx(OUTLIER_SHARE * 0.1),
        "hypothesis": pytest.approx((1 - OUTLIER_SHARE) * 0.1 / 15)}
    assert set(rec["growth"]) == set(PER_HYPOTHESIS)
    assert set(rec["spread"]) == {*KINDS, *PER_HYPOTHESIS} and rec["date"].startswith("20")
    assert set(doc["summary_hypotheses"]) == set(PER_HYPOTHESIS)
    assert out.read_text().startswith("# a navigation unit with noisier gyros")
    assert "thresholds: {step: 99}" not in out.read_text()
    p = calibrate_seed(rows, 0.05)               # the seed method's, for its own target
    assert g.episode_probability == pytest.approx(p, rel=1e-3) == doc["seed_episode_probability"]
    assert rec["seed"]["target"] == 0.05 and rec["seed"]["episode_probability"] == p
    assert rec["seed"]["default"] == 1e-6          # a number for YAML too (written 1.0e-06)
    assert rec["seed"]["declared"] == seed_declared(rows, p)
    assert rec["seed"]["declared_default"] == seed_declared(rows, 1e-6)


def test_the_same_seed_calibrates_the_same_and_in_place(calibrated, capsys, tmp_path):
    src, out, argv = calibrated
    again = tmp_path / "inplace.yaml"
    again.write_text(GRADE)
    i = argv.index("-o")
    argv = [a for a in argv[:i] if a != "--json"]
    assert main(argv + ["--grade", str(again)]) == 0          # no -o: written back
    text = capsys.readouterr().out
    assert again.read_text() == out.read_text()         # seeded: the same file
    thr = dict(load_grade(out).thresholds)
    gz = next(line.split() for line in text.splitlines() if line.startswith("gyro_z_step "))
    # the table: median, 90 %, largest, threshold, spread, before (the file's step: 99)
    assert float(gz[4]) == pytest.approx(thr["gyro_z_step"]) and gz[6] == "99.0"
    assert "budget: 0.5 % per hypothesis (15), outliers 2.5 %" in text


def test_per_kind_keeps_the_old_rule(calibrated, capsys, tmp_path):
    """--per-kind: the kinds' thresholds only (calibrate), the base's per-hypothesis ones are
    dropped (a kind given holds for all its hypotheses), the record says so."""
    src, out, argv = calibrated
    kinds = tmp_path / "kinds.yaml"
    i = argv.index("-o")
    assert main(argv[:i] + ["--per-kind", "-o", str(kinds)]) == 0
    doc = json.loads(capsys.readouterr().out)
    expect = calibrate(doc["flights"], 0.1)
    assert dict(load_grade(kinds).thresholds) == pytest.approx(expect, abs=0.005)
    rec = yaml.safe_load(kinds.read_text())["calibration"]
    assert rec["rule"] == "per_kind" and "growth" not in rec
    assert rec["exceeded"] == exceeded(doc["flights"], expect)
    assert f"thresholds: {{step: {expect['step']:.2f}, " in kinds.read_text()


def test_analyze_isolates_with_the_files_own_threshold(calibrated, bag3d, capsys, tmp_path):
    """The calibrated file through ``analyze --model ins3d --grade``: the gyro x step is
    isolated and judged against the file's gyro_x_step threshold -- not its step kind's, not
    the navigation preset's; the same file with that one value above the statistic no longer
    names gyro x (the isolator reads it)."""
    src, out, argv = calibrated
    if not out.exists():
        assert main(argv) == 0
        capsys.readouterr()
    thr = dict(load_grade(out).thresholds)
    own = thr["gyro_x_step"]
    assert own != thr["step"] and own != thresholds_for("navigation")["gyro_x_step"]
    cmd = ["analyze", str(bag3d), "--model", "ins3d", "--json", "--grade"]
    assert main(cmd + [str(out)]) == 0
    post = json.loads(capsys.readouterr().out)["post_flight"]
    assert (post["fault"]["hypothesis"], post["isolation"]) == ("gyro_x_step", "single")
    assert post["fault"]["threshold"] == own == post["glr"]["thresholds"]["gyro_x_step"]
    high = tmp_path / "high.yaml"
    high.write_text(out.read_text().replace(f"gyro_x_step: {own:.2f}", "gyro_x_step: 1.0e6"))
    assert main(cmd + [str(high)]) == 0
    post = json.loads(capsys.readouterr().out)["post_flight"]
    assert post["glr"]["thresholds"]["gyro_x_step"] == 1e6
    assert post["fault"] is None or post["fault"]["hypothesis"] != "gyro_x_step"


@pytest.mark.parametrize("argv, message", [
    (["--grade", "/no/such/grade.yaml"], "cannot read it"),
    (["--grade", "{bad}"], "not valid YAML"),
    (["--flights", "5"], "--flights must be at least 20, got 5"),
    (["--profile", "loop"], "--profile 'loop': unknown profile"),
    (["--false-isolation", "1.5"], "--false-isolation must be within (0, 1)"),
    (["--seed-declaration", "0"], "--seed-declaration must be within (0, 1)"),
    (["--model", "channel"], "only ins3d"),
    (["--grade", "tactical"], "'tactical' is a preset"),
    (["-o", "/no/such/dir/x.yaml"], "-o: cannot write"),
    (["--grade", "{badkey}"], "unknown key 'thresholds.gyro_w_step'"),
    (["--grade", "{badvalue}"], "thresholds.gyro_z_step must be a finite number > 0"),
])
def test_bad_input_is_one_line_and_loses_nothing(argv, message, tmp_path, capsys):
    good = tmp_path / "g.yaml"
    good.write_text(GRADE)
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    files = {"{bad}": bad}
    for name, line in (("badkey", "gyro_w_step: 3"), ("badvalue", "gyro_z_step: -1")):
        files["{" + name + "}"] = tmp_path / f"{name}.yaml"
        files["{" + name + "}"].write_text(f"name: a\nbase: navigation\nthresholds:\n  {line}\n")
    argv = [str(files.get(a, a)) for a in argv]
    base = ["calibrate", "--grade", str(good), "--no-progress", "--jobs", "1"]
    assert main(base + argv) == 1
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert err.count("\n") == 0 and err.startswith("flight-fdi calibrate: error: "), err
    assert message in err and cap.out == ""
    assert good.read_text() == GRADE and bad.read_text() == "name: [unclosed\n"


def test_the_shipped_grade_files_are_valid():
    """The examples keep loading; navigation_as_file (check a of the docs) is the preset."""
    from dataclasses import fields

    from flight_fdi.core.ins3d.grades import GRADES

    grades = Path(__file__).resolve().parents[2] / "config/grades"
    for name in ("example_mems_custom", "example_nav_noisy"):     # kinds given: per kind
        assert set(dict(load_grade(grades / f"{name}.yaml").thresholds)) == set(KINDS)
    # none given: the base's, the navigation preset's per-hypothesis thresholds included
    from flight_fdi.core.ins3d.glr3d import thresholds_for
    assert dict(load_grade(grades / "navigation_as_file.yaml").thresholds) == \
        thresholds_for("navigation")
    g, nav = load_grade(grades / "navigation_as_file.yaml"), GRADES["navigation"]
    for f in fields(nav):
        if f.name != "name":
            assert getattr(g, f.name) == pytest.approx(getattr(nav, f.name), rel=1e-15)
