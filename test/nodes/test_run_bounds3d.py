"""``flight-fdi run --model ins3d``'s bounds, and ``run --out`` naming a file.

* ``--stall-timeout`` and ``--teardown-timeout`` reach ``run_pipeline3d`` as they reach the
  single-axis pipeline (test_run_bounds.py; before: refused with --model ins3d, one line), with
  the ``on_teardown_timeout`` that completes the command: a stalled 3-D run ends with one line
  naming the stage, and -- in a child process whose recorder's teardown blocks for good -- a
  timed-out teardown still prints the result, writes the report and exits with ``run``'s status
  (3 with --fail-on-fault and a fault).
* ``run BAG --out FILE`` (single-axis) is one line, exit 1, before any node, nothing written
  (before: a FileExistsError traceback from the pipeline; the 3-D path already refused it).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import harness  # noqa: F401  (private ROS domain, inherited by the subprocesses)
import pytest
# the 20-s single-axis flight of the shutdown tests, and its recording check
from nodes.test_pipeline_shutdown import _assert_closed_cleanly, small_bag  # noqa: F401
from nodes.test_run_bounds import _CHILD, _warn_lines

from flight_fdi.cli.main import main


@pytest.fixture(scope="module")
def faulty_bag3d(tmp_path_factory) -> Path:
    """A 60-s 3-D flight with a large accelerometer x step at 20 s (a fault verdict)."""
    path = tmp_path_factory.mktemp("bounds3d") / "accel_x"
    assert main(["simulate", str(path), "--model", "ins3d", "--duration", "60", "--seed", "5",
                 "--fault", "accel:step:t=20,mag=0.05,axis=x"]) == 0
    return path


# ------------------------------------------------------------------------------ the options

def test_the_bounds_reach_the_3d_pipeline(faulty_bag3d, tmp_path, monkeypatch, capsys):
    from flight_fdi.nodes import ins3d_pipeline
    from flight_fdi.nodes.pipeline import PipelineError

    calls = []

    def fake(bag, out, **kwargs):
        calls.append(kwargs)
        raise PipelineError("stopped here")

    monkeypatch.setattr(ins3d_pipeline, "run_pipeline3d", fake)
    out = str(tmp_path / "out")
    assert main(["run", str(faulty_bag3d), "--model", "ins3d", "--out", out,
                 "--stall-timeout", "2.5", "--teardown-timeout", "30"]) == 1
    assert main(["run", str(faulty_bag3d), "--model", "ins3d", "--out", out]) == 1
    given, default = calls
    assert (given["stall_timeout_s"], given["teardown_timeout"]) == (2.5, 30.0)
    assert "stall_timeout_s" not in default and "teardown_timeout" not in default
    assert callable(given["on_teardown_timeout"]) and callable(default["on_teardown_timeout"])
    assert capsys.readouterr().err == "flight-fdi run: error: stopped here\n" * 2


@pytest.mark.parametrize("option, value", [("--stall-timeout", "0"),
                                           ("--teardown-timeout", "ten")])
def test_a_bad_bound_with_the_3d_model_is_one_line_before_anything(tmp_path, capsys, option,
                                                                  value):
    out = tmp_path / "out"
    assert main(["run", str(tmp_path), "--model", "ins3d", "--out", str(out), option,
                 value]) == 1
    err = capsys.readouterr().err
    assert err.startswith(f"flight-fdi run: error: {option}: expected a number of seconds ")
    assert err.count("\n") == 1 and not out.exists()


@pytest.mark.timeout(300)
def test_the_stall_timeout_ends_a_stalled_3d_run(faulty_bag3d, tmp_path, monkeypatch, capfd):
    from flight_fdi.nodes.recorder_node import RecorderNode

    real = RecorderNode._on_message

    def stops_after_50(self, topic, msgtype, data):
        if self.bag.message_count < 50:
            real(self, topic, msgtype, data)

    monkeypatch.setattr(RecorderNode, "_on_message", stops_after_50)
    code = main(["run", str(faulty_bag3d), "--model", "ins3d", "--out", str(tmp_path),
                 "--no-report", "--no-progress", "--stall-timeout", "1"])
    err = capfd.readouterr().err.splitlines()
    assert code == 1
    (line,) = [ln for ln in err if "error" in ln]
    assert line.startswith("flight-fdi run: error: ")
    assert ": recorder_node made no progress for 1 s (" in line
    assert _assert_closed_cleanly(tmp_path / "recording") == 50
    assert not (tmp_path / "result.json").exists()


# ------------------------------------------------------------------------------ blocked teardown

@pytest.mark.timeout(400)
def test_a_timed_out_3d_teardown_still_prints_the_result_and_writes_the_report(faulty_bag3d,
                                                                               tmp_path):
    from flight_fdi.cli.analyze import EXIT_FAULT, FAULT_VERDICTS
    from flight_fdi.cli.ins3d import format_result

    folder = tmp_path / "run"
    cmd = ["run", str(faulty_bag3d), "--model", "ins3d", "--out", str(folder), "--no-progress",
           "--teardown-timeout", "1", "--fail-on-fault"]
    proc = subprocess.Popen([sys.executable, "-c", _CHILD, *cmd], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        rc = proc.wait(timeout=300)
        out, err = proc.communicate(timeout=30)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate()
    assert "teardown blocked" in err
    res = json.loads((folder / "result.json").read_text())
    assert res["model"] == "ins3d" and res["post_flight"]["verdict"] in FAULT_VERDICTS
    assert rc == EXIT_FAULT, err
    index = folder / "report" / "index.html"
    assert out == (f"{format_result(res)}\n\nrecording and result.json in {folder}/\n"
                   f"report (figures and verdict): {index}\n")  # never returned
    assert index.is_file() and "Rebuilt from the recording" in index.read_text()
    # (the filter's own WARN lines, its in-flight alarms, come before)
    first, last = [ln for ln in _warn_lines(err) if "[flight_fdi_pipeline]" in ln]
    assert first.startswith(
        "[WARN] [flight_fdi_pipeline]: the middleware teardown did not end within 1 s "
        "(destroying node recorder_node) after the pipeline's work was complete")
    assert last == ("[WARN] [flight_fdi_pipeline]: exiting with status 3 without the "
                    "middleware teardown")
    assert "Traceback" not in err


# ------------------------------------------------------------------------------ --out a file

def test_run_out_naming_a_file_is_one_line_before_any_node(small_bag, tmp_path,  # noqa: F811
                                                            capsys):
    out = tmp_path / "taken"
    out.write_text("mine\n")
    code = main(["run", str(small_bag), "--out", str(out), "--no-progress"])
    assert code == 1
    assert capsys.readouterr().err == (
        f"flight-fdi run: error: --out {str(out)!r}: cannot make the output folder there (a "
        "file of that name exists)\n")
    assert out.read_text() == "mine\n" and sorted(tmp_path.iterdir()) == [out]
