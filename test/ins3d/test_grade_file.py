"""IMU grades from a YAML file (core/ins3d/grade_file.py): the navigation preset written in
engineering units loads equal to the preset; bad files are refused naming the key; the analysis
takes a file and uses its numbers and thresholds."""
from __future__ import annotations

import math
from dataclasses import fields
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.errors import CoreError
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d.glr3d import thresholds_for
from flight_fdi.core.diagnosis import DiagnosisConfig
from flight_fdi.core.ins3d.grade_file import (CustomGrade, diagnosis_config_of, grade_thresholds,
                                              load_grade, resolve_grade)
from flight_fdi.core.ins3d.grades import GRADES, ImuGrade

from .conftest import flight

REPO = Path(__file__).resolve().parents[2]

#: the navigation preset (grades.py) in the file's engineering units, written out by hand
NAVIGATION = """\
name: navigation
base: tactical            # every value below overrides the base's
gyro_bias_deg_h: 0.005
gyro_instability_deg_h: 0.003
gyro_tau_s: 3600
gyro_arw_deg_rth: 0.002
gyro_scale_ppm: 5
gyro_misalign_mrad: 0.01
gyro_quantum_rad: 1.0e-7
accel_bias_ug: 30
accel_instability_ug: 10
accel_tau_s: 3600
accel_vrw_mps_rth: 0.01
accel_scale_ppm: 50
accel_misalign_mrad: 0.02
accel_quantum_mps: 1e-4   # no dot: PyYAML reads a string, taken as the number
heading_sigma_deg: 0
thresholds: {step: 20, ramp: 20, jump: 30, outliers: 32,
  accelerometer_x_step: 19.7, accelerometer_x_ramp: 17.1, accelerometer_y_step: 25.5,
  accelerometer_y_ramp: 20.5, accelerometer_z_step: 19.3, accelerometer_z_ramp: 16.8,
  gyro_x_step: 21.6, gyro_x_ramp: 21.6, gyro_y_step: 20.6, gyro_y_ramp: 16.8,
  gyro_z_step: 20.6, gyro_z_ramp: 22.0, reference_east_jump: 32.3,
  reference_north_jump: 30.3, reference_up_jump: 30.2}
"""


def _write(tmp_path: Path, text: str, name: str = "g.yaml") -> Path:
    p = tmp_path / name
    p.write_text(text)
    return p


def _assert_grade_equal(a: ImuGrade, b: ImuGrade, rel: float = 1e-15) -> None:
    for f in fields(ImuGrade):
        va, vb = getattr(a, f.name), getattr(b, f.name)
        if f.name == "name":
            assert va == vb
        else:
            assert math.isclose(va, vb, rel_tol=rel, abs_tol=0.0), (f.name, va, vb)


def test_navigation_in_engineering_units_equals_the_preset(tmp_path):
    g = load_grade(_write(tmp_path, NAVIGATION))
    assert isinstance(g, CustomGrade)
    _assert_grade_equal(g, GRADES["navigation"])
    assert dict(g.thresholds) == thresholds_for("navigation")
    for d in (None, 600.0, 7200.0):       # the same length growth as the preset's
        got, want = grade_thresholds(g, d), thresholds_for("navigation", d)
        assert got.keys() == want.keys()
        assert all(math.isclose(got[k], want[k], rel_tol=1e-14) for k in want)


def test_unspecified_values_and_thresholds_come_from_the_base(tmp_path):
    g = load_grade(_write(tmp_path, "name: half\nbase: tactical\ngyro_bias_deg_h: 0.5\n"
                                    "thresholds: {ramp: 40}\n"))
    base = GRADES["tactical"]
    assert g.name == "half" and g.gyro_bias == pytest.approx(0.5 * math.pi / 180 / 3600, 1e-15)
    for f in fields(ImuGrade):
        if f.name not in ("name", "gyro_bias"):
            assert getattr(g, f.name) == getattr(base, f.name)
    assert dict(g.thresholds) == {**thresholds_for("tactical"), "ramp": 40.0}
    # ramps do not grow with the length, jumps do
    assert grade_thresholds(g, 7200.0)["ramp"] == 40.0
    assert grade_thresholds(g, 7200.0)["jump"] == pytest.approx(
        thresholds_for("tactical", 7200.0)["jump"], rel=1e-14)


def test_the_example_file_loads():
    g = load_grade(REPO / "config/grades/example_mems_custom.yaml")
    assert g.name == "example_mems_custom"
    assert g.accel_bias == pytest.approx(1000e-6 * 9.80665, rel=1e-15)
    assert dict(g.thresholds)["step"] == 25.0


