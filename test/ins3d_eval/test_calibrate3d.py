"""The threshold calibration of a grade (flight_fdi/eval/calibrate3d.py): the tail rule on maxima
of known distributions, the length rule both ways, the rates, the grade file written back, and
one nominal flight's maxima against the post_flight section's."""
from __future__ import annotations

import math

import numpy as np
import pytest

from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.glr3d import CALIBRATED_LENGTH_S, thresholds_for
from flight_fdi.core.ins3d.grade_file import (KINDS, grade_from_dict, load_grade,
                                              with_thresholds)
from flight_fdi.core.ins3d.grades import GRADES
from flight_fdi.eval.calibrate3d import (DEFAULT_EPISODE_PROBABILITY, MIN_FLIGHTS,
                                         bootstrap_spread, calibrate, calibrate_seed,
                                         check_rates, exceeded, length_shift, nominal_flight,
                                         plan, rate, seed_declared, tail_threshold)
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.metrics3d import binomial_interval


def _gumbel_rows(n: int, seed: int, scale: float = 2.0, duration: float = 1800.0,
                 loc: dict | None = None) -> list[dict]:
    """Flights whose maxima per kind are Gumbel(loc, scale): P(M > x) ~ exp(-(x - loc) / scale)
    in the tail, the (1 - p) quantile loc - scale ln(-ln(1 - p))."""
    rng = np.random.default_rng(seed)
    loc = loc or {"step": 8.0, "ramp": 5.0, "jump": 18.0, "outliers": 19.0}
    return [{"duration_s": duration, "seed": i,
             "max": {k: float(rng.gumbel(loc[k], scale)) for k in KINDS}} for i in range(n)]


def _gumbel_quantile(loc: float, scale: float, p: float) -> float:
    return loc - scale * math.log(-math.log(1.0 - p))


def test_tail_threshold_extrapolates_a_chi2_like_tail():
    """Gumbel(8, 2) maxima: the 0.25 % quantile (20.0) from 200 flights, the tail extrapolated
    from the 20 largest; over 40 independent samples the mean is 0-1 above it (the floor of
    the tail scale at 2 makes the rule conservative: ~+0.7, a rate ~0.7 x the target) and the
    sd ~1."""
    p, est = 0.0025, []
    for s in range(40):
        m = np.random.default_rng(s).gumbel(8.0, 2.0, 200)
        est.append(tail_threshold(m, p))
    truth = _gumbel_quantile(8.0, 2.0, p)
    assert 0.0 < np.mean(est) - truth < 1.0, (np.mean(est), truth)
    assert 0.3 < np.std(est) < 2.0


def test_a_fatter_tail_raises_the_scale_and_enough_flights_use_the_quantile():
    m = np.random.default_rng(1).gumbel(8.0, 5.0, 400)    # scale 5 > 2: measured, not the floor
    est = tail_threshold(m, 0.0025)
    assert abs(est - _gumbel_quantile(8.0, 5.0, 0.0025)) < 5.0
    assert est > _gumbel_quantile(8.0, 2.0, 0.0025) + 5.0
    m = np.random.default_rng(2).gumbel(8.0, 2.0, 4000)   # n p = 10: the empirical quantile
    assert tail_threshold(m, 0.0025) == pytest.approx(np.quantile(m, 0.9975))
    with pytest.raises(EvalError, match=f"at least {MIN_FLIGHTS} flights"):
        tail_threshold(m[:MIN_FLIGHTS - 1], 0.01)


def test_calibrate_splits_the_target_over_the_kinds_and_moves_to_30_min():
    rows = _gumbel_rows(4000, 3)
    thr = calibrate(rows, 0.01)
    for k in KINDS:
        m = np.array([r["max"][k] for r in rows])
        assert thr[k] == pytest.approx(np.quantile(m, 1 - 0.01 / 4), abs=0.01)
    # flights of 2 h: moved down by c ln 4 (steps 1, ramps 0, jumps and outliers 2)
    long = [{**r, "duration_s": 4 * CALIBRATED_LENGTH_S} for r in rows]
    shifted = calibrate(long, 0.01)
    assert shifted["ramp"] == thr["ramp"]
    assert shifted["step"] == pytest.approx(thr["step"] - math.log(4), abs=0.011)
    assert shifted["jump"] == pytest.approx(thr["jump"] - 2 * math.log(4), abs=0.011)
    assert length_shift(900.0)["outliers"] == pytest.approx(2 * math.log(2))   # up when shorter
    with pytest.raises(EvalError, match="target"):
        calibrate(rows, 0.0)


