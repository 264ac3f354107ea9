"""The node pipeline (bag_player -> filter_node -> recorder_node -> smoother_node): on the sample
bags, against ``analyze_flight``, with either executor, as separate processes, and on bad input.

Agreement tolerance with ``analyze_flight`` of the same bag: identical verdicts, elements,
hypotheses, counts and flags; times (``*_s``) within 1e-6 s (stamps travel through the messages
as float seconds, ~0.2 us resolution at 1.7e9 s); every other number within a relative 1e-6.
"""
from __future__ import annotations

import importlib.util
import json
import signal
import subprocess
from concurrent.futures import ProcessPoolExecutor
from multiprocessing import get_context
from pathlib import Path

import harness  # noqa: F401  (private ROS domain, inherited by the subprocesses)
import pytest

from flight_fdi.bagio.errors import BagError
from flight_fdi.nodes.errors import ParameterError

REPO = Path(__file__).resolve().parents[2]
SAMPLES = ("nominal", "accel_fault_500s", "gyro_fault_500s")
EXE_DIR = REPO / "install" / "flight_fdi" / "lib" / "flight_fdi"


def _load(name: str):
    spec = importlib.util.spec_from_file_location(f"_{name}", Path(__file__).with_name(
        f"{name}.py"))
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


assert_same_result = _load("test_smoother").assert_same_result


def expected_result(bag: Path | str, channel: str = "x") -> dict:
    """``flight-fdi analyze --json`` of the bag (the core, without ROS)."""
    from flight_fdi.bagio import read_flight
    from flight_fdi.core.analysis import AnalysisConfig, analyze_flight
    from flight_fdi.core.models import get_model

    f = read_flight(bag, channel)
    return analyze_flight(get_model("ins_channel"), f.t_ins, f.v_ins, f.t_ref, f.v_ref, f.r_ref,
                          AnalysisConfig(), bag=str(bag), channel=channel, t0=f.t0)


@pytest.fixture(scope="module")
def sample_runs(tmp_path_factory):
    """The pipeline on the three sample bags, two at a time in worker processes (each pipeline
    is isolated in its own process and private context)."""
    from flight_fdi.nodes.pipeline import run_pipeline_detailed

    out = tmp_path_factory.mktemp("samples")
    with ProcessPoolExecutor(max_workers=2, mp_context=get_context("spawn")) as pool:
        futures = {name: pool.submit(run_pipeline_detailed, str(REPO / "bags" / name),
                                       str(out / name))
                   for name in SAMPLES}
        return {name: f.result(timeout=300) for name, f in futures.items()}


@pytest.fixture(scope="module")
def short_bag(tmp_path_factory):
    """A 100 s flight with a gyro drift step of 20 deg/h at 50 s."""
    from flight_fdi.sim import SimConfig, parse_fault, simulate_to_bag

    path = tmp_path_factory.mktemp("short") / "flight"
    simulate_to_bag(SimConfig(duration_s=100.0, seed=7,
                              faults=(parse_fault("gyro:step:t=50,mag=20deg/h"),)), str(path))
    return path


# ------------------------------------------------------------------------------ sample bags

