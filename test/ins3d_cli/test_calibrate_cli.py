"""``flight-fdi calibrate --model ins3d --grade FILE``: a small calibration through the command
(20 flights of 60 s) writes the file back with the thresholds the calibration rule gives on the
flights' maxima and its record; bad input is one line on stderr, exit 1, the file untouched."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from flight_fdi.cli.main import main
from flight_fdi.core.ins3d.grade_file import KINDS, load_grade
from flight_fdi.eval.calibrate3d import calibrate, calibrate_seed, exceeded, seed_declared

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
    expect = calibrate(rows, 0.1)
    assert dict(g.thresholds) == pytest.approx(expect, abs=0.005)
    assert g.name == "noisy_nav" and g.arw == load_grade(src).arw
    rec = yaml.safe_load(out.read_text())["calibration"]
    assert rec["flights"] == 20 and rec["seeds"] == [300, 319] and rec["target"] == 0.1
    assert rec["exceeded"] == exceeded(rows, expect) and rec["duration_s"] == 60.0
    assert set(rec["spread"]) == set(KINDS) and rec["date"].startswith("20")
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
    assert main(argv[:i] + ["--grade", str(again)]) == 0          # no -o: written back
    capsys.readouterr()
    assert dict(load_grade(again).thresholds) == dict(load_grade(out).thresholds)


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
])
def test_bad_input_is_one_line_and_loses_nothing(argv, message, tmp_path, capsys):
    good = tmp_path / "g.yaml"
    good.write_text(GRADE)
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    argv = [str(bad) if a == "{bad}" else a for a in argv]
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
