"""``flight-fdi run`` on real-bag layouts: renamed topics and Odometry through the ROS nodes
(same result and input accounting as ``analyze``, schema-valid), and the bad inputs that once
hung or printed a traceback: one line, exit 1, within seconds, before any ROS graph starts."""
from __future__ import annotations

import json
import os
import subprocess
import sys
import time

import harness  # noqa: F401  (private ROS domain, inherited by the subprocesses)
import numpy as np
import pytest

import craft
from flight_fdi.schema import validate_result


def _cli(*args, timeout=120):
    t = time.monotonic()
    proc = subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", *map(str, args)],
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, "PYTHONUNBUFFERED": "1"})
    return proc, time.monotonic() - t


@pytest.fixture(scope="module")
def short_flight():
    return craft.flight(120.0, ("accel:step:t=60,mag=3mg",), seed=5)


def _bad_bags(tmp, fl):
    nan_ref = craft.write(tmp / "nan_ref", fl, ref_values=np.full_like(fl.v_ref, np.nan))
    zero_ins = craft.write(tmp / "zero_ins", fl, ins_stamps=np.zeros_like(fl.stamp_ns))
    from flight_fdi.bagio import open_writer

    wrong = tmp / "wrong_types"
    with open_writer(wrong) as bag:  # the right topic names, wrong types
        for i in range(50):
            data = b"\x00\x01\x00\x00\x03\x00\x00\x00hi\x00"
            bag.write_raw("/ins/velocity", "std_msgs/msg/String", data, 1_700_000_000 + i)
            bag.write_raw("/reference/velocity", "std_msgs/msg/String", data, 1_700_000_000 + i)
    return {"nan_ref": (nan_ref, "/reference/velocity: no usable samples (0 of 1200 messages "
                                 "usable; 1200 non_finite)"),
            "zero_ins": (zero_ins, "/ins/velocity: no usable samples (0 of 6000 messages usable; "
                                   "6000 zero_stamp)"),
            "wrong_types": (wrong, "/ins/velocity carries std_msgs/msg/String, expected one of")}


@pytest.mark.parametrize("case", ["nan_ref", "zero_ins", "wrong_types"])
def test_bad_inputs_exit_1_with_one_line_within_seconds(tmp_path, short_flight, case):
    bag, message = _bad_bags(tmp_path, short_flight)[case]
    for cmd in ("run", "analyze"):
        proc, took = _cli(cmd, bag, "--out" if cmd == "run" else "--json",
                          *([tmp_path / "out"] if cmd == "run" else []))
        lines = proc.stderr.strip().splitlines()
        assert proc.returncode == 1, proc.stderr
        assert len(lines) == 1 and lines[0].startswith(f"flight-fdi {cmd}: error: "), proc.stderr
        assert message in lines[0] and "Traceback" not in proc.stderr
        assert took < 30.0  # (measured ~2-4 s: Python start-up and the bag; loaded CI margin)
    assert not (tmp_path / "out" / "recording").exists()  # no graph was started


def test_run_with_renamed_topics_and_odometry_equals_analyze(tmp_path, short_flight):
    bag = craft.write(tmp_path / "b", short_flight, "/xsens/odom", craft.ODOM, ("/gps/vel",),
                      craft.TWIST_COV, yaw_rate=0.01)
    args = ["--ins-topic", "/xsens/odom", "--reference-topic", "/gps/vel", "--fail-on-fault"]
    run, _ = _cli("run", bag, "--out", tmp_path / "out", "--json", "--no-report", *args,
                  timeout=300)
    assert run.returncode == 3, run.stderr  # a fault was declared
    progress = [ln for ln in run.stderr.splitlines() if ln.startswith("replay ")]
    assert [ln.split("%")[0].split()[-1] for ln in progress] == [str(p) for p in
                                                                 range(10, 101, 10)]
    got = json.loads(run.stdout)
    ana, _ = _cli("analyze", bag, "--json", *args)
    assert ana.returncode == 3
    expected = json.loads(ana.stdout)
    for res in (got, expected, json.loads((tmp_path / "out" / "result.json").read_text())):
        validate_result(res)
    assert got["input"] == expected["input"] and got["source"] == expected["source"]
    assert got["post_flight"]["headline"] == expected["post_flight"]["headline"]
    f, g = got["post_flight"]["fault"], expected["post_flight"]["fault"]
    assert (f["sensor"], f["kind"], f["axis"]) == ("accelerometer", "step", "x")
    assert set(f) == set(g) and f["hypothesis"] == g["hypothesis"]
    for k in ("onset_s", "magnitude", "statistic"):
        assert f[k] == pytest.approx(g[k], rel=1e-6, abs=1e-6)
