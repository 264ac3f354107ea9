"""The end of ``flight-fdi run``'s one-process pipeline (nodes/pipeline.py): never a hang, nothing
lost.

* A stage that stops making progress ends the run with one line naming it and a non-zero exit;
  the recorder's bag is closed cleanly and holds what was recorded (``stall_timeout_s``).
* The middleware teardown comes after the work -- the recording closed and result.json written
  -- and is bounded (``teardown_timeout``, runner.TeardownWatchdog). As in test_runner.py, a
  child process runs a pipeline whose teardown blocks for good (GIL released, as in
  ``rcl_node_fini``; and GIL held) and must still end, with the pipeline's own status; without
  the bound it does not end.
"""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import harness  # noqa: F401  (private ROS domain, inherited by the subprocesses)
import pytest
import yaml

from flight_fdi.nodes.errors import ParameterError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def small_bag(tmp_path_factory) -> Path:
    """A 20-s flight (1200 messages played, 200 filter steps)."""
    from flight_fdi.sim import SimConfig, simulate_to_bag

    path = tmp_path_factory.mktemp("small") / "flight"
    simulate_to_bag(SimConfig(duration_s=20.0, seed=11), str(path))
    return path


def _metadata(bag: Path) -> dict:
    return yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


def _assert_closed_cleanly(bag: Path) -> int:
    """The recording is complete (closed cleanly) and readable; its message count."""
    from rosbags.rosbag2 import Reader

    meta = _metadata(bag)
    assert meta["custom_data"]["closed_cleanly"] == "true"
    with Reader(bag) as reader:
        n = sum(1 for _ in reader.messages())
    assert n == meta["message_count"] > 0
    return n


# ------------------------------------------------------------------------------ the stall watch

def test_the_stall_watch_names_a_stage_with_work_waiting_and_no_progress():
    from flight_fdi.nodes.pipeline import StallWatch

    now = [0.0]
    watch = StallWatch(1.0, clock=lambda: now[0], max_step_s=0.25)

    def at(t, stages):
        now[0] = t
        return watch.check(stages)

    assert at(0.0, [("player", 10, 5), ("filter", 3, 7)]) is None
    for t in (0.25, 0.5, 0.75):  # the player moves, the filter takes nothing
        assert at(t, [("player", 10 + int(8 * t), 3), ("filter", 3, 9)]) is None
    assert at(1.0, [("player", 20, 3), ("filter", 3, 9)]) == \
        "filter made no progress for 1 s (9 messages waiting for it, 3 done)"
    # progress, or nothing to do, restarts a stage's clock
    assert at(1.25, [("player", 20, 0), ("filter", 4, 9)]) is None
    assert at(1.5, [("player", 20, 1), ("filter", 4, 0)]) is None
    # a long gap between two checks (a callback held the loop) counts max_step_s only
    for t in (9.0, 9.25):  # 0.25 s since 1.5, then 0.25 and 0.25
        assert at(t, [("player", 20, 1), ("filter", 4, 0)]) is None
    assert at(9.5, [("player", 20, 1), ("filter", 4, 0)]) == \
        "player made no progress for 1 s (1 messages waiting for it, 20 done)"


@pytest.mark.parametrize("option, value", [
    ("stall_timeout_s", 0), ("stall_timeout_s", float("nan")), ("stall_timeout_s", "5"),
    ("stall_timeout_s", None), ("teardown_timeout", -1.0), ("teardown_timeout", True),
    ("timeout_s", float("inf"))])
def test_the_bounds_are_validated_before_anything_runs(tmp_path, option, value):
    from flight_fdi.nodes.pipeline import run_pipeline

    with pytest.raises(ParameterError, match=f"invalid {option} .*; allowed: a number of "
                                             "seconds > 0"):
        run_pipeline(tmp_path / "no_bag", tmp_path / "out", **{option: value})
    assert not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------ stalls

def test_a_filter_that_stops_taking_its_input_ends_the_run_naming_it(small_bag, tmp_path,
                                                                     monkeypatch):
    from flight_fdi.nodes.filter_velocity import VelocityMode
    from flight_fdi.nodes.pipeline import PipelineError, run_pipeline

    real = VelocityMode._on_ins

    def stops_after_100(self, data):
        if self.counters["received_ins"] < 100:
            real(self, data)

    monkeypatch.setattr(VelocityMode, "_on_ins", stops_after_100)
    with pytest.raises(PipelineError, match=r"^pipeline stalled while replaying the bag: "
                       r"filter_node made no progress for 1 s \(\d+ messages waiting for it, "
                       r"1\d\d done\)$"):
        run_pipeline(small_bag, tmp_path, stall_timeout_s=1.0)
    _assert_closed_cleanly(tmp_path / "recording")  # what was recorded is kept
    assert not (tmp_path / "result.json").exists()


def test_a_recorder_that_stops_recording_is_one_line_and_exit_1(small_bag, tmp_path, monkeypatch,
                                                               capfd):
    """Through ``flight-fdi run`` (its one-line error and exit status); the recording holds the
    50 messages recorded before the stall, closed cleanly."""
    import functools

    from flight_fdi.cli.main import main
    from flight_fdi.nodes import pipeline
    from flight_fdi.nodes.recorder_node import RecorderNode

    real = RecorderNode._on_message

    def stops_after_50(self, topic, msgtype, data):
        if self.bag.message_count < 50:
            real(self, topic, msgtype, data)

    monkeypatch.setattr(RecorderNode, "_on_message", stops_after_50)
    monkeypatch.setattr(pipeline, "run_pipeline_detailed",
                        functools.partial(pipeline.run_pipeline_detailed, stall_timeout_s=1.0))
    code = main(["run", str(small_bag), "--out", str(tmp_path), "--no-report", "--no-progress"])
    err = capfd.readouterr().err.splitlines()
    assert code == 1
    (line,) = [ln for ln in err if "error" in ln]
    assert line.startswith("flight-fdi run: error: pipeline stalled while ")
    assert ": recorder_node made no progress for 1 s (" in line
    assert not any("Traceback" in ln for ln in err)
    assert _assert_closed_cleanly(tmp_path / "recording") == 50
    assert not (tmp_path / "result.json").exists()


