"""smoother_node: post-flight analysis of a recording, its outputs, the ~/analyze service and bad
input (in-process, plus the executable in batch mode).

The recordings here are written from the core's own forward pass over a simulated flight
(``run_analysis``), so the smoother -- which rebuilds the forward pass from the recorded
FilterStates -- must reproduce ``analyze_flight`` of that flight.
"""
from __future__ import annotations

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import harness  # noqa: F401  (private ROS domain)
import numpy as np
import pytest

from flight_fdi.nodes.errors import ParameterError

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def flight(tmp_path_factory):
    """A 150 s simulated flight with an accelerometer step at 75 s, and its analysis."""
    from flight_fdi.bagio import read_flight
    from flight_fdi.core.analysis import AnalysisConfig, run_analysis
    from flight_fdi.core.models import get_model
    from flight_fdi.sim import SimConfig, parse_fault, simulate_to_bag

    d = tmp_path_factory.mktemp("smoother")
    simulate_to_bag(SimConfig(duration_s=150.0, seed=3,
                              faults=(parse_fault("accel:step:t=75,mag=0.02"),)), str(d / "in"))
    f = read_flight(d / "in", "x")
    model = get_model("ins_channel")
    analysis = run_analysis(model, f.t_ins, f.v_ins, f.t_ref, f.v_ref, f.r_ref, AnalysisConfig(),
                            bag="in", channel="x", t0=f.t0)
    return {"dir": d, "flight": f, "model": model, "analysis": analysis}


