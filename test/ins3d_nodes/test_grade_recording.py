"""A YAML grade file in the node path: filter_node's ``ins3d_grade`` takes it (validated at
start-up), the recording carries its numbers (ModelInfo ``grade.*`` parameters) and the smoother
reads the same grade back."""
from __future__ import annotations

from pathlib import Path

import pytest

from flight_fdi.core.ins3d.grade_file import CustomGrade, load_grade
from flight_fdi.core.ins3d.grades import GRADES
from flight_fdi.nodes.errors import ParameterError
from flight_fdi.nodes.ins3d_mode import build_model
from flight_fdi.nodes.ins3d_recording import grade_params, recorded_grade

EXAMPLE = Path(__file__).resolve().parents[2] / "config/grades/example_mems_custom.yaml"


def _defaults():
    from flight_fdi.nodes.filter_node import _DEFAULTS

    return _DEFAULTS


def test_a_preset_records_only_its_name():
    assert grade_params(GRADES["navigation"]) == ([], [])
    assert recorded_grade("ins3d/navigation", {"rows": 3.0, "t0_sec": 1.0}) == "navigation"


def test_a_grade_file_round_trips_through_the_model_info_parameters():
    g = load_grade(EXAMPLE)
    names, values = grade_params(g)
    assert len(names) == len(set(names)) and all(n.startswith("grade.") for n in names)
    assert "grade.gyro_bias" in names and "grade.threshold_step" in names
    params = {"rows": 3.0, "t0_sec": 5.0, "t0_nanosec": 0.0, **dict(zip(names, values))}
    back = recorded_grade(f"ins3d/{g.name}", params)
    assert isinstance(back, CustomGrade) and back == g


def test_the_node_builds_its_model_from_a_grade_file():
    d = _defaults()
    m = build_model({**d, "model": "ins3d", "ins3d_grade": str(EXAMPLE)}, d)
    assert m.grade == load_grade(EXAMPLE)


@pytest.mark.parametrize("value, needle", [
    ("perfect", "a preset (navigation, tactical, mems) or a YAML grade file"),
    ("consumer", "a preset (navigation, tactical, mems) or a YAML grade file"),
    ("missing.yaml", "cannot read"),
])
def test_a_bad_grade_is_refused_at_start(value, needle):
    d = _defaults()
    with pytest.raises(ParameterError, match="'ins3d_grade'") as exc:
        build_model({**d, "model": "ins3d", "ins3d_grade": value}, d)
    assert needle in str(exc.value)


def test_a_bad_grade_file_is_refused_at_start(tmp_path):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: b\nbase: mems\ngyro_tau_s: 0\n")
    d = _defaults()
    with pytest.raises(ParameterError, match="gyro_tau_s must be a finite number > 0"):
        build_model({**d, "model": "ins3d", "ins3d_grade": str(bad)}, d)
