"""The long-flight evaluation's pieces (flight_fdi/eval/long3d.py, the length rule of the GLR
thresholds, tools/ins3d_eval.py's long sections): known answers on hand-made records, a resumed
study equal to an uninterrupted one, the rendered tables from records on disk."""
from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest

from flight_fdi.core.ins3d.glr3d import CALIBRATED_LENGTH_S, thresholds_for
from flight_fdi.eval.long3d import (LoadSampler, by_onset, calibration_table, detectable_steps,
                                    format_by_onset, format_by_turn_after,
                                    format_nominal_maxima, format_onset_by_axis,
                                    format_onset_coverage, merge_records, nominal_maxima,
                                    read_study, run_recorded, study_files)
from flight_fdi.eval.metrics3d import binomial_interval
from flight_fdi.eval.montecarlo3d import SCENARIOS, Study3DConfig, decision, glr_max_by_kind

REPO = Path(__file__).resolve().parents[2]


def test_thresholds_grow_with_the_length_as_calibrated_per_kind():
    base = thresholds_for("navigation")
    assert thresholds_for("navigation", 900.0) == base            # shorter: as calibrated
    assert thresholds_for("navigation", CALIBRATED_LENGTH_S) == base
    long = thresholds_for("navigation", 7200.0)
    assert long["jump"] == pytest.approx(base["jump"] + 2 * math.log(4.0))   # 32.77
    assert long["outliers"] == pytest.approx(base["outliers"] + 2 * math.log(4.0))
    assert long["step"] == pytest.approx(base["step"] + math.log(4.0))       # 21.39
    assert long["ramp"] == base["ramp"]
    assert thresholds_for("tactical", 3600.0)["jump"] == pytest.approx(30.0 + 2 * math.log(2))


def test_glr_maxima_per_kind_in_the_decision_record():
    stats = {"gyro_x_step": 3.0, "accelerometer_z_step": 7.5, "gyro_y_ramp": 2.0,
             "reference_east_jump": 21.0, "reference_north_jump": 25.5,
             "reference_up_outliers": 19.0}
    assert glr_max_by_kind(stats) == {"step": 7.5, "ramp": 2.0, "jump": 25.5, "outliers": 19.0}
    d = decision({"verdict": "no_fault", "glr": {"statistic": 25.5, "threshold": 30.0,
                                                 "statistics": stats}})
    assert d["glr_max"]["jump"] == 25.5 and d["statistic"] == 25.5
    assert decision({"verdict": "no_fault"})["glr_max"] == {}


def _rec(i, scenario="gyro_step", axis="x", level=0.05, onset=1000.0, right=True, glr=None):
    iso = ({"verdict": "failure", "isolation": "single", "sensor": "gyro", "axis": axis,
            "kind": "step", "onset_s": onset + 10.0, "magnitude": 1e-7}
           if right else {"verdict": "no_fault", "isolation": "none", "kind": None})
    iso.update(candidates=[], onset_interval_s=None)
    sensor = None if scenario == "nominal" else SCENARIOS[scenario][2]
    return {"index": i, "scenario": scenario, "sensor": sensor, "axis": axis, "level": level,
            "onset_s": onset, "ins3d": {**iso, "glr_max": glr or {}}}


def test_nominal_maxima_against_the_thresholds():
    recs = [_rec(i, "nominal", right=False, glr={"step": s, "ramp": 1.0, "jump": j,
                                                 "outliers": 20.0})
            for i, (s, j) in enumerate([(5.0, 20.0), (9.0, 31.0), (7.0, 33.0)])]
    recs.append(_rec(3))                                           # a faulty flight: ignored
    m = nominal_maxima(recs, thresholds_for("navigation", 7200.0))
    assert m["step"] == {"n": 3, "threshold": pytest.approx(20 + math.log(4)), "max": 9.0,
                         "median": 7.0, "above": 0}
    assert m["jump"]["above"] == 1 and m["jump"]["max"] == 33.0    # 31 < 32.77 < 33
    text = format_nominal_maxima(m)
    assert "| jump | 3 | 31.0 | 33.0 | 32.8 | 1 |" in text