@pytest.mark.parametrize("name", SAMPLES)
def test_sample_bag_detection_and_isolation(sample_runs, name):
    from flight_fdi.bagio import read_flight

    run = sample_runs[name]
    res = run.result
    faults = read_flight(REPO / "bags" / name, "x").faults  # the simulator's ground truth
    post, inf = res["post_flight"], res["in_flight"]
    assert res["bag"] == str(REPO / "bags" / name) and res["samples"] == 10000
    assert run.recorded == {"/fdi/innovation": 10000, "/fdi/state": 10000, "/fdi/model": 1}
    assert run.messages_played == 60000 and run.ack_timeouts == 0
    assert json.loads(run.result_json.read_text()) == json.loads(json.dumps(res))
    from flight_fdi.schema import validate_result

    validate_result(json.loads(run.result_json.read_text()))  # result.json follows the schema
    if not faults:
        assert inf["alarms"] == [] and inf["first_alarm_s"] is None
        assert post["verdict"] == "no_fault" and post["glr"]["hypothesis"] == "none"
        return
    (fault,) = faults
    assert fault["start_s"] < inf["first_alarm_s"] < fault["start_s"] + 100
    assert all(a["start_s"] > fault["start_s"] for a in inf["alarms"])
    stats = post["glr"]["statistics"]
    assert stats[fault["hypothesis"]] == pytest.approx(max(stats.values()), rel=1e-6)
    if fault["hypothesis"] == "gyro_drift_step":  # its twin: an accelerometer ramp
        assert post["verdict"] == "ambiguous" and post["fault"] is None
        found = next(c for c in post["candidates"] if c["hypothesis"] == fault["hypothesis"])
    else:
        assert post["verdict"] == "failure" and post["element"] == fault["element"]
        found = post["fault"]
    assert found["onset_s"] == pytest.approx(fault["start_s"], abs=2.0)
    assert found["magnitude"] == pytest.approx(fault["magnitude"], rel=0.1)


@pytest.mark.parametrize("name", SAMPLES)
def test_sample_bag_result_agrees_with_analyze(sample_runs, name):
    assert_same_result(sample_runs[name].result, expected_result(REPO / "bags" / name))


# ------------------------------------------------------------------------------ executors

def test_both_executors_and_storages_give_the_analysis_result(short_bag, tmp_path):
    from flight_fdi.nodes.pipeline import run_pipeline

    expected = expected_result(short_bag)
    events = run_pipeline(short_bag, tmp_path / "events", executor="events")
    single = run_pipeline(short_bag, tmp_path / "single", executor="single", storage="sqlite3")
    assert single == events  # the same filter on the same samples: bit for bit
    assert_same_result(events, expected)
    stats = events["post_flight"]["glr"]["statistics"]
    assert stats["gyro_drift_step"] == pytest.approx(max(stats.values()), rel=1e-6)
    assert (tmp_path / "events" / "recording" / "recording_0.mcap").exists()
    assert (tmp_path / "single" / "recording" / "recording_0.db3").exists()


def test_bad_input(tmp_path, short_bag):
    from flight_fdi.nodes.pipeline import PipelineError, run_pipeline

    with pytest.raises(BagError, match="does not exist"):
        run_pipeline(tmp_path / "missing", tmp_path / "out")
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "metadata.yaml").write_text("not: [a bag\n")
    with pytest.raises(BagError, match="cannot be opened"):
        run_pipeline(junk, tmp_path / "out")
    with pytest.raises(ParameterError, match="channel"):
        run_pipeline(short_bag, tmp_path / "out", channel="z")
    (tmp_path / "out" / "recording").mkdir(parents=True)
    (tmp_path / "out" / "recording" / "x.txt").write_text("precious")
    with pytest.raises(PipelineError, match="RecorderNode.*'output'.*exists"):
        run_pipeline(short_bag, tmp_path / "out")
    with pytest.raises(PipelineError, match="RecorderNode.*'output'.*not a bag"):
        run_pipeline(short_bag, tmp_path / "out", overwrite=True)
    with pytest.raises(PipelineError, match="FilterNode.*'model'"):
        run_pipeline(short_bag, tmp_path / "out2", model=str(tmp_path / "no_such_model.yaml"))
    assert (tmp_path / "out" / "recording" / "x.txt").read_text() == "precious"


# ------------------------------------------------------------------------------ processes

def _start(exe: str, cwd: Path, *params: str) -> subprocess.Popen:
    path = EXE_DIR / exe
    assert path.exists(), "run make setup first (install/ is missing)"
    cmd = ["bash", "-c", 'source "$0" >/dev/null && exec "$@"',
           str(REPO / "install" / "setup.bash"), str(path), "--ros-args"]
    for p in params:
        cmd += ["-p", p]
    return subprocess.Popen(cmd, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)