def test_exceeded_and_the_achieved_rate_on_held_out_flights():
    """Calibrated on 300 flights for 10 %: on 3000 fresh flights of the same distribution the
    rate of flights above some threshold is near 10 % (the union bound: at most)."""
    thr = calibrate(_gumbel_rows(300, 4), 0.10)
    fresh = _gumbel_rows(3000, 5)
    k = exceeded(fresh, thr)
    assert 0.05 < k / 3000 < 0.13, k
    r = rate(k, 3000)
    assert r["interval95"] == list(binomial_interval(k, 3000)) and r["rate"] == k / 3000
    # a 2-h flight is judged against the thresholds raised for its length
    row = {"duration_s": 7200.0, "max": {"step": thr["step"] + 1.0, "ramp": 0.0, "jump": 0.0,
                                         "outliers": 0.0}}
    assert exceeded([row], thr) == 0          # + 1.39 for a step on a 2-h flight


def test_bootstrap_spread_matches_the_spread_over_independent_calibrations():
    rows = _gumbel_rows(200, 6)
    boot = bootstrap_spread(rows, 0.01, draws=150, seed=1)
    indep = [calibrate(_gumbel_rows(200, 100 + s), 0.01) for s in range(40)]
    for k in KINDS:
        sd = float(np.std([t[k] for t in indep], ddof=1))
        assert 0.4 * sd < boot[k] < 2.5 * sd, (k, boot[k], sd)


def test_check_rates_count_single_isolations_and_declarations():
    rows = [{"checks": {"a": {"isolation": iso}}} for iso in
            ("none", "single", "ambiguous", "none", "single")]
    r = check_rates(rows)["a"]
    assert r["false_isolation"]["k"] == 2 and r["declared"]["k"] == 3
    assert r["false_isolation"]["n"] == 5


GRADE = """\
# my IMU: a comment the calibration keeps
name: my_imu
base: navigation
gyro_bias_deg_h: 0.01        # twice the preset's
thresholds:
  step: 25
  ramp: 21
accel_bias_ug: 40
"""
META = {"date": "2026-11-24", "tool": "flight-fdi calibrate", "flights": 200,
        "seeds": [1000, 1199], "duration_s": 1800.0, "profiles": ["cruise_turns", "random"],
        "target": 0.01, "exceeded": 1, "rate": 0.005, "interval95": [0.0001, 0.0275],
        "spread": {"step": 0.9, "ramp": 1.0, "jump": 0.8, "outliers": 0.7}}


def test_with_thresholds_replaces_the_block_and_keeps_the_rest(tmp_path):
    new = {"step": 21.5, "ramp": 19.25, "jump": 31.0, "outliers": 33.125}
    text = with_thresholds(GRADE, new, META)
    assert "# my IMU: a comment the calibration keeps" in text and "twice the preset's" in text
    assert "1 of 200 flights above a threshold (0.5 %, 95 % interval 0.0-2.8 %)" in text
    path = tmp_path / "g.yaml"
    path.write_text(text)
    g = load_grade(path)
    assert dict(g.thresholds) == {"step": 21.5, "ramp": 19.25, "jump": 31.0, "outliers": 33.12}
    before = load_grade_text(GRADE, tmp_path)
    assert {k: v for k, v in g.numbers().items() if not k.startswith("threshold")} == \
        {k: v for k, v in before.numbers().items() if not k.startswith("threshold")}
    again = with_thresholds(text, {k: v + 1 for k, v in new.items()}, {**META, "flights": 50})
    assert again.count("thresholds:") == 1 and again.count("calibration:") == 1
    assert again.count("# GLR thresholds calibrated") == 1 and "accel_bias_ug: 40" in again
    import yaml

    assert yaml.safe_load(again)["calibration"]["flights"] == 50


def load_grade_text(text: str, tmp_path):
    p = tmp_path / "before.yaml"
    p.write_text(text)
    return load_grade(p)


def test_a_calibration_record_must_be_a_mapping():
    with pytest.raises(CoreError, match="calibration must be a mapping"):
        grade_from_dict({"name": "a", "base": "navigation", "calibration": 3})