def test_right_rate_per_onset_bin():
    recs = [_rec(0, onset=800.0), _rec(1, onset=900.0, right=False), _rec(2, onset=2500.0),
            _rec(3, axis="z", onset=850.0, level=0.2), _rec(4, onset=6000.0),   # 6000: outside
            _rec(5, "nominal", right=False)]
    rows = by_onset(recs, [720, 1800, 3000])
    assert [(r["axis"], r["bin"], r["n"], r["right"], r["reached"]) for r in rows] == [
        ("x", (720.0, 1800.0), 2, 1, False), ("x", (1800.0, 3000.0), 1, 1, True),
        ("z", (720.0, 1800.0), 1, 1, True)]
    assert [r["axis"] for r in by_onset(recs, [720, 1800, 3000], levels=[0.2])] == ["z"]
    text = format_by_onset(recs, 7200.0, (0.1, 0.25, 0.4))
    assert "| gyro_step | x | all | 1/2 | 1/1 |" in text
    assert "| gyro_step | x | 0.05 | 1/2 | 1/1 |" in text
    assert "| gyro_step | z | 0.05 |" not in text                 # z has no 0.05 flight here


def test_merge_renumbers_in_order():
    a = [{"index": 1, "v": "a1"}, {"index": 0, "v": "a0"}]
    b = [{"index": 0, "v": "b0"}]
    assert merge_records([a, b]) == [{"index": 0, "v": "a0"}, {"index": 1, "v": "a1"},
                                     {"index": 2, "v": "b0"}]


def test_detectable_step_is_sqrt_threshold_times_the_sd():
    t = np.arange(100.0, 200.0, 10.0)
    unit = SCENARIOS["gyro_step"][6]
    curve = SimpleNamespace(t=t, sd=unit * np.linspace(0.1, 1.0, t.size))
    a = SimpleNamespace(thresholds={"step": 16.0}, glr={"gyro_z_step": curve})
    rows = detectable_steps(a, [0.0, 20.0, 1e6], [("gyro_z_step", "gyro_step")])
    assert rows["gyro_z_step"]["unit"] == "deg/h"
    assert rows["gyro_z_step"]["values"] == pytest.approx([0.4, 4 * 0.3, 4.0])


@pytest.mark.slow
def test_a_stopped_study_resumes_from_its_records(tmp_path):
    cfg = Study3DConfig(nominal=1, per_scenario=1, scenarios=("ref_jump",), duration_s=120.0,
                        profile="random", seed=5, single_axis=False)
    path = tmp_path / "r.jsonl"
    full = run_recorded(cfg, path)
    assert full.resumed == 0 and len(full.records) == 2
    lines = path.read_text().splitlines()
    path.write_text("\n".join(lines[:2]) + "\n" + lines[2][:30])  # stopped mid-write
    again = run_recorded(cfg, path)
    assert again.resumed == 1
    assert json.dumps(again.records, sort_keys=True) == json.dumps(full.records, sort_keys=True)


def _write_records(path, recs, study=None):
    """A records file (eval/records.py's form) of hand-made records, both models' fields."""
    with path.open("w") as f:
        f.write(json.dumps({"records": "flight_fdi.study/1",
                            "study": study or {"duration_s": 7200.0}}) + "\n")
        for r in recs:
            f.write(json.dumps({**r, "single_axis": {
                                "verdict": "no_fault", "isolation": "none", "kind": None,
                                "candidates": []},
                                "kind": "step", "magnitude": 1e-7,
                                "onset_in_turn": False, "next_turn_s": None}) + "\n")


def _section(name, body=None):
    """A generated section of the document, ``body`` its old content."""
    return (f"<!-- BEGIN GENERATED {name} -->\n" + (f"{body}\n" if body else "")
            + f"<!-- END GENERATED {name} -->\n")


def _render_only(out, text):
    """The document ``text`` after tools/ins3d_eval.py --render-only from the results in out."""
    doc = out / "doc.md"
    doc.write_text(text)
    subprocess.run([sys.executable, str(REPO / "tools" / "ins3d_eval.py"), "--render-only",
                    "--out", str(out), "--doc", str(doc)], check=True,
                   capture_output=True, timeout=120)
    return doc.read_text()