def write_recording(path: Path, model, fwd, channel: str = "x", resets: tuple = (),
                    with_model: bool = True, skip: tuple = (), frame_id: str = "") -> None:
    """A recorder_node-like bag: fdi/model once, one fdi/state per forward step (serialized by
    rosbags, as they travel on the wire)."""
    from flight_fdi.bagio import get_typestore, open_writer
    from flight_fdi.core.kalman import GateConfig

    store = get_typestore()
    T = store.types
    gate = GateConfig()

    def header(t: float):
        ns = int(round(t * 1e9))
        return T["std_msgs/msg/Header"](
            stamp=T["builtin_interfaces/msg/Time"](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id=frame_id)

    def arr(a) -> np.ndarray:
        return np.ascontiguousarray(np.asarray(a, dtype=float).reshape(-1))

    with open_writer(path, compression="none") as bag:
        if with_model:
            names = list(model.params)
            info = T["flight_fdi_msgs/msg/ModelInfo"](
                header=header(fwd.t[0]), channel=channel, model_name=model.name,
                state_names=list(model.state_names), state_units=list(model.state_units),
                measurement_names=list(model.measurement_names), n=model.n, m=model.m, p=0,
                a=arr(model.A), qc=arr(model.Qc), h=arr(model.H), r=arr(model.R),
                p0=arr(model.P0), b=np.zeros(0), scale=arr(model.scale), param_names=names,
                param_values=arr([model.params[k] for k in names]), gate_rule=gate.rule,
                gate_probability=gate.probability, alarm_m=gate.alarm_m, alarm_n=gate.alarm_n,
                gate_action=gate.action)
            bag.add_topic("/fdi/model", "flight_fdi_msgs/msg/ModelInfo", qos="transient_local")
            bag.write("/fdi/model", "flight_fdi_msgs/msg/ModelInfo", info, int(fwd.t[0] * 1e9))
        for k in range(len(fwd.t)):
            if k in skip:  # lost by the recorder
                continue
            reset = k == 0 or k in resets
            msg = T["flight_fdi_msgs/msg/FilterState"](
                header=header(fwd.t[k]), channel=channel, state_names=list(model.state_names),
                x=arr(fwd.x[k]), p=arr(fwd.P[k]), z=arr(fwd.z[k]), r=arr(fwd.R[k]),
                h=arr(fwd.H[k]), u=np.zeros(0), dt=0.0 if reset else float(fwd.dt[k]),
                fused=bool(fwd.fused[k]), gated=bool(fwd.exceeded[k]), reset=reset)
            bag.write("/fdi/state", "flight_fdi_msgs/msg/FilterState", msg, int(fwd.t[k] * 1e9))


def _unordered_ambiguity(result: dict) -> dict:
    """``result`` with an ambiguous GLR pair as an unordered pair: the two candidates' statistics
    agree to ~1e-14 (e.g. a gyro drift step and an accelerometer bias ramp, which make the same
    velocity error), so which one GLR ranks first is decided by rounding, and the ROS pipeline
    (forward pass rebuilt from the recording) and ``analyze`` (the forward pass itself) round
    differently. The candidates are sorted by hypothesis, the headline compared as its words,
    the disagreement note without the element GLR names first, and GLR's per-hypothesis
    statistics stand for its first/runner-up fields."""
    pf = result.get("post_flight") if isinstance(result, dict) else None
    if not isinstance(pf, dict) or pf.get("isolation") != "ambiguous":
        return result
    pf = dict(pf, candidates=sorted(pf["candidates"], key=lambda c: c["hypothesis"]),
              headline=sorted(pf["headline"].split()))
    if isinstance(pf.get("disagreement"), str):  # "... GLR ... names <the first of the pair>"
        pf["disagreement"] = pf["disagreement"].rsplit(" names ", 1)[0]
    if isinstance(pf.get("glr"), dict):
        pf["glr"] = {k: v for k, v in pf["glr"].items()
                     if k in ("isolation", "statistics", "threshold", "residual")}
    return dict(result, post_flight=pf)


def assert_same_result(got: dict, expected: dict, time_tol: float = 1e-6,
                       rel_tol: float = 1e-6) -> None:
    """The schema keys of ``expected`` with equal strings / ints / bools, and floats within
    rel_tol (times ``*_s`` within time_tol seconds: stamps travel as float seconds); an
    ambiguous pair compared unordered (:func:`_unordered_ambiguity`)."""
    got, expected = _unordered_ambiguity(got), _unordered_ambiguity(expected)

    def walk(a, b, path):
        if isinstance(b, dict):
            for k in b:
                if k == "input":  # analyze's extra input statistics, not part of the schema
                    continue
                assert k in a, f"{path}/{k} missing"
                walk(a[k], b[k], f"{path}/{k}")
        elif isinstance(b, list):
            assert len(a) == len(b), f"{path}: {len(a)} != {len(b)}"
            for i, (x, y) in enumerate(zip(a, b)):
                walk(x, y, f"{path}[{i}]")
        elif isinstance(b, float) and not isinstance(b, bool):
            assert isinstance(a, float), f"{path}: {a!r} vs {b!r}"
            tol = time_tol if path.endswith("_s") else rel_tol * max(1.0, abs(b))
            assert abs(a - b) <= tol, f"{path}: {a!r} vs {b!r}"
        else:
            assert a == b, f"{path}: {a!r} vs {b!r}"

    walk(got, expected, "")


# ------------------------------------------------------------------------------ analysis

def test_model_info_round_trip():
    from flight_fdi.core.kalman import GateConfig
    from flight_fdi.core.models import get_model
    from flight_fdi.nodes.convert import model_info_msg, s_to_stamp
    from flight_fdi.core.recording import model_from_info

    model = get_model("ins_channel", tau_a=1800.0)
    gate = GateConfig(rule="seed", alarm_m=2, alarm_n=4, action="reject")
    back, back_gate = model_from_info(model_info_msg(s_to_stamp(1.0), "y", model, gate))
    for name in ("A", "Qc", "H", "R", "P0", "scale"):
        np.testing.assert_array_equal(getattr(back, name), getattr(model, name), err_msg=name)
    assert back.state_names == model.state_names and back.params == dict(model.params)
    assert back_gate == gate


def test_recording_gives_the_analysis_of_the_flight(ros, flight, tmp_path):
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    from flight_fdi.core.analysis import analyze_flight, AnalysisConfig
    from flight_fdi.nodes.result_msgs import post_flight_from_msg
    from flight_fdi.nodes.smoother_node import SmootherNode
    from flight_fdi_msgs.msg import FaultLocalization, SmoothedState

    a, f = flight["analysis"], flight["flight"]
    write_recording(tmp_path / "rec", flight["model"], a.fwd)
    listener = ros.node("listener")
    smoothed: list = []
    listener.create_subscription(SmoothedState, "fdi/smoothed", smoothed.append, 5000)
    node = ros.node(SmootherNode, {"bag": str(tmp_path / "rec"), "flight_start_s": f.t0,
                                   "output_json": str(tmp_path / "r.json"),
                                   "smoothed_queue_depth": 5000})
    ros.spin_until(node.done, timeout=30)
    expected = analyze_flight(flight["model"], f.t_ins, f.v_ins, f.t_ref, f.v_ref, f.r_ref,
                              AnalysisConfig(), bag=str(tmp_path / "rec"), channel="x", t0=f.t0)
    written = json.loads((tmp_path / "r.json").read_text())
    from flight_fdi.schema import validate_result

    validate_result(written)  # the smoother node's result follows the versioned schema
    assert_same_result(written, expected)
    assert written["post_flight"]["fault"]["sensor"] == "accelerometer"
    post = written["post_flight"]
    assert post["glr"]["hypothesis"] == "accel_bias_step" and post["element"] == "accel_bias"
    assert post["onset_s"] == pytest.approx(75.0, abs=2.0)
    assert post["magnitude"] == pytest.approx(0.02, rel=0.1)

    # a late subscriber still gets the result (reliable, transient local)
    late: list = []
    qos = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
    listener.create_subscription(FaultLocalization, "fdi/fault_localization", late.append, qos)
    ros.spin_until(lambda: late, what="the latched FaultLocalization")
    msg = late[0]
    assert msg.verdict == FaultLocalization.VERDICT_FAILURE and msg.verdict_name == "failure"
    assert msg.element == "accel_bias" and msg.samples == len(a.fwd.t)
    assert msg.flight_start.sec == int(f.t0)
    # the person's terms travel on the message too (ros2 topic echo shows them)
    assert (msg.sensor, msg.kind, msg.isolation) == ("accelerometer", "step", "single")
    assert msg.headline == written["post_flight"]["headline"] and "accelerometer" in msg.headline
    from_msg = post_flight_from_msg(msg)  # (the message carries the seed/GLR fields)

    def common(e, g):
        return {k: common(v, g[k]) if isinstance(v, dict) else v for k, v in e.items() if k in g}
    assert_same_result(from_msg, common(expected["post_flight"], from_msg))

    # one SmoothedState per step, x(i/N) of the core's two-filter smoother
    ros.spin_until(lambda: len(smoothed) == len(a.fwd.t), what="all SmoothedState")
    xs = np.array([m.x_smoothed for m in smoothed])
    np.testing.assert_allclose(xs, a.bwd.x_s, rtol=1e-6, atol=1e-12 * np.abs(a.bwd.x_s).max())
    mid = smoothed[len(smoothed) // 2]
    assert mid.dof == a.bwd.dof[len(smoothed) // 2] and len(mid.v_tilde) == 4
    # v~ and dD decompose J: sum over informative elements of v~^2 / dD is the total J
    informative = np.isfinite(np.array(mid.delta_d))
    vt, dd = np.array(mid.v_tilde)[informative], np.array(mid.delta_d)[informative]
    assert np.sum(vt * vt / dd) == pytest.approx(mid.j_terms[-1], rel=1e-6)


def test_analyze_service_reruns_on_a_new_bag_and_channel(ros, flight, tmp_path):
    from rclpy.parameter import Parameter
    from std_srvs.srv import Trigger

    from flight_fdi.nodes.smoother_node import SmootherNode

    a = flight["analysis"]
    write_recording(tmp_path / "rec_y", flight["model"], a.fwd, channel="y")
    node = ros.node(SmootherNode, {"publish_smoothed": False})  # no bag yet: waits
    client = ros.node("caller").create_client(Trigger, "/smoother_node/analyze")
    assert client.wait_for_service(timeout_sec=5)
    future = client.call_async(Trigger.Request())
    ros.spin_until(future)
    assert not future.result().success and "no bag given" in future.result().message
    assert node.runs == 1 and node.done.done()
    node.set_parameters([Parameter("bag", value=str(tmp_path / "rec_y")),
                         Parameter("channel", value="y")])
    future = client.call_async(Trigger.Request())
    ros.spin_until(future, timeout=30)
    assert future.result().success and node.runs == 2
    assert "failure: accelerometer y: bias step of +2" in future.result().message
    assert node.last.result["channel"] == "y" and node.last.recording.channel == "y"


def test_reset_segments_use_the_longest(ros, flight, tmp_path):
    from flight_fdi.bagio.recording import read_recording

    a = flight["analysis"]
    write_recording(tmp_path / "rec", flight["model"], a.fwd, resets=(200,))
    rec = read_recording(tmp_path / "rec", "x")
    assert rec.problems["segments"] == 2 and len(rec.t) == len(a.fwd.t) - 200
    assert rec.t[0] == pytest.approx(a.fwd.t[200]) and rec.dt[0] == 0.0


def test_missing_states_are_bridged_by_prediction_and_reported(ros, flight, tmp_path):
    """A recording that lost states (a recorder behind its publisher, before KEEP_ALL): the
    smoother predicts across each gap, as the filter does over a reference dropout, and reports
    the gaps instead of refusing the flight."""
    from flight_fdi.core.kalman import ForwardResult
    from flight_fdi.bagio.recording import read_recording
    from flight_fdi.nodes.smoother_node import SmootherNode

    a, f = flight["analysis"], flight["flight"]
    skip = (400, 401, 1000)
    write_recording(tmp_path / "rec", flight["model"], a.fwd, skip=skip)
    rec = read_recording(tmp_path / "rec", "x")
    keep = np.array([k for k in range(len(a.fwd.t)) if k not in skip])
    assert len(rec.t) == keep.size and rec.problems["segments"] == 1
    # the step after a gap predicts over the whole gap: dt = the stamp spacing
    np.testing.assert_allclose(rec.dt[1:], np.diff(a.fwd.t[keep]), atol=1e-6)
    assert [(g["after_s"], g["before_s"], g["missing_states"]) for g in rec.gaps] == [
        (pytest.approx(a.fwd.t[399]), pytest.approx(a.fwd.t[402]), 2),
        (pytest.approx(a.fwd.t[999]), pytest.approx(a.fwd.t[1001]), 1)]
    # the rebuilt prior after the gap is Phi(gap) x(before the gap), the filter's own dropout rule
    fwd = ForwardResult.from_record(rec.model, rec.t, rec.dt, rec.z, rec.R, rec.H, rec.fused,
                                    None, rec.x, rec.P)
    from scipy.linalg import expm

    k = 400  # index in the recording of the first state after the first gap
    Phi = expm(rec.model.A * (a.fwd.t[402] - a.fwd.t[399]))
    np.testing.assert_allclose(fwd.x_prior[k], Phi @ rec.x[k - 1], rtol=1e-9,
                               atol=1e-12 * np.abs(rec.x).max())

    node = ros.node(SmootherNode, {"bag": str(tmp_path / "rec"), "flight_start_s": f.t0,
                                   "publish_smoothed": False})
    ros.spin_until(node.done, timeout=30)
    res = node.last.result
    assert not node.last.error and res["post_flight"]["verdict"] == "failure"
    post = res["post_flight"]
    assert post["glr"]["hypothesis"] == "accel_bias_step" and post["element"] == "accel_bias"
    assert post["onset_s"] == pytest.approx(75.0, abs=2.0)
    gaps = res["recording"]["gaps"]
    assert [g["missing_states"] for g in gaps] == [2, 1]
    assert gaps[0]["after_s"] == pytest.approx(a.fwd.t[399] - f.t0, abs=1e-6)


# ------------------------------------------------------------------------------ bad input

def _diag_level(node) -> bytes:
    return node._statuses()[0].level


@pytest.mark.parametrize("case", ["missing", "garbage", "no_model", "empty_dir"])
def test_missing_or_corrupt_bag_gives_an_error_result_not_a_crash(ros, flight, tmp_path, case):
    from flight_fdi.nodes.smoother_node import SmootherNode

    bag = tmp_path / "bag"
    if case == "garbage":
        write_recording(bag, flight["model"], flight["analysis"].fwd)
        mcap = next(bag.glob("*.mcap"))
        mcap.write_bytes(mcap.read_bytes()[:100] + b"\x00" * 1000)
    elif case == "no_model":
        write_recording(bag, flight["model"], flight["analysis"].fwd, with_model=False)
    elif case == "empty_dir":
        bag.mkdir()
    node = ros.node(SmootherNode, {"bag": str(bag), "output_json": str(tmp_path / "r.json")})
    ros.spin_until(node.done)
    res = json.loads((tmp_path / "r.json").read_text())
    from flight_fdi.schema import validate_result

    validate_result(res)
    assert res["post_flight"]["verdict"] == "insufficient_data" and res["samples"] == 0
    # (the recording is read raw, as the 3-D one: the damaged mcap file is named)
    expected = {"missing": "does not exist", "garbage": "bag.mcap is truncated",
                "no_model": "no topic /fdi/model", "empty_dir": "not a rosbag2 bag"}[case]
    assert expected in res["error"] and expected in node.last.error
    assert "\n" not in res["error"]
    assert _diag_level(node) == b"\x02"  # ERROR


def test_the_smoothers_analysis_runs_without_ros(flight, tmp_path):
    """What the node runs on a recording (``bagio.recording_analysis.smoother_run``) needs no
    rclpy: in a fresh interpreter it imports none and gives the analysis of the flight; a bag it
    cannot analyse is an insufficient_data result with the one-line error, never a raise."""
    from flight_fdi.core.analysis import AnalysisConfig, analyze_flight

    a, f = flight["analysis"], flight["flight"]
    write_recording(tmp_path / "rec", flight["model"], a.fwd)
    code = ("import json, sys\n"
            "from flight_fdi.bagio.recording_analysis import smoother_run\n"
            "run = smoother_run(sys.argv[1], 'x', flight_start_s=float(sys.argv[2]))\n"
            "bad = smoother_run(sys.argv[1] + '_missing', 'y')\n"
            "ros = sorted(m for m in sys.modules if m.startswith(('rclpy', 'flight_fdi.nodes')))\n"
            "print(json.dumps({'result': run.result, 'bad': bad.result, 'error': bad.error,\n"
            "                  'ros': ros}))\n")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "rec"), repr(f.t0)],
                         capture_output=True, text=True, timeout=120,
                         env={**os.environ, "PYTHONPATH": str(REPO)}, check=True)
    got = json.loads(out.stdout)
    assert got["ros"] == []
    expected = analyze_flight(flight["model"], f.t_ins, f.v_ins, f.t_ref, f.v_ref, f.r_ref,
                              AnalysisConfig(), bag=str(tmp_path / "rec"), channel="x", t0=f.t0)
    assert_same_result(got["result"], expected)
    assert got["result"]["post_flight"]["element"] == "accel_bias"
    assert got["bad"]["post_flight"]["verdict"] == "insufficient_data"
    assert "does not exist" in got["error"] and got["bad"]["error"] == got["error"]