def test_nominal_flight_maxima_are_the_post_flight_statistics_and_seeded():
    """One 60-s flight: the maxima per kind equal the post_flight section's GLR statistics
    (montecarlo3d.glr_max_by_kind, another path), the same seed gives the same numbers, the
    navigation preset written as a file the same flight; a check's isolation is recorded."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.eval.montecarlo3d import glr_max_by_kind
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    nav = thresholds_for("navigation")
    low = {k: 0.0 for k in KINDS}
    f = plan(GRADES["navigation"], 1, 77, ("cruise_turns",), 60.0,
             checks={"nav": nav, "low": low})[0]
    r = nominal_flight(f)
    assert r["seed"] == 77 and r["checks"]["low"]["isolation"] != "none"
    inp = from_flight(simulate3d(Sim3DConfig(TrajectoryConfig(
        profile="cruise_turns", duration_s=60.0, rate_hz=100.0, seed=77), grade="navigation",
        seed=77)))
    post = analyze_ins3d(inp.steps, inp.refs, grade="navigation", with_observability=False,
                         **inp.vertical()).post_flight_dict()
    assert r["max"] == pytest.approx(glr_max_by_kind(post["glr"]["statistics"]), rel=1e-9)
    assert r["checks"]["nav"]["isolation"] == post.get("isolation", "none")   # its thresholds
    assert nominal_flight(f)["max"] == r["max"]
    file_grade = grade_from_dict({"name": "nav_file", "base": "navigation"})
    g = nominal_flight(plan(file_grade, 1, 77, ("cruise_turns",), 60.0)[0])
    assert g["max"] == pytest.approx(r["max"], rel=1e-9) and g["grade"] == "nav_file"


def test_plan_checks_its_settings():
    g = GRADES["navigation"]
    assert [f.seed for f in plan(g, 3, 10)] == [10, 11, 12]
    assert [f.profile for f in plan(g, 4, 0, ("random", "straight"))] == \
        ["random", "straight", "random", "straight"]
    for kw, msg in (({"profiles": ("loop",)}, "unknown profile 'loop'"),
                    ({"seed": -1}, "seed must be"), ({"duration_s": 10.0}, "60..10800")):
        with pytest.raises(EvalError, match=msg):
            plan(g, 2, **{"seed": 0, **kw})


def test_writing_a_calibrated_file_again_with_its_own_record_changes_nothing():
    from pathlib import Path

    import yaml

    path = Path(__file__).resolve().parents[2] / "config/grades/example_nav_noisy.yaml"
    text = path.read_text()
    doc = yaml.safe_load(text)
    assert with_thresholds(text, doc["thresholds"], doc["calibration"],
                           doc.get("seed_episode_probability")) == text
    assert doc["calibration"]["flights"] >= 200 and doc["thresholds"]["step"] > 20.0


def test_the_tools_held_out_check(tmp_path):
    """tools/ins3d_calibrate.py --check: per flight the isolation of the grade file's thresholds
    and of its base preset's, and the rates; its JSON holds the rows (tools/ins3d_eval.py)."""
    import json
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    out = tmp_path / "check.json"
    low = tmp_path / "low.yaml"
    low.write_text("name: low\nbase: navigation\nthresholds: {step: 0.1, ramp: 0.1, jump: 0.1, "
                   "outliers: 0.1}\n")
    run = subprocess.run([sys.executable, str(repo / "tools" / "ins3d_calibrate.py"), "--grade",
                          str(low), "--check", "--flights", "2", "--duration", "60", "--seed0",
                          "40", "--out", str(out)], capture_output=True, text=True, timeout=300,
                         cwd=repo)
    assert run.returncode == 0, run.stderr
    rows = json.loads(out.read_text())
    assert [r["seed"] for r in rows] == [40, 41]
    assert all(r["checks"]["grade"]["isolation"] != "none" for r in rows)   # thresholds 0.1
    assert "grade thresholds {'step': 0.1" in run.stdout
    assert f"base thresholds {thresholds_for('navigation')}" in run.stdout
    assert "false isolation" in run.stdout and "2/2 = 100.0 %" in run.stdout


