"""``flight-fdi run``'s bounds on the command line, and what a timed-out teardown keeps.

* ``--stall-timeout`` and ``--teardown-timeout`` set the pipeline's ``stall_timeout_s`` and
  ``teardown_timeout`` (docs/hardening.md section 5): validated (one line, exit 1, nothing
  written), listed by ``--help``, passed to the pipeline, and acted on.
* A teardown that blocks after the result was written no longer loses ``run``'s own output: as
  in test_pipeline_shutdown.py, a child process runs ``flight-fdi run`` whose recorder's teardown
  blocks for good; past the bound it still prints the result (text or --json), writes the
  report and exits with the status ``run`` gives (0, or 3 with --fail-on-fault and a fault).
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import harness  # noqa: F401  (private ROS domain, inherited by the subprocesses)
import pytest
# the 20-s flight of the shutdown tests (module fixture, reused)
from nodes.test_pipeline_shutdown import _assert_closed_cleanly, small_bag  # noqa: F401

from flight_fdi.cli.main import main


@pytest.fixture(scope="module")
def faulty_bag(tmp_path_factory) -> Path:
    """A 20-s flight with a large accelerometer step at 8 s."""
    from flight_fdi.sim import SimConfig, parse_fault, simulate_to_bag

    path = tmp_path_factory.mktemp("faulty") / "flight"
    simulate_to_bag(SimConfig(duration_s=20.0, seed=11,
                              faults=(parse_fault("accel:step:t=8,mag=0.5"),)), str(path))
    return path


# ------------------------------------------------------------------------------ the options

def run_help(capsys) -> str:
    """``flight-fdi run --help`` (exit 0), its whitespace collapsed."""
    with pytest.raises(SystemExit) as exit_:
        main(["run", "--help"])
    assert exit_.value.code == 0
    return " ".join(capsys.readouterr().out.split())


def test_help_lists_the_bounds(capsys):
    text = run_help(capsys)
    assert "--stall-timeout S end the run with an error naming the stage when a stage with " \
           "work waiting makes no progress for S seconds (1 to 3600; default 60)" in text
    assert "--teardown-timeout S bound on the middleware teardown after the run's work " \
           "(1 to 600 s; default 10)" in text


def test_the_help_defaults_are_the_pipelines():
    from flight_fdi.nodes.pipeline import STALL_TIMEOUT_S, TEARDOWN_TIMEOUT_S

    assert (STALL_TIMEOUT_S, TEARDOWN_TIMEOUT_S) == (60.0, 10.0)


@pytest.mark.parametrize("option, value, allowed", [
    ("--stall-timeout", "0", "1 to 3600"), ("--stall-timeout", "3601", "1 to 3600"),
    ("--stall-timeout", "nan", "1 to 3600"), ("--stall-timeout", "inf", "1 to 3600"),
    ("--stall-timeout", "ten", "1 to 3600"), ("--stall-timeout", "-5", "1 to 3600"),
    ("--teardown-timeout", "0.5", "1 to 600"), ("--teardown-timeout", "601", "1 to 600"),
    ("--teardown-timeout", "", "1 to 600")])
def test_a_bad_bound_is_one_line_and_exit_1_before_anything(tmp_path, capsys, option, value,
                                                          allowed):
    bag = tmp_path / "bag"
    bag.mkdir()
    out = tmp_path / "out"
    code = main(["run", str(bag), "--out", str(out), option, value])
    err = capsys.readouterr().err
    assert code == 1
    assert err == (f"flight-fdi run: error: {option}: expected a number of seconds from "
                   f"{allowed}, got {value!r}\n")
    assert not out.exists()


def test_the_bounds_reach_the_pipeline(tmp_path, monkeypatch, capsys):
    from flight_fdi.nodes import pipeline

    calls = []

    def fake(bag, out, **kwargs):
        calls.append(kwargs)
        raise pipeline.PipelineError("stopped here")

    monkeypatch.setattr(pipeline, "run_pipeline_detailed", fake)
    bag = tmp_path / "bag"
    bag.mkdir()
    assert main(["run", str(bag), "--out", str(tmp_path / "out"), "--stall-timeout", "2.5",
                 "--teardown-timeout", "30"]) == 1
    assert main(["run", str(bag), "--out", str(tmp_path / "out")]) == 1
    given, default = calls
    assert (given["stall_timeout_s"], given["teardown_timeout"]) == (2.5, 30.0)
    assert "stall_timeout_s" not in default and "teardown_timeout" not in default
    assert callable(given["on_teardown_timeout"])
    assert capsys.readouterr().err.count("flight-fdi run: error: stopped here\n") == 2


@pytest.fixture
def recorder_stops_after_50(monkeypatch):
    """The recorder records the first 50 messages and then nothing (a stalled run)."""
    from flight_fdi.nodes.recorder_node import RecorderNode

    real = RecorderNode._on_message

    def stops_after_50(self, topic, msgtype, data):
        if self.bag.message_count < 50:
            real(self, topic, msgtype, data)

    monkeypatch.setattr(RecorderNode, "_on_message", stops_after_50)


def test_the_stall_timeout_option_ends_a_stalled_run(small_bag, tmp_path,  # noqa: F811
                                                     recorder_stops_after_50, capfd):
    code = main(["run", str(small_bag), "--out", str(tmp_path), "--no-report", "--no-progress",
                 "--stall-timeout", "1"])
    err = capfd.readouterr().err.splitlines()
    assert code == 1
    (line,) = [ln for ln in err if "error" in ln]
    assert ": recorder_node made no progress for 1 s (" in line
    assert _assert_closed_cleanly(tmp_path / "recording") == 50


# ------------------------------------------------------------------------------ blocked teardown

_CHILD = """
import sys, threading
from flight_fdi.cli.main import main
from flight_fdi.nodes.recorder_node import RecorderNode

