"""``flight-fdi montecarlo``: options, JSON output, the full-result file and one-line errors."""
from __future__ import annotations

import argparse
import json

import pytest

from flight_fdi.cli import montecarlo
from flight_fdi.core.errors import CoreError


def parser():
    p = argparse.ArgumentParser(prog="flight-fdi")
    montecarlo.register(p.add_subparsers(dest="command"))
    return p


def test_montecarlo_json_and_full_result_file(tmp_path, capsys):
    out = tmp_path / "study.json"
    args = parser().parse_args([
        "montecarlo", "--nominal", "1", "--per-fault", "1", "--accel-levels", "5",
        "--gyro-levels", "20", "--duration", "200", "--onset", "0.3,0.5", "--seed", "3",
        "--jobs", "1", "--json", "--no-progress", "--out", str(out)])
    assert args.func(args) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["config"]["nominal"] == 1 and doc["config"]["accel_levels_mg"] == [5.0]
    assert doc["config"]["onset_window"] == [0.3, 0.5]
    assert doc["config"]["analysis"]["gate"]["alarm_m"] == 3
    m = doc["metrics"]
    assert m["flights"] == {"nominal": 1, "accel": 1, "gyro": 1}
    # (the gyro step is reported beside its twin, the accelerometer ramp: ambiguous)
    assert m["confusion"]["glr"]["counts"] == [[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]
    assert "flights" not in doc  # stdout: settings and metrics only
    full = json.loads(out.read_text())
    assert [f["kind"] for f in full["flights"]] == ["nominal", "accel", "gyro"]
    assert full["metrics"] == m
    onset = full["flights"][1]["onset_s"]
    assert 60.0 <= onset <= 100.0


def test_montecarlo_text_output(capsys):
    args = parser().parse_args([
        "montecarlo", "--nominal", "1", "--per-fault", "0", "--duration", "100", "--jobs", "1",
        "--no-progress"])
    assert args.func(args) == 0
    text = capsys.readouterr().out
    assert "flights: 1 nominal, 0 accelerometer, 0 gyro" in text
    assert "| in_flight |" in text and "confusion matrix, glr" in text


def test_montecarlo_errors():
    p = parser()
    with pytest.raises(SystemExit):  # argparse: not numbers
        p.parse_args(["montecarlo", "--accel-levels", "a,b"])
    args = p.parse_args(["montecarlo", "--onset", "0.9,0.1", "--jobs", "1"])
    with pytest.raises(CoreError, match="onset_window"):
        args.func(args)
    args = p.parse_args(["montecarlo", "--alarm", "3-5"])
    with pytest.raises(Exception, match="M/N"):
        args.func(args)