def _seed_rows(n: int, seed: int, quiet: float = 0.6, loc: float = 40.0) -> list[dict]:
    """Flights of which a fraction ``quiet`` has no persistent J episode (x = 0), the others a
    peak with x = loc + 2 Exp(1) (a chi^2-like tail shifted by model mismatch)."""
    rng = np.random.default_rng(seed)
    return [{"seed_x": 0.0 if rng.random() < quiet else float(loc + rng.exponential(2.0))}
            for _ in range(n)]


def test_calibrate_seed_keeps_the_declarations_within_the_target():
    """The episode probability p the rule picks: on the calibration flights at most the target
    declared; on 4000 fresh flights of the same law about the target (the tail rule is
    conservative: below 1.3 x); never above the default; a quiet grade keeps the default."""
    rows = _seed_rows(200, 1)
    p = calibrate_seed(rows, 0.02)
    assert p < DEFAULT_EPISODE_PROBABILITY
    assert seed_declared(rows, DEFAULT_EPISODE_PROBABILITY) > 60       # x > 27.6: all loud ones
    assert seed_declared(rows, p) <= 0.02 * 200
    fresh = _seed_rows(4000, 2)
    assert seed_declared(fresh, p) / 4000 < 1.3 * 0.02
    assert calibrate_seed(_seed_rows(200, 3, loc=5.0), 0.02) == DEFAULT_EPISODE_PROBABILITY
    x = -2.0 * math.log(p)                                 # declared iff x > -2 ln p
    assert seed_declared([{"seed_x": x * 1.001}, {"seed_x": x * 0.999}], p) == 1
    with pytest.raises(EvalError, match="seed-method target"):
        calibrate_seed(rows, 1.0)


def test_with_thresholds_writes_the_seed_episode_probability(tmp_path):
    new = {"step": 21.5, "ramp": 19.25, "jump": 31.0, "outliers": 33.125}
    meta = {**META, "seed": {"declared": 2, "default": 1e-06, "declared_default": 57}}
    text = with_thresholds(GRADE, new, meta, 3.4567e-21)
    assert "seed_episode_probability: 3.457e-21" in text
    assert "2 of 200 flights declared (with the default 1e-06: 57)" in text
    path = tmp_path / "g.yaml"
    path.write_text(text)
    assert load_grade(path).episode_probability == 3.457e-21
    again = with_thresholds(text, new, meta, 1e-7)
    assert again.count("seed_episode_probability:") == 1 and "1.000e-07" in again
    assert "seed_episode_probability" not in with_thresholds(again, new, META)


def test_the_seed_statistic_is_where_the_seed_method_starts_declaring():
    """One 180-s flight of the noisy example grade with a persistent J episode: x of its row is
    exactly the boundary -- the seed method declares with episode probability exp(-x/2) x 1.001
    and not with exp(-x/2) x 0.999; its recorded verdict (the default 1e-6) agrees with x."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.diagnosis import DiagnosisConfig
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.core.ins3d.postflight import seed_method
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    from pathlib import Path

    g = load_grade(Path(__file__).resolve().parents[2] / "config/grades/example_nav_noisy.yaml")
    f = plan(g, 1, 502, ("cruise_turns",), 180.0)[0]
    r = nominal_flight(f)
    assert r["seed_x"] > 1.0
    assert (r["seed_verdict"] != "no_fault") == (seed_declared([r], 1e-6) == 1)
    inp = from_flight(simulate3d(Sim3DConfig(TrajectoryConfig(
        profile="cruise_turns", duration_s=180.0, rate_hz=100.0, seed=502), grade=g, seed=502)))
    a = analyze_ins3d(inp.steps, inp.refs, grade=g, with_observability=False, **inp.vertical())
    p = math.exp(-0.5 * r["seed_x"])
    verdicts = [seed_method(a.model, a.backward, DiagnosisConfig(episode_probability=q)).verdict
                for q in (1.001 * p, 0.999 * p)]
    assert verdicts[0] != "no_fault" and verdicts[1] == "no_fault"
    quiet = nominal_flight(plan(g, 1, 500, ("cruise_turns",), 180.0)[0])   # no episode
    assert quiet["seed_x"] == 0.0 and quiet["seed_verdict"] == "no_fault"


def _hyp_rows(n: int, seed: int, scale: dict, duration: float = 1800.0,
              shift: dict | None = None) -> list[dict]:
    """Flights whose maximum per hypothesis is exponential with the given scale (tail
    P(M > x) = exp(-x / scale): the quantile at p is scale ln(1 / p)), plus ``shift``."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS

    rng = np.random.default_rng(seed)
    shift = shift or {}
    return [{"duration_s": duration, "seed": i,
             "max_by_hypothesis": {h: float(rng.exponential(scale.get(h, 2.0)))
                                   + shift.get(h, 0.0) for h in PER_HYPOTHESIS}}
            for i in range(n)]