@pytest.mark.parametrize("text, key", [
    ("name: a\nbase: mems\ngyro_bias: 1\n", "'gyro_bias'"),
    ("name: a\nbase: mems\ngyro_bias_deg_h: fast\n", "gyro_bias_deg_h"),
    ("name: a\nbase: mems\ngyro_bias_deg_h: [1]\n", "gyro_bias_deg_h"),
    ("name: a\nbase: mems\naccel_bias_ug: true\n", "accel_bias_ug"),
    ("name: a\nbase: mems\naccel_bias_ug: -1\n", "accel_bias_ug"),
    ("name: a\nbase: mems\naccel_bias_ug: .nan\n", "accel_bias_ug"),
    ("name: a\nbase: mems\naccel_bias_ug: .inf\n", "accel_bias_ug"),
    ("name: a\nbase: mems\ngyro_tau_s: 0\n", "gyro_tau_s"),
    ("name: a\nbase: consumer\n", "base"),
    ("name: a\n", "base"),
    ("base: mems\n", "name"),
    ("name: a/b\nbase: mems\n", "name"),
    ("name: a\nbase: mems\nthresholds: {slope: 3}\n", "thresholds.slope"),
    ("name: a\nbase: mems\nthresholds: {step: -3}\n", "thresholds.step"),
    ("name: a\nbase: mems\nthresholds: 20\n", "thresholds"),
    ("- 1\n- 2\n", "mapping"),
    ("name: [\n", "not valid YAML (line"),
    ("name: a\nbase: mems\nseed_episode_probability: 0\n", "seed_episode_probability"),
    ("name: a\nbase: mems\nseed_episode_probability: 1\n", "seed_episode_probability"),
    ("name: a\nbase: mems\nseed_episode_probability: -1e-9\n", "seed_episode_probability"),
    ("name: a\nbase: mems\nseed_episode_probability: often\n", "seed_episode_probability"),
    ("name: a\nbase: mems\nseed_episode_probability: true\n", "seed_episode_probability"),
])
def test_a_bad_file_is_refused_naming_the_key(tmp_path, text, key):
    path = _write(tmp_path, text)
    with pytest.raises(CoreError) as exc:
        load_grade(path)
    msg = str(exc.value)
    assert key in msg and str(path) in msg and "\n" not in msg


def test_resolve_grade(tmp_path):
    assert resolve_grade("tactical") is GRADES["tactical"]
    assert resolve_grade(GRADES["mems"]) is GRADES["mems"]
    g = load_grade(_write(tmp_path, NAVIGATION))
    assert resolve_grade(str(tmp_path / "g.yaml")) == g
    with pytest.raises(CoreError, match="unknown IMU grade 'consumer'"):
        resolve_grade("consumer")
    with pytest.raises(CoreError, match="cannot read"):
        resolve_grade(str(tmp_path / "missing.yaml"))


def test_recording_numbers_round_trip(tmp_path):
    g = load_grade(REPO / "config/grades/example_mems_custom.yaml")
    assert CustomGrade.from_numbers(g.name, g.numbers()) == g
    nums = g.numbers()
    del nums["threshold_jump"]
    with pytest.raises(CoreError, match="threshold_jump"):
        CustomGrade.from_numbers(g.name, nums)


def test_the_analysis_takes_a_grade_file(tmp_path):
    """The navigation file gives the preset's analysis (same filter, same thresholds); a file
    with other thresholds changes only the thresholds."""
    inp = from_flight(flight("cruise_turns", 420.0, "navigation", "baro", 5))
    preset = analyze_ins3d(inp.steps, inp.refs, grade="navigation", with_observability=False)
    path = _write(tmp_path, NAVIGATION)
    custom = analyze_ins3d(inp.steps, inp.refs, grade=str(path), with_observability=False)
    np.testing.assert_allclose(custom.forward.x, preset.forward.x, rtol=1e-12, atol=1e-15)
    assert custom.thresholds == pytest.approx(preset.thresholds, rel=1e-14)
    assert (custom.isolation.isolation, custom.isolation.best) == \
        (preset.isolation.isolation, preset.isolation.best)
    assert custom.summary()["grade"] == "navigation"
    high = _write(tmp_path, NAVIGATION.replace("step: 20", "step: 99"), "high.yaml")
    other = analyze_ins3d(inp.steps, inp.refs, grade=str(high), with_observability=False)
    assert other.thresholds["step"] == 99.0
    assert other.thresholds["ramp"] == pytest.approx(preset.thresholds["ramp"], rel=1e-14)