def test_invalid_parameters(ros):
    from flight_fdi.nodes.smoother_node import SmootherNode

    for params, pattern in [({"channel": "z"}, "'channel'"),
                            ({"fisher_window": 4}, "'fisher_window'"),
                            ({"glr_false_alarm": 0.0}, "'glr_false_alarm'"),
                            ({"state_topic": ""}, "'state_topic'")]:
        with pytest.raises(ParameterError, match=pattern):
            ros.node(SmootherNode, params)


def test_batch_mode_exit_status(flight, tmp_path):
    """The executable with exit_when_done: 0 and the JSON for a good recording, 1 and an error
    line (no traceback) for a missing one."""
    write_recording(tmp_path / "rec", flight["model"], flight["analysis"].fwd)
    env = dict(os.environ, PYTHONPATH=str(REPO))
    for bag, status in ((tmp_path / "rec", 0), (tmp_path / "missing", 1)):
        proc = subprocess.run(
            [sys.executable, "-m", "flight_fdi.nodes.smoother_node", "--ros-args",
             "-p", f"bag:={bag}", "-p", f"output_json:={tmp_path / 'out.json'}",
             "-p", "exit_when_done:=true", "-p", "publish_smoothed:=false"],
            capture_output=True, text=True, timeout=60, env=env, cwd=tmp_path)
        assert proc.returncode == status, proc.stderr
        assert "Traceback" not in proc.stderr
        res = json.loads((tmp_path / "out.json").read_text())
        if status:
            assert "does not exist" in proc.stderr and res["error"]
        else:
            assert "failure: accelerometer x: bias step" in proc.stderr
            assert math.isfinite(res["post_flight"]["glr"]["statistic"])
    proc = subprocess.run([sys.executable, "-m", "flight_fdi.nodes.smoother_node", "--ros-args",
                           "-p", "exit_when_done:=true"], capture_output=True, text=True,
                          timeout=60, env=env, cwd=tmp_path)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr
    assert "exit_when_done needs a 'bag'" in proc.stderr