def test_tool_renders_the_long_sections_from_partial_records(tmp_path):
    """tools/ins3d_eval.py --render-only on records files of an unfinished long study: the
    generated sections say partial and carry the tables; other sections are left alone."""
    nominal = [_rec(i, "nominal", right=False, glr={"step": 5.0, "ramp": 4.0, "jump": 20.0,
                                                    "outliers": 21.0}) for i in range(3)]
    faults = [_rec(0, onset=900.0), _rec(1, axis="y", onset=4000.0, level=0.1)]
    for name, recs in (("nominal_long.jsonl", nominal), ("faults_long_gyro_step.jsonl", faults)):
        _write_records(tmp_path / name, recs)
    text = _render_only(tmp_path, "keep\n" + _section("nominal_long", "old")
                        + _section("faults_long") + "tail\n")
    assert text.startswith("keep\n") and text.endswith("tail\n") and "\nold\n" not in text
    assert "**Partial: 3 flights" in text and "**Partial: 2 flights" in text
    assert "| jump | 3 | 20.0 | 20.0 | 32.8 | 0 |" in text
    assert "| gyro_step | x | all | 1/1 | - | - | - | - |" in text
    assert "| gyro_step | y | all | - | - | - | 1/1 | - |" in text   # 4000 s: 3960-5040


def test_calibration_table_counts_the_long_flights_above_each_rule():
    def row(dur, step, jump, verdict="no_fault"):
        return {"duration_s": dur, "verdict": verdict,
                "max": {"step": step, "ramp": 1.0, "jump": jump, "outliers": 10.0}}

    short = [row(1800.0, s, j) for s, j in ((5.0, 15.0), (7.0, 17.0), (9.0, 19.0))]
    long = [row(7200.0, s, j) for s, j in ((6.0, 18.0), (8.0, 20.0), (21.0, 31.0))]
    long.append(row(7200.0, 10.0, 33.0, "failure"))
    base = {"step": 20.0, "ramp": 20.0, "jump": 30.0, "outliers": 32.0}
    rule = {"step": 21.5, "ramp": 20.0, "jump": 32.8, "outliers": 34.8}
    text = calibration_table(short, long, base, rule,
                             {"step": 1.0, "ramp": 0.0, "jump": 2.0, "outliers": 2.0})
    # medians 7 -> 9 (+2 = 1.44 ln 4); one step above 20, none above 21.5
    assert "| step | 7.0 / 8.6 / 9.0 | 9.0 / " in text
    assert "| +2.0 (1.44) | 1 | 1, 21.5, 0 |" in text
    # jumps 31 and 33 above 30, only 33 above 32.8
    assert "| jump |" in text and "| 2 | 2, 32.8, 1 |" in text
    assert "fixed 2 (50.0 %), rule 1 (25.0 %); verdicts: failure 1, no_fault 3." in text


def test_onset_coverage_table_per_scenario_and_reported_kind():
    def row(scen, kind, onset, iv3, iv6, right=True):
        return {"scenario": scen, "right": right, "reported_kind": kind if right else None,
                "onset_s": onset, "intervals": {"3.84": iv3, "6.0": iv6} if right else None}

    rows = [row("gyro_ramp", "step", 100.0, (110.0, 200.0), (90.0, 210.0)),
            row("gyro_ramp", "step", 300.0, (250.0, 350.0), (240.0, 360.0)),
            row("gyro_ramp", "ramp", 500.0, (480.0, 520.0), (470.0, 530.0)),
            row("gyro_ramp", None, 700.0, None, None, right=False)]
    text = format_onset_coverage(rows, (3.84, 6.0))
    assert "| gyro_ramp | 3/4 | step | 1/2 (95) | 2/2 (120) |" in text
    assert "| gyro_ramp | 3/4 | ramp | 1/1 (40) | 1/1 (60) |" in text


def test_right_rate_split_by_a_turn_after_the_onset():
    recs = [_rec(0), _rec(1, right=False), _rec(2, level=0.1)]
    recs[0]["next_turn_s"], recs[1]["next_turn_s"], recs[2]["next_turn_s"] = 1500.0, None, 2e3
    text = format_by_turn_after(recs + [_rec(3, "nominal", right=False)])
    assert "| gyro_step | x | 0.05 | 1/1 | 0/1 |" in text
    assert "| gyro_step | x | 0.1 | 1/1 | - |" in text


