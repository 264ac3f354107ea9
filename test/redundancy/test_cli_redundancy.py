"""The redundancy commands (criticality, voter-calibrate, voter-experiment, imu-simulate), run
through ``register`` + ``run`` on a parser of their own (the lead adds them to flight-fdi)."""
from __future__ import annotations

import argparse
import importlib
import json
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.cli.errors import CliError
from flight_fdi.core.errors import CoreError
from flight_fdi.sim.errors import SimError

REPO = Path(__file__).resolve().parents[2]
EXAMPLE = REPO / "config" / "models" / "redundant_5ch.yaml"
MODULES = ("flight_fdi.cli.criticality", "flight_fdi.cli.voter_calibrate",
           "flight_fdi.cli.voter_experiment", "flight_fdi.cli.imu_simulate")


def cli(argv, capsys):
    parser = argparse.ArgumentParser(prog="flight-fdi")
    sub = parser.add_subparsers(dest="command", required=True)
    for name in MODULES:
        importlib.import_module(name).register(sub)
    args = parser.parse_args(argv)
    rc = args.func(args)
    return rc, capsys.readouterr().out


SMALL = ["--duration", "6", "--rate", "100", "--window", "50", "--eval-every", "2",
         "--min-segment", "0.3", "--smooth", "0.2", "--segments", "6", "--no-progress"]


def test_criticality_json_and_table(capsys):
    from flight_fdi.core.redundancy import criticality, load_redundant_model

    rc, out = cli(["criticality", "--model", str(EXAMPLE), "--json"], capsys)
    assert rc == 0
    doc = json.loads(out)
    model, spec = load_redundant_model(EXAMPLE)
    ref = criticality(model, spec)
    assert doc["sensors"] == list(spec.names) and len(doc["sets"]) == 32
    assert doc["kf2_never_worse_than_af"] is True
    assert doc["classes"]["af"]["vital"] == list(ref.vital["af"])
    for s, r in zip(doc["sets"], ref.sets):
        assert s["pattern"] == r.pattern and s["J"]["af"] == pytest.approx(r.J["af"])
    rc, out = cli(["criticality", "--model", str(EXAMPLE), "--max-failed", "1",
                   "--bound", "1e-3"], capsys)
    assert rc == 0 and "vital" in out and "[10111]" in out
    assert "inadmissible fault sets: none" in out  # every set is below the raised bound
    rows = [ln for ln in out.splitlines() if len(ln) > 5 and ln[:5].strip("01") == ""]
    assert len(rows) == 6  # nominal + 5 single failures


def test_criticality_bad_inputs(capsys, tmp_path):
    with pytest.raises(CoreError, match="No such file"):
        cli(["criticality", "--model", str(tmp_path / "nope.yaml")], capsys)
    bad = tmp_path / "bad.yaml"
    bad.write_text(EXAMPLE.read_text().replace("rows: [4]", "rows: [9]"))
    with pytest.raises(CoreError, match="row 9 is not a row index"):
        cli(["criticality", "--model", str(bad)], capsys)
    with pytest.raises(CliError, match="--max-failed"):
        cli(["criticality", "--model", str(EXAMPLE), "--max-failed", "9"], capsys)
    with pytest.raises(CliError, match="--bound"):
        cli(["criticality", "--model", str(EXAMPLE), "--bound", "-1"], capsys)


def test_voter_calibrate_writes_a_loadable_table(capsys, tmp_path):
    from flight_fdi.core.voting import load_table

    out_file = tmp_path / "t.json"
    curves = tmp_path / "c.npz"
    rc, out = cli(["voter-calibrate", str(out_file), "--flights", "40", "--alpha", "0.01",
                   "--quantities", "gyro_z,accel_x", "--curves", str(curves), "--json",
                   "--seed", "3", *SMALL], capsys)
    assert rc == 0
    info = json.loads(out)
    table = load_table(out_file)
    assert table.quantities == ("gyro_z", "accel_x") and table.window == 50
    assert table.alpha == 0.01 and table.rate_hz == 100.0 and table.duration_s == 6.0
    assert table.calibration["flights"] == 40 and table.calibration["seed"] == 3
    assert set(info["entries"]) == {"gyro_z", "accel_x"}
    for q in table.quantities:
        for p in ("x1", "x2", "x3"):
            ts = table.entries[q][p][0]
            assert len(ts) <= 6 and 0.5 in ts  # forced cut at the end of the first window
    with np.load(curves) as z:
        assert z["lower"].shape == (300, 2, 3) and list(z["quantities"]) == ["gyro_z", "accel_x"]
    # the table text output
    rc, out = cli(["voter-calibrate", str(out_file), "--force", "--flights", "20", *SMALL],
                  capsys)
    assert rc == 0 and "gyro_x" in out and "deg/h" in out