def test_the_seed_episode_probability_loads_and_round_trips(tmp_path):
    """``seed_episode_probability``: read (a YAML string without a dot too), carried by a
    recording's numbers, the grade's DiagnosisConfig; absent: the default, also for presets."""
    g = load_grade(_write(tmp_path, NAVIGATION + "seed_episode_probability: 2.5e-12\n"))
    assert g.episode_probability == 2.5e-12
    assert diagnosis_config_of(g) == DiagnosisConfig(episode_probability=2.5e-12)
    assert CustomGrade.from_numbers(g.name, g.numbers()) == g
    assert g.numbers()["episode_probability"] == 2.5e-12
    nodot = load_grade(_write(tmp_path, NAVIGATION + "seed_episode_probability: 1e-9\n", "n.yaml"))
    assert nodot.episode_probability == 1e-9
    plain = load_grade(_write(tmp_path, NAVIGATION, "p.yaml"))
    assert plain.episode_probability is None and "episode_probability" not in plain.numbers()
    assert CustomGrade.from_numbers(plain.name, plain.numbers()).episode_probability is None
    assert diagnosis_config_of(plain) == DiagnosisConfig() == diagnosis_config_of(GRADES["mems"])


def test_the_analysis_uses_the_grades_seed_episode_probability(tmp_path):
    """A file with ``seed_episode_probability`` p gives the analysis a caller gets with
    DiagnosisConfig(episode_probability=p) (the seed method's rules, verdict and post_flight
    section); a caller's DiagnosisConfig still wins; without the key: the default. On this
    flight (seed 7) the seed method's strongest J episode lies between the two: declared with
    0.3, not with the default 1e-6."""
    inp = from_flight(flight("cruise_turns", 420.0, "navigation", "baro", 7))
    path = _write(tmp_path, NAVIGATION + "seed_episode_probability: 0.3\n")
    kw = {"with_observability": False}
    by_file = analyze_ins3d(inp.steps, inp.refs, grade=str(path), **kw)
    by_cfg = analyze_ins3d(inp.steps, inp.refs, grade=str(_write(tmp_path, NAVIGATION, "n.yaml")),
                           diagnosis=DiagnosisConfig(episode_probability=0.3), **kw)
    assert by_file.seed.config == by_cfg.seed.config == DiagnosisConfig(episode_probability=0.3)
    assert by_file.seed.verdict == by_cfg.seed.verdict != "no_fault"
    assert by_file.post_flight_dict() == by_cfg.post_flight_dict()
    caller = analyze_ins3d(inp.steps, inp.refs, grade=str(path), diagnosis=DiagnosisConfig(), **kw)
    assert caller.seed.config == DiagnosisConfig()
    preset = analyze_ins3d(inp.steps, inp.refs, grade="navigation", **kw)
    assert preset.seed.config == DiagnosisConfig() and preset.seed.verdict == "no_fault"


def test_a_recording_carries_the_seed_episode_probability(tmp_path):
    """filter_node's ModelInfo parameters of a grade file (``grade_params``) give the smoother
    (``recorded_grade``) the same grade, its seed_episode_probability included."""
    from flight_fdi.nodes.ins3d_recording import grade_params, recorded_grade

    import yaml

    path = REPO / "config/grades/example_nav_noisy.yaml"
    g = load_grade(path)
    p = float(yaml.safe_load(path.read_text())["seed_episode_probability"])
    assert g.episode_probability == p < 1e-6          # calibrated: stricter than the default
    names, values = grade_params(g)
    back = recorded_grade(f"ins3d/{g.name}", dict(zip(names, values)))
    assert back == g and diagnosis_config_of(back).episode_probability == p


def test_per_hypothesis_thresholds_load_round_trip_and_grow_with_the_length(tmp_path):
    """A grade file may give a hypothesis its own threshold (glr3d.PER_HYPOTHESIS); a kind
    given drops the base's hypotheses of that kind; a recording's numbers carry them."""
    from flight_fdi.core.ins3d.glr3d import growth_of, hypotheses, threshold_of

    g = load_grade(_write(tmp_path, "name: zed\nbase: tactical\n"
                                    "thresholds: {step: 30, gyro_z_step: 18.5}\n"))
    thr = dict(g.thresholds)
    assert thr["gyro_z_step"] == 18.5 and thr["step"] == 30.0
    hyps = {h.name: h for h in hypotheses(3)}
    assert threshold_of(thr, hyps["gyro_z_step"]) == 18.5
    assert threshold_of(thr, hyps["gyro_x_step"]) == 30.0
    assert CustomGrade.from_numbers(g.name, g.numbers()) == g
    long = grade_thresholds(g, 7200.0)
    assert long["gyro_z_step"] == pytest.approx(18.5 + growth_of("gyro_z_step") * math.log(4))
    # a kind given drops the base's hypotheses of that kind, the others are kept
    nav = thresholds_for("navigation")
    g2 = dict(load_grade(_write(tmp_path, "name: n2\nbase: navigation\n"
                                          "thresholds: {step: 25}\n")).thresholds)
    assert not any(k.endswith("_step") for k in g2)
    assert all(g2[k] == v for k, v in nav.items() if not k.endswith(("_step", "step")))
    with pytest.raises(CoreError, match="thresholds.gyro_w_step"):
        load_grade(_write(tmp_path, "name: bad\nbase: tactical\n"
                                    "thresholds: {gyro_w_step: 3}\n"))
