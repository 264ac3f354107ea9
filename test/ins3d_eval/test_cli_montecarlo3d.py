"""``flight-fdi montecarlo --model ins3d``: option validation (one line on stderr, exit 1, no
flight run) and a tiny study through the command with its JSON and records."""
from __future__ import annotations

import json

import pytest

from flight_fdi.cli.main import main


@pytest.mark.parametrize("argv, message", [
    (["--model", "ins4d"], "--model must be one of channel, ins3d, got 'ins4d'"),
    (["--model", "ins3d", "--channel", "y"], "--channel belongs to the single-axis study"),
    (["--model", "ins3d", "--scenarios", "accel_step,bad"], "unknown scenario 'bad'"),
    (["--model", "ins3d", "--grade", "consumer"], "unknown grade 'consumer'"),
    (["--model", "ins3d", "--level", "gyro_step=0.1,x"], "--level 'gyro_step=0.1,x'"),
    (["--model", "ins3d", "--level", "gyro=0.1"], "unknown scenario 'gyro'"),
    (["--model", "ins3d", "--duration", "10"], "duration_s must be within 60..10800 s"),
    (["--model", "ins3d", "--out", "/no/such/dir/x.json"], "--out: cannot write"),
    (["--model", "ins3d", "--ladder", "--ladder-grades", "navigation,foo"], "unknown grade"),
])
def test_bad_options_are_one_line_errors(argv, message, capsys):
    assert main(["montecarlo", "--no-progress", "--jobs", "1", *argv]) == 1
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert err.count("\n") == 0, err
    assert err.startswith("flight-fdi montecarlo: error: ") and message in err
    assert captured.out == ""


def test_tiny_study_json_and_records(tmp_path, capsys):
    records = tmp_path / "r.jsonl"
    out = tmp_path / "study.json"
    argv = ["montecarlo", "--model", "ins3d", "--nominal", "1", "--per-fault", "1",
            "--scenarios", "gyro_step", "--level", "gyro_step=0.2", "--duration", "120",
            "--profile", "cruise_turns", "--no-single-axis", "--jobs", "1", "--no-progress",
            "--json", "--records", str(records), "--out", str(out), "--seed", "5"]
    assert main(argv) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["model"] == "ins3d"
    assert doc["config"]["levels"] == {"gyro_step": [0.2]}
    assert doc["metrics"]["flights"] == {"nominal": 1, "gyro_step": 1}
    assert doc["metrics"]["models"] == ["ins3d"]
    header, *lines = [json.loads(s) for s in records.read_text().splitlines()]
    assert header["study"]["model"] == "ins3d"  # the study's settings (resume: --records)
    assert sorted(r["index"] for r in lines) == [0, 1]
    full = json.loads(out.read_text())
    assert [r["scenario"] for r in full["flights"]] == ["nominal", "gyro_step"]
    assert full["flights"][1]["level"] == 0.2 and full["flights"][1]["unit"] == "deg/h"