def test_a_profile_study_has_its_own_files_and_sections(tmp_path):
    """Long studies on another profile (``--long-profile cruise_turns``) write
    ``<study>_cruise_turns*`` files: reading the ``random`` study does not pick them up (their
    names begin with its name), and --render-only fills the profile's own sections only."""
    nominal = [_rec(i, "nominal", right=False, glr={"step": 5.0, "ramp": 4.0, "jump": 20.0,
                                                    "outliers": 21.0}) for i in range(2)]
    nominal_ct = [_rec(i, "nominal", right=False, glr={"step": 6.0, "ramp": 4.0, "jump": 22.0,
                                                       "outliers": 21.0}) for i in range(5)]
    faults_ct = [_rec(0, onset=900.0, axis="z")]
    _write_records(tmp_path / "nominal_long.jsonl", nominal)
    _write_records(tmp_path / "nominal_long_cruise_turns.jsonl", nominal_ct)
    _write_records(tmp_path / "faults_long_cruise_turns_gyro_step.jsonl", faults_ct)
    assert [p.name for p in study_files(tmp_path, "nominal_long")] == ["nominal_long.jsonl"]
    assert [p.name for p in study_files(tmp_path, "faults_long")] == []
    assert len(read_study(tmp_path, "nominal_long")[1]) == 2
    assert len(read_study(tmp_path, "nominal_long_cruise_turns")[1]) == 5
    assert len(read_study(tmp_path, "faults_long_cruise_turns")[1]) == 1
    text = _render_only(tmp_path, _section("faults_long", "random faults")
                        + _section("nominal_long_cruise_turns")
                        + _section("faults_long_cruise_turns"))
    assert "\nrandom faults\n" in text                   # no random fault records: kept
    assert "**Partial: 5 flights" in text and "**Partial: 1 flights" in text
    assert "| ins3d | 5 | 0.0 % (0) | 0.0-52.2 % |" in text      # 1 - 0.025 ** (1 / 5)
    assert "| jump | 5 | 22.0 | 22.0 | 32.8 | 0 |" in text
    assert "| gyro_step | z | 1/1 | 10.0 | 10 | - |" in text      # onset error 10 s


def test_onset_error_and_interval_coverage_by_axis():
    recs = [_rec(0, onset=1000.0), _rec(1, onset=2000.0), _rec(2, onset=3000.0, right=False),
            _rec(3, axis="z", onset=1000.0), _rec(4, "nominal", right=False)]
    recs = [{**r, "kind": "step", "magnitude": 1e-7} for r in recs]
    recs[1]["ins3d"]["onset_s"] = 1970.0                             # 30 s early
    recs[0]["ins3d"]["onset_interval_s"] = [990.0, 1030.0]           # holds 1000, width 40
    recs[1]["ins3d"]["onset_interval_s"] = [1950.0, 1990.0]          # misses 2000
    text = format_onset_by_axis(recs)
    # x: right 2 of 3, abs errors 10 and 30: median 20, 90th percentile 28
    assert "| gyro_step | x | 2/3 | 20.0 | 28 | 1/2 (40) |" in text
    assert "| gyro_step | z | 1/1 | 10.0 | 10 | - |" in text
    assert "nominal" not in text and "| gyro_step | y |" not in text


def test_exact_binomial_interval_known_answers():
    assert binomial_interval(0, 200) == (0.0, pytest.approx(1 - 0.025 ** (1 / 200)))
    assert binomial_interval(200, 200) == (pytest.approx(0.025 ** (1 / 200)), 1.0)
    lo, hi = binomial_interval(5, 10)                  # Clopper-Pearson tables: 0.187-0.813
    assert (lo, hi) == (pytest.approx(0.18709, abs=1e-5), pytest.approx(0.81291, abs=1e-5))
    lo, hi = binomial_interval(1, 200)                 # 1 - (1 - p)^200 = 0.025 at the bound
    assert 1 - (1 - lo) ** 200 == pytest.approx(0.025)
    assert (1 - hi) ** 200 + 200 * hi * (1 - hi) ** 199 == pytest.approx(0.025)
    assert binomial_interval(0, 0) is None
    with pytest.raises(ValueError):
        binomial_interval(3, 2)