# ------------------------------------------------------------------------------ teardown

_CHILD = """
import ctypes, json, sys, threading
from pathlib import Path
import rclpy
from flight_fdi.nodes import pipeline
from flight_fdi.nodes.recorder_node import RecorderNode

how, where, stall, timeout, bag, out = sys.argv[1:]
out = Path(out)

def block():
    meta = (out / "recording" / "metadata.yaml").read_text()
    result = out / "result.json"
    print("teardown blocked; recording closed:", "closed_cleanly: 'true'" in meta,
          "; result:", json.loads(result.read_text())["post_flight"]["verdict"]
          if result.exists() else None, flush=True)
    if how == "gil":              # blocked in C with the GIL held (PyDLL keeps it)
        ctypes.PyDLL(None).pause()
    threading.Event().wait()      # blocked, GIL released (as in rcl_node_fini)

def wrap(real):
    def blocking(*args, **kwargs):
        real(*args, **kwargs)
        block()
    return blocking

if where == "recorder":
    RecorderNode.destroy_node = wrap(RecorderNode.destroy_node)
else:
    rclpy.shutdown = wrap(rclpy.shutdown)
if stall == "stall":
    real = RecorderNode._on_message
    RecorderNode._on_message = lambda self, *a: (real(self, *a)
                                                 if self.bag.message_count < 50 else None)
try:
    pipeline.run_pipeline(bag, out, stall_timeout_s=1.0 if stall == "stall" else 60.0,
                          teardown_timeout=None if timeout == "none" else float(timeout))
finally:
    print("returned", flush=True)
"""

#: name -> (GIL, where the teardown blocks, stall, teardown_timeout)
_CASES = {"released": ("released", "recorder", "-", "1.0"),
          "context": ("released", "context", "-", "1.0"),
          "gil": ("gil", "recorder", "-", "1.0"),
          "failed": ("released", "recorder", "stall", "1.0"),
          "unbounded": ("released", "recorder", "-", "none")}


@pytest.fixture(scope="module")
def blocked_teardowns(small_bag, tmp_path_factory):
    """The five cases at once, each in its own process: name -> (status, stdout, stderr); the
    unbounded one is killed once it has not ended 5 s after its teardown blocked (status
    None)."""
    out = tmp_path_factory.mktemp("blocked")
    procs = {name: subprocess.Popen([sys.executable, "-c", _CHILD, *case, str(small_bag),
                                     str(out / name)], stdout=subprocess.PIPE,
                                    stderr=subprocess.PIPE, text=True)
             for name, case in _CASES.items()}
    results = {}
    try:
        unbounded = procs.pop("unbounded")
        first = unbounded.stdout.readline()  # the teardown is blocked (or the child died: "")
        try:
            unbounded.wait(timeout=5.0)      # the assertion's window: it must NOT end
            status = unbounded.returncode
        except subprocess.TimeoutExpired:
            status = None
        unbounded.kill()
        rest, err = unbounded.communicate(timeout=30)
        results["unbounded"] = (status, first + rest, err)
        for name, proc in procs.items():
            results[name] = (proc.wait(timeout=120), *proc.communicate(timeout=30))  # (bounds)
    finally:
        for proc in procs.values():
            if proc.poll() is None:
                proc.kill()
                proc.communicate()
    return results


_DONE = "teardown blocked; recording closed: True ; result: no_fault\n"


def test_a_blocked_teardown_after_the_result_ends_with_status_0(blocked_teardowns):
    rc, out, err = blocked_teardowns["released"]
    assert rc == 0, err
    assert out == _DONE, err  # the recording and result.json complete before; never returned
    warn = [ln for ln in err.splitlines() if "[WARN]" in ln]
    assert warn == ["[WARN] [flight_fdi_pipeline]: the middleware teardown did not end within "
                    "1 s (destroying node recorder_node) after the pipeline's work was complete "
                    "(recording closed, result written); exiting with status 0 without it. "
                    "Stacks:"]
    assert "in blocking" in err and "in _teardown" in err  # the stack says where


def test_a_context_shutdown_that_blocks_is_named(blocked_teardowns):
    rc, out, err = blocked_teardowns["context"]
    assert rc == 0, err
    assert out == _DONE, err
    assert "did not end within 1 s (shutting down the context) after the pipeline's work was " \
           "complete" in err


def test_a_teardown_blocked_with_the_gil_held_still_ends_with_the_stacks(blocked_teardowns):
    rc, out, err = blocked_teardowns["gil"]
    assert rc == 1, err                 # faulthandler's watchdog: no status to give
    assert out == _DONE, err
    assert "Timeout (0:00:02)!" in err and "in blocking" in err


def test_a_blocked_teardown_after_a_failure_keeps_its_status_and_says_why(blocked_teardowns):
    rc, out, err = blocked_teardowns["failed"]
    assert rc == 1, err
    assert out == "teardown blocked; recording closed: True ; result: None\n"
    assert "(destroying node recorder_node) after the pipeline failed (pipeline stalled while " \
           in err and "recorder_node made no progress for 1 s" in err
    assert "exiting with status 1 without it" in err


def test_without_the_bound_the_blocked_teardown_does_not_end(blocked_teardowns):
    rc, out, err = blocked_teardowns["unbounded"]
    assert out == _DONE and rc is None, err