def test_calibrate_hypotheses_gives_each_an_equal_share_of_the_budget():
    """Exponential maxima (scale 2, gyro z 3): each threshold is the quantile at
    p = 0.75 x 1 % / 15 (the outliers keep their kind's quarter), scale x ln(1 / p), within
    the tail rule's sampling error; mixed lengths pooled after each hypothesis' own shift."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS
    from flight_fdi.eval.calibrate3d import OUTLIER_SHARE, calibrate_hypotheses

    p = (1 - OUTLIER_SHARE) * 0.01 / len(PER_HYPOTHESIS)
    assert p == pytest.approx(5e-4)
    scale = {"gyro_z_step": 3.0}
    rows = _hyp_rows(3000, 4, scale)
    thr = calibrate_hypotheses(rows, 0.01, growth={h: 0.0 for h in PER_HYPOTHESIS})
    assert set(thr) == set(PER_HYPOTHESIS)
    for h in PER_HYPOTHESIS:
        truth = scale.get(h, 2.0) * math.log(1 / p)          # 15.2 (22.8 for gyro z)
        assert abs(thr[h] - truth) < 0.1 * truth, (h, thr[h], truth)
    # 2-h flights whose maxima are the 30-min ones + c ln 4 (c = 1.5 for gyro z, 0 else):
    # moved back by their own growth, pooled, the same thresholds
    ln4 = math.log(4.0)
    long = _hyp_rows(3000, 5, scale, 4 * CALIBRATED_LENGTH_S, {"gyro_z_step": 1.5 * ln4})
    growth = {h: 0.0 for h in PER_HYPOTHESIS} | {"gyro_z_step": 1.5}
    pooled = calibrate_hypotheses(rows + long, 0.01, growth)
    for h in PER_HYPOTHESIS:
        assert abs(pooled[h] - thr[h]) < 0.08 * thr[h], (h, pooled[h], thr[h])
    naive = calibrate_hypotheses(rows + long, 0.01, {h: 0.0 for h in PER_HYPOTHESIS})
    assert naive["gyro_z_step"] > pooled["gyro_z_step"] + 1.0      # unshifted: too high


def test_hypothesis_growth_is_the_median_growth_per_ln_length_never_below_zero():
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS
    from flight_fdi.eval.calibrate3d import exceeded_hypotheses, hypothesis_growth

    short = _hyp_rows(401, 6, {})
    med = {h: float(np.median([r["max_by_hypothesis"][h] for r in short]))
           for h in PER_HYPOTHESIS}
    ln4 = math.log(4.0)
    long = [{**r, "duration_s": 7200.0, "max_by_hypothesis": {
        h: v + (1.5 * ln4 if h == "gyro_z_step" else -1.0 if h == "gyro_x_ramp" else 0.0)
        for h, v in r["max_by_hypothesis"].items()}} for r in short]
    c = hypothesis_growth(short, long)
    assert c["gyro_z_step"] == pytest.approx(1.5)
    assert c["gyro_x_ramp"] == 0.0                           # a fall is not a growth
    assert c["gyro_x_step"] == pytest.approx(0.0, abs=1e-12)
    assert med["gyro_z_step"] > 0
    with pytest.raises(EvalError, match="longer"):
        hypothesis_growth(long, short)
    # flights above a threshold: the hypothesis' own, else its kind's, at the flight's length
    thr = {"step": 100.0, "ramp": 100.0, "jump": 100.0, "outliers": 100.0, "gyro_z_step": 8.0}
    z = np.array([r["max_by_hypothesis"]["gyro_z_step"] for r in short])
    assert exceeded_hypotheses(short, thr) == int(np.sum(z > 8.0))
    z_long = z + 1.5 * ln4
    from flight_fdi.core.ins3d.glr3d import growth_of
    assert exceeded_hypotheses(long, thr) == int(np.sum(
        z_long > 8.0 + growth_of("gyro_z_step") * ln4))


def test_a_per_hypothesis_calibration_is_written_as_a_block_and_read_back(tmp_path):
    """calibrate_grade on flights with both records: the kinds' (calibrate) and the
    hypotheses' (calibrate_hypotheses) thresholds; written as a block, loaded back the same
    values, and writing the file again with its own record changes nothing; the bootstrap
    spread has one entry per threshold."""
    import yaml

    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS
    from flight_fdi.eval.calibrate3d import calibrate_grade, calibrate_hypotheses

    rows = [{**a, **b} for a, b in zip(_gumbel_rows(200, 8), _hyp_rows(200, 9, {}))]
    thr = calibrate_grade(rows, 0.01)
    assert thr == {**calibrate(rows, 0.01), **calibrate_hypotheses(rows, 0.01)}
    assert calibrate_grade(rows, 0.01, per_hypothesis=False) == calibrate(rows, 0.01)
    meta = {**META, "rule": "per_hypothesis", "shares": {"outliers": 0.0025,
                                                         "hypothesis": 0.0005}}
    text = with_thresholds(GRADE, thr, meta, 2e-8)
    assert "\nthresholds:\n  step: " in text and "\n  gyro_z_step: " in text
    assert "# calibration rule: per hypothesis, 0.05 % of flights each, outliers 0.25 %" in text
    path = tmp_path / "g.yaml"
    path.write_text(text)
    assert dict(load_grade(path).thresholds) == pytest.approx(thr, abs=0.005)
    doc = yaml.safe_load(text)
    assert with_thresholds(text, doc["thresholds"], doc["calibration"],
                           doc["seed_episode_probability"]) == text
    spread = bootstrap_spread(rows, 0.01, draws=20, seed=3, per_hypothesis=True)
    assert set(spread) == {*KINDS, *PER_HYPOTHESIS} and all(v > 0 for v in spread.values())


def test_calibrated_at_another_length_the_analysis_gets_back_that_lengths_cut():
    """Flights of 2 h: the file holds the 30-min value (the maxima moved by -c ln 4, c the
    hypothesis' growth, glr3d.growth_of); a 2-h analysis raises it by the same c ln 4, i.e.
    uses the tail cut of the 2-h maxima themselves (grade_file.grade_thresholds)."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS, growth_of
    from flight_fdi.core.ins3d.grade_file import grade_thresholds
    from flight_fdi.eval.calibrate3d import OUTLIER_SHARE, calibrate_grade

    long = [{**a, **b} for a, b in zip(_gumbel_rows(200, 10, duration=7200.0),
                                       _hyp_rows(200, 11, {}, 7200.0))]
    thr = calibrate_grade(long, 0.01)
    g = grade_from_dict({"name": "long", "base": "tactical", "thresholds": thr})
    at_2h = grade_thresholds(g, 7200.0)
    p = (1 - OUTLIER_SHARE) * 0.01 / len(PER_HYPOTHESIS)
    for h in ("gyro_z_step", "reference_east_jump", "accelerometer_x_ramp"):
        cut = tail_threshold(np.array([r["max_by_hypothesis"][h] for r in long]), p)
        assert at_2h[h] == pytest.approx(cut, abs=0.006)
        assert thr[h] == pytest.approx(cut - growth_of(h) * math.log(4.0), abs=0.006)


def test_a_check_keeps_its_per_hypothesis_thresholds():
    """plan(checks=...) keeps a set's per-hypothesis thresholds (tools/ins3d_calibrate.py
    --check on a per-hypothesis file): kinds out of reach and one hypothesis at 0 -- that
    hypothesis is what the check isolates; without it nothing is."""
    high = {k: 1e6 for k in KINDS}
    f = plan(GRADES["navigation"], 1, 77, ("cruise_turns",), 60.0,
             checks={"kinds": high, "own": {**high, "gyro_y_ramp": 0.0}})[0]
    assert dict(f.checks)["own"][-1] == ("gyro_y_ramp", 0.0)
    r = nominal_flight(f)
    assert r["checks"]["kinds"]["isolation"] == "none"
    assert r["checks"]["own"]["isolation"] != "none"
    assert r["checks"]["own"]["best"] == "gyro_y_ramp"