@pytest.mark.slow
def test_tool_runs_a_long_study_on_the_cruise_turns_profile(tmp_path):
    """tools/ins3d_eval.py --only nominal_long --long-profile cruise_turns: 2 short flights of
    that profile, recorded and rendered under the profile's names with the load it ran under."""
    doc = tmp_path / "doc.md"
    doc.write_text(_section("nominal_long", "random") + _section("nominal_long_cruise_turns"))
    subprocess.run([sys.executable, str(REPO / "tools" / "ins3d_eval.py"), "--only",
                    "nominal_long", "--long-profile", "cruise_turns", "--long-nominal", "2",
                    "--long-duration", "120", "--seed", "100", "--jobs", "1", "--out",
                    str(tmp_path), "--doc", str(doc)], check=True, capture_output=True,
                   timeout=600)
    res = json.loads((tmp_path / "nominal_long_cruise_turns.json").read_text())
    assert res["config"]["profile"] == "cruise_turns" and res["config"]["seed"] == 106
    assert len(res["flights"]) == 2 and not (tmp_path / "nominal_long.json").exists()
    lo, hi = res["load_average"]
    assert 0.0 <= lo <= hi
    text = doc.read_text()
    assert "\nrandom\n" in text
    assert "Settings: 2 flights of 120 s, profile `cruise_turns`, grade navigation, seed 106" \
        in text and f"load average {lo:.1f}-{hi:.1f}" in text


def test_load_sampler_reports_the_range_of_its_samples():
    sampler = LoadSampler(every_s=3600.0)
    lo, hi = sampler.stop()            # the thread's first sample, then the last one at stop
    assert len(sampler.samples) == 2 and [lo, hi] == [min(sampler.samples), max(sampler.samples)]
    assert 0.0 <= lo <= hi


def test_nominal_maxima_per_hypothesis_against_its_own_threshold():
    from flight_fdi.eval.long3d import nominal_maxima_by_hypothesis

    thr = {"step": 21.4, "ramp": 20.0, "jump": 32.8, "outliers": 34.8, "gyro_z_step": 16.0}
    stats = [{"gyro_z_step": z, "gyro_x_step": x, "reference_east_jump": j,
              "reference_east_outliers": 40.0} for z, x, j in
             ((3.0, 5.0, 20.0), (17.0, 22.0, 30.0), (9.0, 4.0, 33.0))]
    recs = [{**_rec(i, "nominal", right=False), "ins3d": {"glr_statistics": s}}
            for i, s in enumerate(stats)]
    recs.append(_rec(3))                                          # a faulty flight: ignored
    m = nominal_maxima_by_hypothesis(recs, thr)
    assert "reference_east_outliers" not in m                     # outliers: per kind
    assert m["gyro_z_step"] == {"n": 3, "threshold": 16.0, "max": 17.0, "median": 9.0,
                                "above": 1}
    assert m["gyro_x_step"]["threshold"] == 21.4 and m["gyro_x_step"]["above"] == 1
    assert m["reference_east_jump"]["above"] == 1
    text = format_nominal_maxima(m, "hypothesis")
    assert "| gyro_z_step | 3 | 9.0 | 17.0 | 16.0 | 1 |" in text and "(its own)" in text
    assert nominal_maxima_by_hypothesis([_rec(0, "nominal", right=False)], thr) == {}


def test_hypothesis_calibration_table_counts_the_long_flights_above_own_and_kind():
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS, threshold_of, thresholds_for
    from flight_fdi.core.ins3d.glr3d import hypotheses
    from flight_fdi.eval.long3d import hypothesis_calibration_table

    def row(dur, z):
        return {"duration_s": dur, "max_by_hypothesis": {
            h: (z if h == "gyro_z_step" else 1.0) for h in PER_HYPOTHESIS}}

    short = [row(1800.0, z) for z in (2.0, 3.0, 4.0)]
    long = [row(7200.0, z) for z in (3.0, 20.9, 30.0)]
    kinds = {"step": 20.0, "ramp": 20.0, "jump": 30.0, "outliers": 32.0}
    text = hypothesis_calibration_table(short, long, kinds)
    gz = next(h for h in hypotheses(3) if h.name == "gyro_z_step")
    own = threshold_of(thresholds_for("navigation", 7200.0), gz)
    above = sum(z > own for z in (3.0, 20.9, 30.0))
    line = next(x for x in text.splitlines() if x.startswith("| gyro_z_step |"))
    assert "| 3.0 / 3.8 / 4.0 | 20.9 / 28.2 / 30.0 |" in line   # median / 90 % / largest
    assert above == 2 and line.endswith("| 2 (1) |")   # own 20.6: 20.9 and 30; kind's 21.39: 30
    assert len(text.splitlines()) == 2 + len(PER_HYPOTHESIS)