def test_stacked_reference_rows_merge_into_the_information_equivalent_row():
    """A FilterState of a multi-reference filter (k stacked rows) is read as one row that gives
    the same posterior; a prediction-only state as an unfused step; other shapes are refused."""
    from types import SimpleNamespace

    from flight_fdi.core.kalman import KalmanFilter
    from flight_fdi.core.models import ins_channel
    from flight_fdi.core.recording import measurement_of

    model = ins_channel()
    h = [1.0, 0.0, 0.0, 0.0]
    z = [0.3, 0.1, 0.25]
    r = [0.01, 0.04, 0.02]
    R3 = np.diag(r)
    msg = SimpleNamespace(z=z, r=R3.ravel().tolist(), h=h * 3)
    zm, Rm, Hm = measurement_of(msg, model)
    stacked, merged = KalmanFilter(model), KalmanFilter(model)
    stacked.predict(0.1)
    merged.predict(0.1)
    stacked.update(np.array(z), R=R3, H=np.array([h] * 3))
    merged.update(zm, R=Rm, H=Hm)
    np.testing.assert_allclose(merged.x, stacked.x, rtol=1e-10, atol=1e-15)
    np.testing.assert_allclose(merged.P, stacked.P, rtol=1e-9, atol=1e-20)

    empty = measurement_of(SimpleNamespace(z=[], r=[], h=[]), model)
    assert empty is not None and empty[0].shape == (1,)
    assert measurement_of(SimpleNamespace(z=[1.0], r=[0.01], h=[1.0, 0.0]), model) is None
    with pytest.raises(ValueError, match="not stacked copies"):
        measurement_of(SimpleNamespace(z=[1.0, 2.0], r=[0.01, 0, 0, 0.01],
                                       h=[1.0, 0, 0, 0, 0, 1.0, 0, 0]), model)


def test_outputs_carry_the_recorded_frame(ros, flight, tmp_path):
    """fdi/fault_localization and fdi/smoothed have the frame_id of the recorded states (the
    filter's navigation frame, its frame_id parameter)."""
    from flight_fdi.nodes.smoother_node import SmootherNode
    from flight_fdi_msgs.msg import FaultLocalization, SmoothedState
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    a = flight["analysis"]
    write_recording(tmp_path / "rec", flight["model"], a.fwd, frame_id="nav")
    listener = ros.node("listener")
    smoothed: list = []
    result: list = []
    listener.create_subscription(SmoothedState, "fdi/smoothed", smoothed.append, 5000)
    listener.create_subscription(FaultLocalization, "fdi/fault_localization", result.append,
                                 QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                                            durability=DurabilityPolicy.TRANSIENT_LOCAL))
    node = ros.node(SmootherNode, {"bag": str(tmp_path / "rec"), "smoothed_queue_depth": 5000})
    ros.spin_until(node.done, timeout=30)
    ros.spin_until(lambda: result and len(smoothed) == len(a.fwd.t), what="the outputs")
    assert result[0].header.frame_id == "nav"
    assert {m.header.frame_id for m in smoothed} == {"nav"}