def test_filter_and_recorder_as_separate_processes(ros, short_bag, tmp_path):
    """The installed filter_node and recorder_node executables, fed by the player in this
    process, record what the in-process pipeline records: the same analysis result."""
    from diagnostic_msgs.msg import DiagnosticArray

    from flight_fdi.nodes.bag_player import BagPlayer
    from flight_fdi.nodes.smoother_node import SmootherNode

    counts: dict[str, int] = {}

    def on_diag(msg):
        for st in msg.status:
            if st.name.startswith("recorder_node"):
                counts.update({kv.key[:-6]: int(kv.value) for kv in st.values
                               if kv.key.endswith(" count")})

    probe = ros.node("probe")
    probe.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    procs = [_start("filter_node", tmp_path, "channels:=[x]", "input_qos:=reliable"),
             _start("recorder_node", tmp_path, "output:=rec")]
    try:
        # the recorder has matched the filter once it recorded the filter's latched model
        ros.spin_until(lambda: counts.get("/fdi/model") == 1, timeout=60,
                       what="the recorder recording the filter's model")
        player = ros.node(BagPlayer, {"bag": str(short_bag), "fast": True,
                                      "ack_topic": "fdi/state", "publish_clock": False})
        ros.spin_until(player.done, timeout=120, what="the replay")
        ros.spin_until(lambda: counts.get("/fdi/state", 0) >= player.acks == 1000
                       and counts.get("/fdi/innovation") == counts["/fdi/state"],
                       timeout=30, what="the recorder receiving every filter output")
        for proc in procs:
            proc.send_signal(signal.SIGINT)
        assert [proc.wait(timeout=30) for proc in procs] == [0, 0]
    finally:
        for proc in procs:
            if proc.poll() is None:
                proc.kill()
            proc.communicate(timeout=20)
    assert player.ack_timeouts == 0 and counts["/fdi/state"] == 1000
    smoother = ros.node(SmootherNode, {"bag": str(tmp_path / "rec"), "publish_smoothed": False,
                                       "flight_start_s": player.first_stamp_ns * 1e-9})
    ros.spin_until(smoother.done, timeout=30)
    assert not smoother.last.error
    res = dict(smoother.last.result, bag=str(short_bag))
    assert_same_result(res, expected_result(short_bag))


def test_the_pipeline_log_level_does_not_outlive_its_context():
    """``--log-level`` sets rcutils' process-wide default level: the private context puts it
    back, or every node created later in the process (e.g. the next test's filter_node) would
    stay silent on /rosout below that level."""
    import rclpy.logging

    from flight_fdi.nodes.pipeline import _private_context

    before = rclpy.logging.get_logger_effective_level("filter_node")
    with _private_context(["--log-level", "fatal"]):
        assert rclpy.logging.get_logger_effective_level("filter_node") == \
            rclpy.logging.LoggingSeverity.FATAL
    assert rclpy.logging.get_logger_effective_level("filter_node") == before


def test_ctrl_c_during_flight_fdi_run_is_one_line_and_exit_130(tmp_path):
    """SIGINT in the middle of the replay (after the first in-flight alarm is logged) stops the
    run between callbacks: exit 130 and one line, no callback traceback from the executor."""
    proc = subprocess.Popen([str(REPO / ".venv" / "bin" / "flight-fdi"), "run",
                             str(REPO / "bags" / "accel_fault_500s"), "--out", str(tmp_path),
                             "--no-report"], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    try:
        for line in proc.stderr:
            if "alarm raised" in line:
                break
        else:
            pytest.fail("the run ended without logging an alarm")
        proc.send_signal(signal.SIGINT)
        out, err = proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.communicate(timeout=20)
    assert proc.returncode == 130
    lines = [ln for ln in err.splitlines() if "alarm raised" not in ln]
    assert lines == ["flight-fdi: interrupted"], err
    assert "post flight" not in out
