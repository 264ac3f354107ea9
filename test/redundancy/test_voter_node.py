"""voter_node in-process: simulated three-IMU bags are played by publishing their messages from a
driver node (no sleeps: the executor is spun until the node has received what was sent).

Expected decisions are computed independently of the node's streaming code: the batch window
means (``core.voting.window_means``), the table's bounds at the flight times (``bounds_at``) and
the vectorised truth table over the whole flight, from the flight's arrays.
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flight_fdi.core.voting import SINGLE_FAULT, pair_differences, vote_array, window_means
from flight_fdi.nodes import convert
from flight_fdi.nodes.errors import ParameterError
from flight_fdi.sim.imu import IMU_MSG, IMU_TOPICS, write_imu_bag

CHUNK = 50  # samples per IMU published between two spins (150 messages < queue depth)
WINDOW = 50
RATE_HZ = 100.0
DURATION_S = 6.0


@pytest.fixture(autouse=True)
def _same_setup(sim):
    assert (sim.WINDOW, sim.RATE_HZ, sim.DURATION_S) == (WINDOW, RATE_HZ, DURATION_S)


@pytest.fixture
def flight(sim):
    return sim.flight


def bag_messages(fl, tmp_path, name):
    """Write the flight as a bag, read it back: per sample, the three rclpy Imu messages."""
    from flight_fdi.bagio import read_messages
    from sensor_msgs.msg import Imu

    path = tmp_path / name
    write_imu_bag(fl, str(path))
    per_topic = {t: [] for t in IMU_TOPICS}
    for topic, msgtype, _, m in read_messages(path, IMU_TOPICS):
        assert msgtype == IMU_MSG
        msg = Imu()
        msg.header.stamp.sec, msg.header.stamp.nanosec = m.header.stamp.sec, m.header.stamp.nanosec
        msg.header.frame_id = m.header.frame_id
        w, a = m.angular_velocity, m.linear_acceleration
        msg.angular_velocity.x, msg.angular_velocity.y, msg.angular_velocity.z = w.x, w.y, w.z
        msg.linear_acceleration.x, msg.linear_acceleration.y, msg.linear_acceleration.z = \
            a.x, a.y, a.z
        per_topic[topic].append(msg)
    return list(zip(*(per_topic[t] for t in IMU_TOPICS)))


def expected_votes(fl, table):
    """(status, faulty) (T, Q) of the batch voter on the flight arrays."""
    qi = [list(("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")).index(q)
          for q in table.quantities]
    P = np.moveaxis(fl.output[:, :, qi], 0, -1)          # (T, Q, 3 IMUs)
    means = window_means(pair_differences(P), WINDOW, axis=0)
    lo, up = table.bounds_at(fl.t)
    status, faulty, _ = vote_array((means >= lo) & (means <= up))
    return status, faulty, means


class Rig:
    def __init__(self, ros, table_file, **params):
        from diagnostic_msgs.msg import DiagnosticArray
        from flight_fdi_msgs.msg import VoteStatus
        from harness import collect
        from sensor_msgs.msg import Imu

        from flight_fdi.nodes.voter_node import VoterNode

        self.ros = ros
        # confirm_s 0: one decision isolates (the seed-002 experiment's semantics)
        params = {"thresholds_file": str(table_file), "input_qos": "reliable",
                  "diagnostics_period_s": 0.2, "confirm_s": 0.0, **params}
        self.node = ros.node(VoterNode, parameters=params)
        self.drv = ros.node("voter_test_driver")
        self.pubs = [self.drv.create_publisher(Imu, t, 200) for t in IMU_TOPICS]
        self.votes = collect(ros, self.drv, VoteStatus, "fdi/vote", 5000)
        self.voted = collect(ros, self.drv, Imu, "imu/voted", 5000)
        self.diags = collect(ros, self.drv, DiagnosticArray, "/diagnostics", 100)
        ros.wait_for_subscribers(self.pubs)
        ros.wait_for_subscribers([self.node.pub_vote, self.node.pub_voted])
        self.sent = [0, 0, 0]

    def received(self):
        return [self.node.counters[f"received_imu{k + 1}"] for k in range(3)]

    def settle(self):
        self.ros.spin_until(lambda: self.received() == self.sent, what="inputs received")

    def play(self, samples, imus=(0, 1, 2)):
        for i, triple in enumerate(samples):
            for k in imus:
                self.pubs[k].publish(triple[k])
                self.sent[k] += 1
            if (i + 1) % CHUNK == 0:
                self.settle()
        self.settle()

    def wait_outputs(self, n_voted):
        self.ros.spin_until(lambda: len(self.voted) >= n_voted, what="voted output")


def _frames(msgs):
    return [m.header.frame_id for m in msgs]


def test_nominal_bag_no_fault_no_switch(ros, table_file, small_calibration, tmp_path, flight):
    table = small_calibration[2].table
    fl = flight(101)
    status, _, means = expected_votes(fl, table)
    assert status.max() < SINGLE_FAULT  # the independent batch voter agrees: no fault
    rig = Rig(ros, table_file)
    samples = bag_messages(fl, tmp_path, "nominal")
    rig.play(samples)
    T = len(samples)
    rig.wait_outputs(T)
    c = rig.node.counters
    assert c["matched_triples"] == T and c["decisions"] == T
    assert all(c[f"unmatched_imu{k}"] == 0 for k in (1, 2, 3))
    assert c["isolations"] == 0 and c["selection_switches"] == 0
    assert set(_frames(rig.voted)) == {"imu1"} and len(rig.voted) == T
    # the voted stream is IMU1's, unchanged, in order
    assert [convert.stamp_to_s(m.header.stamp) for m in rig.voted] == \
        [convert.stamp_to_s(s[0].header.stamp) for s in samples]
    rig.ros.spin_until(lambda: len(rig.votes) == T, what="every vote (status_every 1)")
    last = rig.votes[-1]
    Q = len(table.quantities)
    assert list(last.quantities) == list(table.quantities)
    assert len(last.pair_mean) == len(last.epsilon) == 3 * Q and len(last.status) == Q
    np.testing.assert_allclose(np.reshape(last.pair_mean, (Q, 3)), means[-1], rtol=1e-9,
                               atol=1e-12)
    got = np.array([list(v.status) for v in rig.votes])
    np.testing.assert_array_equal(got, status)
    assert {v.selected_imu for v in rig.votes} == {1}
    assert all(v.overall_status < SINGLE_FAULT for v in rig.votes)
    lo, up = table.bounds(DURATION_S - 1.0 / RATE_HZ)
    np.testing.assert_array_equal(np.reshape(last.lower_bound, (Q, 3)), lo)
    np.testing.assert_array_equal(np.reshape(last.upper_bound, (Q, 3)), up)


def _first_fault(status, faulty, q):
    idx = np.flatnonzero(status[:, q] >= SINGLE_FAULT)
    return int(idx[0]), int(faulty[idx[0], q])


@pytest.mark.parametrize("imu, expect_selected", [(2, 1), (1, 2)])
def test_stuck_gyro_isolated_and_output_switches(ros, table_file, small_calibration, tmp_path,
                                                 flight, imu, expect_selected):
    """IMU2 gyro z stuck at zero: IMU2 isolated, the output stays on IMU1 (the truth table's
    choice); IMU1 stuck: IMU1 isolated and the output switches to IMU2 for good."""
    table = small_calibration[2].table
    fl = flight(102, f"imu{imu}:gyro_z:zero:t=2.5")
    q = list(table.quantities).index("gyro_z")
    status, faulty, _ = expected_votes(fl, table)
    k0, who = _first_fault(status, faulty, q)
    assert who == imu and fl.t[k0] >= 2.5           # the batch voter isolates the stuck IMU
    rig = Rig(ros, table_file, status_every=10)
    samples = bag_messages(fl, tmp_path, f"stuck{imu}")
    rig.play(samples)
    rig.wait_outputs(len(samples))
    node = rig.node
    assert int(node.latched[q]) == imu and node.counters["isolations"] >= 1
    assert node.selected == expect_selected
    frames = _frames(rig.voted)
    if imu == 1:
        # IMU1 until the decision at k0 (inclusive: the decision's own triple goes out from the
        # new selection), IMU2 from then on, never back
        assert frames[:k0] == ["imu1"] * k0
        assert frames[k0:] == ["imu2"] * (len(frames) - k0)
        assert node.counters["selection_switches"] == 1
    else:
        assert set(frames) == {"imu1"} and node.counters["selection_switches"] == 0
    rig.ros.spin_until(lambda: _last_vote_seen(rig, samples), what="last vote")
    v = rig.votes[-1]
    assert v.isolated_imu[q] == imu and v.selected_imu == expect_selected
    assert v.status[q] == SINGLE_FAULT and v.epsilon_sum[q] == 1
    statuses = {s.name: s for s in node.diagnostic_statuses()}
    vote = statuses["voter_node: vote"]
    assert vote.level == b"\x01" and f"IMU{imu} on gyro_z" in vote.message


def _last_vote_seen(rig, samples):
    # status_every 10 over 600 decisions: the last decision (599) is not a multiple of 10, so
    # wait for the vote of decision 590 or a change
    return len(rig.votes) > 0 and convert.stamp_to_s(rig.votes[-1].header.stamp) >= \
        convert.stamp_to_s(samples[-11][0].header.stamp)


@pytest.mark.parametrize("release, back", [(0, False), (2, True)])
def test_selection_is_sticky(ros, table_file, small_calibration, tmp_path, flight, release, back):
    """A transient fault of IMU1 (1.5 s): the output moves to IMU2 and, with release 0, never
    returns; with release_after_windows 2 it returns only after two whole windows of healthy
    votes after the fault has left the window."""
    table = small_calibration[2].table
    fl = flight(103, "imu1:gyro_z:zero:t=2,end=3.5")
    q = list(table.quantities).index("gyro_z")
    status, faulty, _ = expected_votes(fl, table)
    k0, who = _first_fault(status, faulty, q)
    assert who == 1
    rig = Rig(ros, table_file, release_after_windows=release, status_every=1000)
    samples = bag_messages(fl, tmp_path, f"transient{release}")
    rig.play(samples)
    rig.wait_outputs(len(samples))
    frames = np.array(_frames(rig.voted))
    assert np.all(frames[:k0] == "imu1") and frames[k0] == "imu2"
    if not back:
        assert np.all(frames[k0:] == "imu2") and rig.node.latched[q] == 1
        return
    # independent expectation of the release: the first decision after which the gyro_z vote
    # has been healthy for 2 * WINDOW decisions in a row (after the fault was isolated)
    healthy = status[:, q] == 0
    run = 0
    release_at = None
    for k in range(k0 + 1, len(healthy)):
        run = run + 1 if healthy[k] else 0
        if run >= 2 * WINDOW:
            release_at = k
            break
    assert release_at is not None, "the flight is long enough for the release"
    # no other quantity isolated IMU1 in this flight
    assert not np.any((status >= SINGLE_FAULT) & (faulty == 1) & (np.arange(status.shape[1]) != q))
    assert np.all(frames[k0:release_at] == "imu2")
    assert np.all(frames[release_at:] == "imu1")
    assert rig.node.counters["releases"] == 1 and rig.node.counters["selection_switches"] == 2


def test_bad_and_missing_input_is_counted_never_fatal(ros, table_file, tmp_path, flight):
    """IMU3 never arrives, IMU2 sends a NaN and a duplicate: counted, reported, the voted
    output keeps flowing from IMU1 (unvoted)."""
    import copy

    fl = flight(104)
    samples = bag_messages(fl, tmp_path, "partial")[:200]
    rig = Rig(ros, table_file, max_wait_s=0.05)
    bad = copy.deepcopy(samples[10][1])
    bad.angular_velocity.y = math.nan
    samples[10] = (samples[10][0], bad, samples[10][2])
    rig.play(samples, imus=(0, 1))
    rig.pubs[1].publish(samples[-1][1])  # duplicate stamp
    rig.sent[1] += 1
    rig.settle()
    c = rig.node.counters
    assert c["dropped_imu2_nonfinite"] == 1 and c["dropped_imu2_duplicate"] == 1
    assert c["matched_triples"] == 0 and c["decisions"] == 0
    # samples wait max_wait_s (5 samples at 100 Hz) for IMU3 and then expire
    expired1 = c["unmatched_imu1"]
    assert 200 - 6 <= expired1 <= 200
    rig.wait_outputs(expired1)
    assert set(_frames(rig.voted)) == {"imu1"} and c["unvoted_published"] == expired1
    statuses = {s.name: s for s in rig.node.diagnostic_statuses()}
    inputs = statuses["voter_node: inputs"]
    assert inputs.level == b"\x01" and "no messages on /imu3/data yet" in inputs.message
    values = {kv.key: kv.value for kv in inputs.values}
    assert values["dropped_imu2_nonfinite"] == "1" and values["received_imu3"] == "0"
    assert "no vote yet" in statuses["voter_node: vote"].message
    # /diagnostics is published on the timer
    rig.ros.spin_until(lambda: len(rig.diags) > 0, what="diagnostics")


def test_silent_selected_imu_is_not_selected(ros, table_file, tmp_path, flight):
    """IMU1 stops: the voted output continues from IMU2 (IMU1 is silent, not isolated)."""
    fl = flight(105)
    samples = bag_messages(fl, tmp_path, "silent")[:300]
    rig = Rig(ros, table_file, stale_after_s=0.2)
    rig.play(samples[:100])
    rig.play(samples[100:], imus=(1, 2))
    rig.ros.spin_until(lambda: rig.voted and rig.voted[-1].header.frame_id == "imu2",
                       what="output from IMU2")
    assert rig.node.selected == 2 and not np.any(rig.node.latched)
    assert rig.node.counters["selection_switches"] == 1
    frames = _frames(rig.voted)
    assert frames[:100] == ["imu1"] * 100


@pytest.mark.parametrize("content, match", [
    (None, "file not found"),
    ("{not json", "not valid JSON"),
    (json.dumps({"format": "something else"}), "not a threshold table"),
])
def test_missing_or_corrupt_table_stops_the_node(ros, tmp_path, content, match):
    from flight_fdi.nodes.voter_node import VoterNode

    path = tmp_path / "t.json"
    if content is not None:
        path.write_text(content)
    with pytest.raises(ParameterError, match=match) as err:
        ros.node(VoterNode, parameters={"thresholds_file": str(path)})
    assert "'thresholds_file'" in str(err.value)


def test_table_parameter_is_required_and_topics_checked(ros, table_file):
    from flight_fdi.nodes.voter_node import VoterNode

    with pytest.raises(ParameterError, match="thresholds_file"):
        ros.node(VoterNode, parameters={})
    with pytest.raises(ParameterError, match="exactly three"):
        ros.node(VoterNode, parameters={"thresholds_file": str(table_file),
                                        "imu_topics": ["/a", "/b"]})
    with pytest.raises(ParameterError, match="duplicate"):
        ros.node(VoterNode, parameters={"thresholds_file": str(table_file),
                                        "imu_topics": ["/a", "/b", "/a"]})
    with pytest.raises(ParameterError, match="three different topics"):  # "a" resolves to /a
        ros.node(VoterNode, parameters={"thresholds_file": str(table_file),
                                        "imu_topics": ["/a", "/b", "a"]})


def test_voter_yaml_is_the_generated_params_file(repo_root):
    """config/voter.yaml is regenerated from VOTER_PARAMS (python -m flight_fdi.nodes.params)."""
    from flight_fdi.nodes.params import render_module

    text = (repo_root / "config" / "voter.yaml").read_text(encoding="utf-8")
    assert text == render_module("flight_fdi.nodes.voter_node")


@pytest.mark.parametrize("executor", [None, "single"])
def test_the_executable_spins_until_sigint(table_file, tmp_path, executor):
    """``voter_node`` on its default executor (EventsExecutor) and on the single-threaded one:
    it starts, spins, and exits 0 on SIGINT without a traceback."""
    import os
    import signal
    import subprocess
    import sys
    from pathlib import Path

    repo = Path(__file__).resolve().parents[2]
    env = dict(os.environ, PYTHONPATH=str(repo), ROS_AUTOMATIC_DISCOVERY_RANGE="OFF")
    cmd = [sys.executable, "-u", "-m", "flight_fdi.nodes.voter_node"]
    cmd += ["--executor", executor] if executor else []
    proc = subprocess.Popen(cmd + ["--ros-args", "-p", f"thresholds_file:={table_file}", "-p",
                                   "diagnostics_period_s:=0.2"],
                            stderr=subprocess.PIPE, text=True, env=env, cwd=tmp_path)
    try:
        for line in proc.stderr:  # logged at the end of the constructor
            if "voting " in line:
                break
        else:
            pytest.fail("the voter never started")
        proc.send_signal(signal.SIGINT)
        rest = proc.stderr.read()
        assert proc.wait(timeout=30) == 0, rest
        assert "Traceback" not in rest, rest
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.stderr.close()


# ------------------------------------------------------------------------ the real excerpt
# voter_node on test/redundancy/data/mimu: the node runs the same engine as flight-fdi vote --
# same decisions; it learns the offsets, estimates the time offsets and isolates an injected
# stuck gyro after the confirmation time.

from pathlib import Path  # noqa: E402

REAL = Path(__file__).parent / "data" / "mimu"
REAL_TABLE = REAL / "thresholds_without_vertical_path_9.json"
CONFIRM = 60


def run(table, ns, P, confirm=CONFIRM):
    from flight_fdi.core.voter_core import VoterCore

    core = VoterCore(table, confirm=confirm)
    parts = [core.push(ns, P), core.finish()]
    status = np.concatenate([d.status for d in parts])
    t = np.concatenate([d.t_flight for d in parts])
    return core, t, status, [e for d in parts for e in d.events]


N_SAMPLES = 1500     # 12.5 s: learning (5 s), then 7.5 s of decisions


def messages(ns, P):
    from sensor_msgs.msg import Imu

    out = []
    for i in range(ns.size):
        triple = []
        for k in range(3):
            m = Imu()
            m.header.stamp.sec, m.header.stamp.nanosec = divmod(int(ns[i]), 1_000_000_000)
            m.header.frame_id = f"imu{k + 1}"
            w, a = P[i, :3, k], P[i, 3:, k]
            m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
            m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = \
                map(float, a)
            triple.append(m)
        out.append(tuple(triple))
    return out


@pytest.fixture(scope="module")
def excerpt():
    from flight_fdi.cli.imu_csv import read_csv

    t, _ = read_csv(REAL / "IMU_1.csv.gz")
    P = np.stack([read_csv(REAL / f"IMU_{k}.csv.gz")[1] for k in (1, 2, 3)], axis=-1)
    ns = np.round((1.7e9 + t) * 1e9).astype(np.int64)
    return ns[:N_SAMPLES], P[:N_SAMPLES]


SEQ_TABLE = REAL / "thresholds_seq_without_vertical_path_9.json"


@pytest.mark.parametrize("stuck, table_file", [(False, REAL_TABLE), (True, REAL_TABLE),
                                               ("accel", SEQ_TABLE)])
def test_node_equals_offline_engine_on_real_data(ros, excerpt, stuck, table_file):
    """Also with the sequential detector (SEQ_TABLE): an accel x step of 0.07 m/s^2 in IMU3
    from 6 s, which only its CUSUM isolates on this excerpt (test_voter_sequential.py)."""
    ns, P = excerpt
    if stuck:
        P = P.copy()
        if stuck == "accel":
            P[(ns - ns[0]) * 1e-9 >= 6.0, 3, 2] += 0.07     # IMU3 accel x +0.07 m/s^2 from 6 s
        else:
            P[(ns - ns[0]) * 1e-9 >= 8.0, 2, 2] = 0.0      # IMU3 gyro z stuck from 8 s
    from flight_fdi.core.voting import load_table

    table = load_table(table_file)
    core, t, status, events = run(table, ns, P)
    rig = Rig(ros, table_file, status_every=1, confirm_s=CONFIRM / 120.0 - 1e-6,
              match_tolerance_s=0.001)
    rig.play(messages(ns, P))
    rig.wait_outputs(N_SAMPLES)
    node = rig.node
    # the node decides what the engine decides up to its alignment delay at the end
    lag = len(status) - node.counters["decisions"]
    assert 0 <= lag <= math.ceil(max(core.tau) * 120) + 1
    assert np.allclose(node.core.tau, core.tau)
    iso = [(q, new) for _, q, _, new in events if new]
    assert node.counters["isolations"] == len(iso)
    if stuck == "accel":
        assert iso == [(3, 3)] and node.latched[3] == 3 and node.selected == 1
    elif stuck:
        assert iso == [(2, 3)] and node.latched[2] == 3 and node.selected == 1
        frames = [m.header.frame_id for m in rig.voted]
        assert set(frames) == {"imu1"}
    else:
        assert iso == [] and node.counters["selection_switches"] == 0
    statuses = np.array([list(v.status) for v in rig.votes])
    assert statuses.shape[0] >= node.counters["decisions"]
    np.testing.assert_array_equal(statuses[:len(status) - lag], status[:len(status) - lag])