real = RecorderNode.destroy_node

def blocking(self, *args, **kwargs):
    real(self, *args, **kwargs)
    print("teardown blocked", file=sys.stderr, flush=True)
    threading.Event().wait()      # blocked for good, GIL released (as in rcl_node_fini)

RecorderNode.destroy_node = blocking
code = main(sys.argv[1:])
print("returned", code, flush=True)
"""


@pytest.fixture(scope="module")
def blocked_runs(small_bag, faulty_bag, tmp_path_factory):  # noqa: F811
    """``flight-fdi run`` with a recorder whose teardown blocks, --teardown-timeout 1: the text
    output with the report (nominal flight) and --json --fail-on-fault --no-report (faulty
    flight), at once: name -> (status, stdout, stderr, output folder)."""
    root = tmp_path_factory.mktemp("blocked_run")
    cases = {"text": (small_bag, []),
             "json": (faulty_bag, ["--json", "--fail-on-fault", "--no-report"])}
    procs = {}
    try:
        for name, (bag, opts) in cases.items():
            cmd = ["run", str(bag), "--out", str(root / name), "--no-progress",
                   "--teardown-timeout", "1", *opts]
            procs[name] = subprocess.Popen([sys.executable, "-c", _CHILD, *cmd],
                                           stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                           text=True)
        return {name: (proc.wait(timeout=300), *proc.communicate(timeout=30), root / name)
                for name, proc in procs.items()}
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()


def _warn_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if "[WARN]" in ln]


@pytest.mark.timeout(400)  # (the fixture's two runs, under load)
def test_a_timed_out_teardown_still_prints_the_result_and_writes_the_report(blocked_runs):
    from flight_fdi.cli.analyze import format_result

    rc, out, err, folder = blocked_runs["text"]
    assert rc == 0, err
    assert "teardown blocked" in err
    res = json.loads((folder / "result.json").read_text())
    index = folder / "report" / "index.html"
    assert out == (f"{format_result(res)}\n\nrecording and result.json in {folder}/\n"
                   f"report (figures and verdict): {index}\n")  # never returned
    assert index.is_file() and "<html" in index.read_text().lower()
    assert _warn_lines(err) == [
        "[WARN] [flight_fdi_pipeline]: the middleware teardown did not end within 1 s "
        "(destroying node recorder_node) after the pipeline's work was complete (recording "
        "closed, result written); completing the command without it. Stacks:",
        "[WARN] [flight_fdi_pipeline]: exiting with status 0 without the middleware teardown"]
    assert "Traceback" not in err


@pytest.mark.timeout(400)
def test_a_timed_out_teardown_keeps_the_json_output_and_the_fault_status(blocked_runs):
    from flight_fdi.cli.analyze import EXIT_FAULT, FAULT_VERDICTS

    rc, out, err, folder = blocked_runs["json"]
    res = json.loads((folder / "result.json").read_text())
    assert res["post_flight"]["verdict"] in FAULT_VERDICTS
    assert rc == EXIT_FAULT, err
    assert json.loads(out) == res and out.count("\n") == 1  # never returned
    assert not (folder / "report").exists()
    assert _warn_lines(err)[-1] == ("[WARN] [flight_fdi_pipeline]: exiting with status 3 "
                                    "without the middleware teardown")