def test_voter_calibrate_bad_inputs(capsys, tmp_path):
    existing = tmp_path / "t.json"
    existing.write_text("{}")
    with pytest.raises(CliError, match="exists already"):
        cli(["voter-calibrate", str(existing), *SMALL], capsys)
    with pytest.raises(CliError, match="--quantities"):
        cli(["voter-calibrate", str(tmp_path / "n.json"), "--quantities", "gyro_w", *SMALL],
            capsys)
    with pytest.raises(CliError, match="--alpha"):
        cli(["voter-calibrate", str(tmp_path / "n.json"), "--alpha", "0", *SMALL], capsys)
    with pytest.raises(SimError, match="unknown parameters"):
        cli(["voter-calibrate", str(tmp_path / "n.json"), "--param", "bogus=1", *SMALL], capsys)
    with pytest.raises(CoreError, match="too few"):
        cli(["voter-calibrate", str(tmp_path / "n.json"), "--flights", "5", *SMALL], capsys)


def test_voter_experiment_tiny(capsys):
    """A tiny seeded version of the seed-002 experiment: large faults are detected, sooner
    than small ones, and isolate the faulty IMU."""
    rc, out = cli(["voter-experiment", "--runs", "20", "--calibration-flights", "60",
                   "--amplitudes", "20,500", "--frequencies", "1,20", "--alphas", "0.002",
                   "--onset", "3", "--json", *SMALL], capsys)
    assert rc == 0
    doc = json.loads(out)
    cells = [c for c in doc["cells"] if c["frequency_hz"] is not None]
    assert len(cells) == 4 and doc["runs"] == 20 and doc["shape"] == "square_onoff"
    nominal = [c for c in doc["cells"] if c["frequency_hz"] is None]
    assert len(nominal) == 1 and 0.0 <= nominal[0]["false_alarm_runs"] <= 1.0
    big = [c for c in cells if c["amplitude"] == 500]
    assert all(c["missed"] == 0.0 and c["correct_isolation"] == 1.0 for c in big)
    for f in (1.0, 20.0):
        small = next(c for c in cells if c["amplitude"] == 20 and c["frequency_hz"] == f)
        large = next(c for c in cells if c["amplitude"] == 500 and c["frequency_hz"] == f)
        if small["mean_s"] is not None:
            assert large["mean_s"] < small["mean_s"]
    rc, out = cli(["voter-experiment", "--runs", "5", "--calibration-flights", "20",
                   "--amplitudes", "500", "--frequencies", "5", "--alphas", "0.05",
                   "--onset", "3", *SMALL], capsys)
    assert rc == 0 and "| 0.05 | 500 | 5 |" in out


def test_voter_experiment_bad_inputs(capsys):
    with pytest.raises(CliError, match="--amplitudes"):
        cli(["voter-experiment", "--amplitudes", "5,x", *SMALL], capsys)
    with pytest.raises(CliError, match="--onset"):
        cli(["voter-experiment", "--onset", "10", *SMALL], capsys)
    with pytest.raises(CliError, match="--alphas"):
        cli(["voter-experiment", "--alphas", "2", *SMALL], capsys)
    with pytest.raises(SimError, match="below half"):
        cli(["voter-experiment", "--frequencies", "80", "--onset", "3", "--runs", "2",
             "--calibration-flights", "10", *SMALL], capsys)


def test_imu_simulate(capsys, tmp_path):
    from flight_fdi.bagio import bag_topics

    bag = tmp_path / "imu"
    rc, out = cli(["imu-simulate", str(bag), "--duration", "2", "--rate", "100",
                   "--imu-fault", "imu2:gyro_x:zero:t=1"], capsys)
    assert rc == 0 and "IMU2 gyro_x zero" in out and "600 IMU messages" in out
    assert bag_topics(bag) == {"/sim/fault": "std_msgs/msg/String",
                               **{f"/imu{k}/data": "sensor_msgs/msg/Imu" for k in (1, 2, 3)}}
    with pytest.raises(SimError, match="imu1, imu2 or imu3"):
        cli(["imu-simulate", str(tmp_path / "x"), "--imu-fault", "imu9:gyro_x:zero:t=1"],
            capsys)
    from flight_fdi.bagio.errors import BagError

    with pytest.raises(BagError, match="exists already"):
        cli(["imu-simulate", str(bag), "--duration", "2"], capsys)


def test_errors_are_the_types_main_reports():
    """flight-fdi main prints these types as one line (CliError, CoreError, SimError, BagError)."""
    from flight_fdi.cli.main import _user_errors

    errs = _user_errors()
    assert all(issubclass(e, errs) for e in (CliError, CoreError, SimError))
