"""``--grade FILE.yaml`` for ``flight-fdi analyze --model ins3d``: a grade file gives the same
analysis as the preset it writes out; a bad file or an unknown name is a one-line error."""
from __future__ import annotations

import json
from pathlib import Path

import pytest

from flight_fdi.cli.main import main
from flight_fdi.schema import validate_result

REPO = Path(__file__).resolve().parents[2]


def _tactical_file(tmp_path: Path, extra: str = "") -> Path:
    """The tactical preset, all from the base, under another name."""
    p = tmp_path / "my_tactical.yaml"
    p.write_text("name: my_tactical\nbase: tactical\n" + extra)
    return p


def test_a_grade_file_analyses_as_its_preset(bag3d, tmp_path, capsys):
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json", "--grade", "tactical"]) == 0
    preset = json.loads(capsys.readouterr().out)
    path = _tactical_file(tmp_path)
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json",
                 "--grade", str(path)]) == 0
    custom = json.loads(capsys.readouterr().out)
    validate_result(custom)
    assert custom["ins3d"]["grade"] == "my_tactical"
    assert custom["source"]["grade"] == str(path.resolve())
    preset["ins3d"].pop("grade"), custom["ins3d"].pop("grade")
    assert custom["ins3d"] == preset["ins3d"] and custom["post_flight"] == preset["post_flight"]
    # the example file is accepted
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json", "--grade",
                 str(REPO / "config/grades/example_mems_custom.yaml")]) == 0
    assert json.loads(capsys.readouterr().out)["ins3d"]["grade"] == "example_mems_custom"


@pytest.mark.parametrize("text, needle", [
    (None, "cannot read"),
    ("name: x\nbase: mems\naccel_bias_ug: -5\n", "accel_bias_ug must be a finite number >= 0"),
    ("name: x\nbase: mems\nbias: 5\n", "unknown key 'bias'"),
    ("name: x\nbase: cheap\n", "base must be a preset"),
])
def test_a_bad_grade_file_is_one_line(bag3d, tmp_path, capsys, text, needle):
    path = tmp_path / "g.yaml"
    if text is not None:
        path.write_text(text)
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--grade", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and needle in err[0] and err[0].startswith("flight-fdi analyze: error:")


def test_an_unknown_grade_name_is_one_line(bag3d, capsys):
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--grade", "consumer"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "'consumer': not a preset" in err[0]


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_run_with_a_grade_file_equals_analyze(bag3d, tmp_path, capfd):
    """The pipeline's filter_node loads the file, the recording carries its numbers, and the
    smoother analyses with them: the result of ``analyze`` with the same file."""
    path = _tactical_file(tmp_path, "gyro_bias_deg_h: 0.5\naccel_bias_ug: 150\n"
                                    "thresholds: {step: 23.0}\n")
    argv = ["--model", "ins3d", "--json", "--grade", str(path)]
    assert main(["analyze", str(bag3d), *argv]) == 0
    ref = json.loads(capfd.readouterr().out)
    assert main(["run", str(bag3d), *argv, "--out", str(tmp_path / "run"), "--no-progress",
                 "--no-report"]) in (0, 3)
    res = json.loads(capfd.readouterr().out)
    validate_result(res)
    assert res["ins3d"]["grade"] == "my_tactical"
    assert res["post_flight"] == ref["post_flight"] and res["ins3d"] == ref["ins3d"]
    assert res["in_flight"] == ref["in_flight"]


def test_report_of_a_result_reanalyses_with_the_results_grade_and_rows(bag3d, tmp_path, capsys):
    """``report RESULT.json`` analyses the bag again as the result was made (its grade, rows and
    topics), not with the command's defaults; an option given on the command line wins."""
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--json", "--grade", "tactical",
                 "--rows", "2"]) == 0
    made = json.loads(capsys.readouterr().out)
    doc = tmp_path / "result.json"
    doc.write_text(json.dumps(made))
    assert main(["report", str(doc), "--out", str(tmp_path / "rep"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)["summary"]
    assert summary["source"]["grade"] == "tactical" and summary["source"]["rows"] == 2
    assert summary["post_flight"] == made["post_flight"]
    assert main(["report", str(doc), "--out", str(tmp_path / "rep2"), "--json",
                 "--grade", "navigation"]) == 0
    again = json.loads(capsys.readouterr().out)["summary"]
    assert again["source"]["grade"] == "navigation" and again["source"]["rows"] == 2


def test_signature_error_in_a_grade_file_widens_the_confident_answer(bag3d, tmp_path, capsys):
    """``signature_error_rad``: the model-error allowance of ``glr3d.settle``. On this flight the
    3 deg/h gyro x step beats its rival, the accelerometer y step (signatures alike to cos 0.89
    through the filter), by a gap that an allowance of 0.33 rad (the real recordings' setting)
    leaves confident and one of 0.6 rad does not (the boundary is near 0.47 here): then it is
    ambiguous, both named, and the headline says why. The allowance survives the recording's
    grade numbers (the smoother analyses with it)."""
    from flight_fdi.core.ins3d.grade_file import CustomGrade, load_grade, signature_error_of
    from flight_fdi.core.ins3d.grades import GRADES

    answers = {}
    for eps in ("0.33", "0.6"):
        path = tmp_path / f"nav_{eps}.yaml"
        path.write_text(f"name: nav_eps\nbase: navigation\nsignature_error_rad: {eps}\n")
        assert main(["analyze", str(bag3d), "--model", "ins3d", "--json",
                     "--grade", str(path)]) == 0
        answers[eps] = json.loads(capsys.readouterr().out)["post_flight"]
    glr = answers["0.33"]["glr"]
    assert (glr["hypothesis"], glr["isolation"], glr["runner_up"]) == \
        ("gyro_x_step", "single", "accelerometer_y_step")
    assert answers["0.33"]["verdict"] == "failure"
    glr6 = answers["0.6"]["glr"]
    assert glr6["isolation"] == "ambiguous" and glr6["statistic"] == glr["statistic"]
    assert {c["sensor"] + " " + c["axis"] for c in answers["0.6"]["candidates"]} == \
        {"gyro x", "accelerometer y"}
    assert "what the model's error allows" in answers["0.6"]["headline"]
    # the default is the grade's misalignment; the value round-trips through a recording's numbers
    assert signature_error_of(GRADES["navigation"]) == max(GRADES["navigation"].gyro_misalign,
                                                           GRADES["navigation"].accel_misalign)
    g = load_grade(tmp_path / "nav_0.6.yaml")
    assert signature_error_of(g) == 0.6
    assert CustomGrade.from_numbers(g.name, g.numbers()) == g


@pytest.mark.parametrize("value, needle", [("2.0", "below pi/2"), ("-0.1", ">= 0"),
                                           ("wide", "must be a number")])
def test_a_bad_signature_error_is_one_line(bag3d, tmp_path, capsys, value, needle):
    path = tmp_path / "g.yaml"
    path.write_text(f"name: x\nbase: navigation\nsignature_error_rad: {value}\n")
    assert main(["analyze", str(bag3d), "--model", "ins3d", "--grade", str(path)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "signature_error_rad" in err[0] and needle in err[0]
