"""``--grade FILE.yaml`` for ``flight-fdi simulate --model ins3d`` and ``montecarlo --model
ins3d``: a file equal to a preset simulates (and studies) the same flights as the preset; a
file's own values are the ones simulated and recorded; a bad file is one line."""
from __future__ import annotations

import json
from dataclasses import fields

import numpy as np
import pytest
import yaml

from flight_fdi.cli.main import main
from flight_fdi.core.ins3d.grade_file import load_grade
from flight_fdi.core.ins3d.grades import DEG_H, GRADES, ImuGrade
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig

#: the tactical preset as a file (every value the base's)
AS_TACTICAL = "name: tact_file\nbase: tactical\n"
#: a tactical unit with 4x the gyro bias and a larger accelerometer scale factor
NOISY = AS_TACTICAL.replace("tact_file", "noisy_tact") + (
    "gyro_bias_deg_h: 4.0\naccel_scale_ppm: 1200\nthresholds: {step: 27.5}\n")


def _doc(bag) -> dict:
    meta = yaml.safe_load((bag / "metadata.yaml").read_text())
    return json.loads(meta["rosbag2_bagfile_information"]["custom_data"]["flight_fdi.sim3d"])


def test_a_preset_as_a_file_simulates_the_presets_flight(tmp_path):
    path = tmp_path / "t.yaml"
    path.write_text(AS_TACTICAL)
    traj = TrajectoryConfig(profile="cruise_turns", duration_s=60.0, seed=4)
    a = simulate3d(Sim3DConfig(traj, grade="tactical", seed=4))
    b = simulate3d(Sim3DConfig(traj, grade=load_grade(path), seed=4))
    assert np.array_equal(a.ins.v, b.ins.v) and np.array_equal(a.gyro.matrix, b.gyro.matrix)


def test_simulate_records_the_files_values(tmp_path, capsys):
    path = tmp_path / "noisy.yaml"
    path.write_text(NOISY)
    out, ref = tmp_path / "noisy", tmp_path / "tactical"
    common = ["--model", "ins3d", "--duration", "60", "--seed", "3", "--imu-rate", "10",
              "--velocity-rate", "10"]
    assert main(["simulate", str(out), *common, "--grade", str(path)]) == 0
    assert "noisy_tact IMU" in capsys.readouterr().out
    assert main(["simulate", str(ref), *common, "--grade", "tactical"]) == 0
    imu, base = _doc(out)["imu"], _doc(ref)["imu"]
    assert imu["name"] == "noisy_tact" and base["name"] == "tactical"
    assert imu["gyro_bias"] == pytest.approx(4.0 * DEG_H, rel=1e-12)
    assert imu["accel_scale"] == pytest.approx(1200e-6, rel=1e-12)
    assert imu["thresholds"] == {"step": 27.5, "ramp": 22.0, "jump": 30.0, "outliers": 32.0}
    same = [f.name for f in fields(ImuGrade) if f.name not in
            ("name", "gyro_bias", "accel_scale")]
    assert {k: imu[k] for k in same} == {k: base[k] for k in same}
    assert imu["accel_matrix"] != base["accel_matrix"]        # the file's scale factors
    g = GRADES["tactical"]
    assert base["gyro_bias"] == g.gyro_bias and base["accel_scale"] == g.accel_scale


@pytest.mark.parametrize("cmd", ["simulate", "montecarlo"])
def test_a_bad_grade_file_is_one_line(cmd, tmp_path, capsys):
    path = tmp_path / "bad.yaml"
    path.write_text("name: x\nbase: tactical\ngyro_bias_deg_h: -1\n")
    argv = ([cmd, str(tmp_path / "b"), "--model", "ins3d", "--duration", "60"]
            if cmd == "simulate" else
            [cmd, "--model", "ins3d", "--nominal", "1", "--per-fault", "0", "--duration", "60",
             "--jobs", "1", "--no-progress"])
    assert main(argv + ["--grade", str(path)]) == 1
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert err.count("\n") == 0 and f"flight-fdi {cmd}: error:" in err
    assert "gyro_bias_deg_h must be a finite number >= 0" in err and cap.out == ""
    assert not (tmp_path / "b").exists()


def test_montecarlo_with_a_grade_file(tmp_path, capsys):
    """A file equal to the tactical preset: the same records as --grade tactical (seeded); its
    numbers in the study's config; a noisier file changes the flights."""
    same, noisy = tmp_path / "t.yaml", tmp_path / "n.yaml"
    same.write_text(AS_TACTICAL)
    noisy.write_text(NOISY)
    base = ["montecarlo", "--model", "ins3d", "--nominal", "1", "--per-fault", "1",
            "--scenarios", "gyro_step", "--level", "gyro_step=20", "--duration", "120",
            "--profile", "cruise_turns", "--no-single-axis", "--jobs", "1", "--no-progress",
            "--seed", "8"]
    docs = {}
    for name, grade in (("preset", "tactical"), ("file", str(same)), ("noisy", str(noisy))):
        out = tmp_path / f"{name}.json"
        assert main(base + ["--grade", grade, "--out", str(out), "--json"]) == 0
        capsys.readouterr()
        docs[name] = json.loads(out.read_text())
    p, f, n = (docs[k]["flights"] for k in ("preset", "file", "noisy"))
    assert [r["ins3d"] for r in p] == [r["ins3d"] for r in f]
    assert [r["grade"] for r in f] == ["tact_file"] * 2
    cfg = docs["noisy"]["config"]
    assert cfg["grade"] == "noisy_tact"
    assert cfg["grade_values"]["gyro_bias"] == pytest.approx(4.0 * DEG_H, rel=1e-12)
    assert cfg["grade_values"]["thresholds"]["step"] == 27.5
    assert "grade_values" not in docs["preset"]["config"]
    assert n[1]["ins3d"]["glr_max"] != p[1]["ins3d"]["glr_max"]
