"""The ladder on a YAML grade file (``run_ladder`` / ``montecarlo --model ins3d --ladder --grade
FILE``): a tiny ladder (accelerometer steps, 1 rung, 2 flights of 120 s per axis, ~1 s each)
shows that the file's grade is what is simulated and analysed: the navigation preset written as
a file flies and decides exactly as the preset; a file that differs only in a simulator value
(a gyro scale factor, not a state of the model) changes the flights' statistics; a file that
differs only in one threshold changes only that axis' outcome, not the statistics."""
from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from flight_fdi.cli.main import main
from flight_fdi.core.ins3d.glr3d import thresholds_for
from flight_fdi.core.ins3d.grade_file import grade_from_dict
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.ladder3d import LADDER_TOP, ladder_top, run_ladder
from flight_fdi.eval.metrics3d import OUTCOMES
from flight_fdi.eval.montecarlo3d import Study3DConfig

NAV_FILE = Path(__file__).resolve().parents[2] / "config/grades/navigation_as_file.yaml"
NAV = yaml.safe_load(NAV_FILE.read_text())
CFG = Study3DConfig(duration_s=120.0, profile="random", seed=3, single_axis=False)


def _ladder(grade) -> dict:
    return run_ladder(CFG, (grade,), scenarios=("accel_step",), runs=2, rungs=1)


def _by_axis(lad: dict) -> dict:
    return {g["axis"]: g for g in lad["groups"]}


@pytest.fixture(scope="module")
def preset():
    return _ladder("navigation")


def test_the_preset_written_as_a_file_is_the_preset(preset):
    lad = _ladder(str(NAV_FILE))
    a, b = _by_axis(preset), _by_axis(lad)
    for ax in "xyz":
        assert b[ax]["grade"] == "navigation_as_file" and a[ax]["grade"] == "navigation"
        assert b[ax]["hypothesis"] == f"accelerometer_{ax}_step"
        ra, rb = a[ax]["rungs"][0], b[ax]["rungs"][0]
        assert rb["level"] == ra["level"] == LADDER_TOP["navigation"]["accel_step"]
        assert rb["statistic_median"] == pytest.approx(ra["statistic_median"], rel=1e-6)
        assert {k: rb[k] for k in OUTCOMES} == {k: ra[k] for k in OUTCOMES}
    info = lad["grades"][0]
    assert info["name"] == "navigation_as_file" and not info["preset"]
    assert info["thresholds"] == thresholds_for("navigation", 120.0)
    assert info["values"]["accel_scale"] == pytest.approx(50e-6)
    assert preset["grades"][0] == {"name": "navigation", "preset": True,
                                   "thresholds": thresholds_for("navigation", 120.0)}


def test_a_simulator_only_value_of_the_file_is_simulated(preset):
    """gyro_scale_ppm is not in the estimator's model (scale factors are not states): only
    the simulated flights can change the statistics."""
    lad = _ladder(grade_from_dict({**NAV, "name": "scaled", "gyro_scale_ppm": 1e5}))
    a, b = _by_axis(preset), _by_axis(lad)
    assert lad["grades"][0]["values"]["gyro_scale"] == pytest.approx(0.1)
    diff = [abs(b[ax]["rungs"][0]["statistic_median"] / a[ax]["rungs"][0]["statistic_median"]
                - 1.0) for ax in "xyz"]
    assert max(diff) > 0.2, diff


def test_the_files_threshold_decides(preset):
    """One per-hypothesis threshold raised above every flight's statistic: the same flights
    (statistics equal), that axis no longer isolated, the others as the preset's."""
    thr = {"accelerometer_x_step": 1e5}
    lad = _ladder(grade_from_dict({**NAV, "name": "deaf_x", "thresholds": thr}))
    a, b = _by_axis(preset), _by_axis(lad)
    assert a["x"]["rungs"][0]["right"] == 2 and b["x"]["rungs"][0]["right"] == 0
    assert b["x"]["smallest_95"] is None and b["x"]["direction"] == "up"
    for ax in "xyz":
        assert b[ax]["rungs"][0]["statistic_median"] == \
            pytest.approx(a[ax]["rungs"][0]["statistic_median"], rel=1e-9)
    for ax in "yz":
        assert b[ax]["rungs"][0]["right"] == a[ax]["rungs"][0]["right"]
    assert lad["grades"][0]["thresholds"]["accelerometer_x_step"] == 1e5


def test_ladder_top_and_grade_errors():
    assert ladder_top(grade_from_dict({"name": "m", "base": "mems"})) == LADDER_TOP["mems"]
    assert ladder_top("tactical") == LADDER_TOP["tactical"]
    with pytest.raises(EvalError, match="no ladder top for base 'perfect'"):
        ladder_top(grade_from_dict({"name": "p", "base": "perfect"}))
    with pytest.raises(EvalError, match="two grades named alike"):
        run_ladder(CFG, ("navigation", grade_from_dict({"name": "navigation",
                                                        "base": "tactical"})))
    with pytest.raises(EvalError, match="unknown grade 'foo'"):
        run_ladder(CFG, ("foo",))


def test_cli_ladder_on_a_grade_file(tmp_path, capsys):
    """``--ladder --grade FILE``: the file's ladder (the --scenarios given), its thresholds and
    values in the JSON (and --out), the rung's progress on stderr as the preset ladder's;
    ``--ladder-grades`` takes files beside presets; a bad file is one line, exit 1; the GNSS
    jump is not a ladder scenario."""
    path = tmp_path / "deaf.yaml"
    path.write_text(NAV_FILE.read_text().replace("name: navigation_as_file", "name: deaf")
                    + "thresholds: {accelerometer_y_step: 100000}\n")
    out = tmp_path / "ladder.json"
    common = ["montecarlo", "--model", "ins3d", "--ladder", "--scenarios", "accel_step",
              "--duration", "120", "--seed", "3", "--ladder-runs", "2", "--ladder-rungs", "1",
              "--jobs", "1", "--no-single-axis"]
    assert main(common + ["--grade", str(path), "--json", "--out", str(out)]) == 0
    cap = capsys.readouterr()
    doc = json.loads(cap.out)
    assert "ladder rung 1/1" in cap.err
    assert json.loads(out.read_text()) == doc
    lad = doc["ladder"]
    assert [g["grade"] for g in lad["groups"]] == ["deaf"] * 3
    assert lad["grades"][0]["thresholds"]["accelerometer_y_step"] == 1e5
    y = _by_axis(lad)["y"]
    assert y["rungs"][0]["right"] == 0 and y["smallest_95"] is None
    assert main(common + ["--no-progress", "--ladder-grades", f"navigation,{path}"]) == 0
    text = capsys.readouterr().out
    assert "| navigation | accel_step | y | 1 mg (bottom rung) | 1: 2/2 |" in text
    assert "| deaf | accel_step | y | not reached (> 1 mg) |" in text
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: b\nbase: navigation\nthresholds: {gyro_w_step: 3}\n")
    for opt in (["--grade", str(bad)], ["--ladder-grades", f"navigation,{bad}"]):
        assert main(common + ["--no-progress"] + opt) == 1
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and "unknown key 'thresholds.gyro_w_step'" in err, err
    from flight_fdi.eval.montecarlo3d import SCENARIOS
    for given in ("ref_jump", ",".join(SCENARIOS)):      # the whole list given is given too
        assert main(common[:5] + [given] + common[6:] + ["--no-progress"]) == 1
        assert "ladder scenario must be an IMU scenario" in capsys.readouterr().err
