"""bag_player: timed and loss-free fast replay, /clock, bad input, parameters (in-process)."""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.nodes.errors import ParameterError

T0_NS = 1_700_000_000 * 1_000_000_000
INS, REF = "/ins/velocity", "/reference/velocity"


def _write_flight(path: Path, seconds: float = 2.0, storage: str = "mcap",
                  extra: bool = False, compression: str = "none"
                  ) -> dict[str, list[tuple[int, bytes]]]:
    """A small bag: INS 50 Hz, reference 10 Hz (receive time = stamp); returns what was
    written per topic as (receive time, CDR bytes)."""
    from flight_fdi.bagio import cdr, open_writer

    n_ins = int(seconds * 50)
    t_ins = T0_NS + np.arange(n_ins, dtype=np.int64) * 20_000_000
    t_ref = t_ins[::5]
    tw_ins = np.zeros((n_ins, 6))
    tw_ins[:, 0] = np.arange(n_ins) * 0.01  # identifies each message
    tw_ref = np.zeros((t_ref.size, 6))
    tw_ref[:, 0] = np.arange(t_ref.size) * 0.05
    ins = cdr.encode(cdr.TWIST_STAMPED, t_ins, "ins", tw_ins)
    ref = cdr.encode(cdr.TWIST_COV_STAMPED, t_ref, "ref", tw_ref, np.eye(6).reshape(-1) * 0.01)
    series = [(REF, cdr.TWIST_COV_STAMPED, t_ref, ref), (INS, cdr.TWIST_STAMPED, t_ins, ins)]
    if extra:  # a topic that is not played by default
        series.append(("/sim/other", cdr.TWIST_STAMPED, t_ref, ref and cdr.encode(
            cdr.TWIST_STAMPED, t_ref, "o", tw_ref)))
    with open_writer(path, storage=storage, compression=compression) as bag:
        bag.write_series(series)
    return {INS: list(zip(t_ins.tolist(), ins)), REF: list(zip(t_ref.tolist(), ref))}


def _raw_sub(node, topic: str, depth: int = 1000):
    """Raw subscription recording (steady arrival time, bytes)."""
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    cls = TwistStamped if topic == INS else TwistWithCovarianceStamped
    got: list[tuple[float, bytes]] = []
    node.create_subscription(cls, topic, lambda d: got.append((time.monotonic(), d)),
                             QoSProfile(depth=depth, reliability=ReliabilityPolicy.RELIABLE),
                             raw=True)
    return got


def test_timed_replay_keeps_the_spacing_scaled_by_rate(ros, tmp_path):
    from flight_fdi.nodes.bag_player import BagPlayer

    written = _write_flight(tmp_path / "b", seconds=2.0)
    sink = ros.node("sink")
    ins, ref = _raw_sub(sink, INS), _raw_sub(sink, REF)
    rate = 4.0
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "rate": rate,
                                  "publish_clock": False})
    ros.spin_until(player.done, timeout=20)
    ros.spin_until(lambda: len(ins) == 100 and len(ref) == 20, what="all messages delivered")
    assert [d for _, d in ins] == [d for _, d in written[INS]]  # the bag's bytes, in order
    assert [d for _, d in ref] == [d for _, d in written[REF]]
    # spacing: the bag spans 1.98 s -> 0.495 s at rate 4; never early, late by scheduling only.
    # Times from the player's start (its first publish, same process and clock): measured from
    # the first arrival instead, a first message delivered late on a loaded machine made the
    # next ones look early
    arrivals = np.array([t for t, _ in ins])
    bag_t = (np.array([t for t, _ in written[INS]]) - T0_NS) * 1e-9
    lag = (arrivals - player.started_at) - bag_t / rate
    assert lag.min() > -0.001, "a message was published before its time"
    assert np.median(lag) < 0.05 and lag.max() < 0.5
    assert player.published == 120 and not player.error


@pytest.mark.parametrize("window", [8, 400])
def test_fast_replay_loses_nothing_with_shallow_queues_when_acknowledged(ros, tmp_path, window):
    """A consumer with queue depth 8 that acknowledges each reference sample as the filter does
    with fdi/state (once the INS sample after it has arrived, i.e. after taking every input
    stamped up to it): with ack_window = 8 the player never has more than 8 messages in flight
    and nothing is lost; the control, a window beyond the queue depth, loses messages."""
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from flight_fdi.nodes.bag_player import BagPlayer
    from flight_fdi.nodes.convert import filter_state_msg
    from flight_fdi_msgs.msg import FilterState

    written = _write_flight(tmp_path / "b", seconds=6.0)
    consumer = ros.node("consumer")
    qos = QoSProfile(depth=8, reliability=ReliabilityPolicy.RELIABLE)
    ack = consumer.create_publisher(FilterState, "fdi/state", 100)
    got_ins, got_ref, waiting = [], [], []

    def stamp(msg) -> int:
        return msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec

    def answer() -> None:
        while waiting and got_ins and stamp(got_ins[-1]) > stamp(waiting[0]):
            ref = waiting.pop(0)
            ack.publish(filter_state_msg(ref.header.stamp, "x", ["v"], [0.0], [[1.0]]))

    def on_ins(msg):
        got_ins.append(msg)
        answer()

    def on_ref(msg):
        got_ref.append(msg)
        waiting.append(msg)
        answer()

    consumer.create_subscription(TwistStamped, INS, on_ins, qos)
    consumer.create_subscription(TwistWithCovarianceStamped, REF, on_ref, qos)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "fast": True,
                                  "ack_topic": "fdi/state", "ack_window": window,
                                  "publish_clock": False})
    peak = [0]
    ros.spin_until(lambda: (peak.__setitem__(0, max(peak[0], player.in_flight))
                            or player.done.done()), timeout=30, what="replay")
    # the last message of each topic always arrives (keep last keeps the newest)
    ros.spin_until(lambda: got_ins and abs(got_ins[-1].twist.linear.x - 2.99) < 1e-9
                   and got_ref and abs(got_ref[-1].twist.twist.linear.x - 2.95) < 1e-9,
                   what="the last messages")
    if window > 8:  # the control: the consumer's queues overflowed
        assert len(got_ins) < 300
        return
    assert [m.twist.linear.x for m in got_ins] == pytest.approx(np.arange(300) * 0.01)
    assert [m.twist.twist.linear.x for m in got_ref] == pytest.approx(np.arange(60) * 0.05)
    assert peak[0] <= 8 and player.ack_timeouts == 0
    assert player.acks == 60 and player.acked_ns == written[REF][-1][0]
    assert player.first_stamp_ns == T0_NS


def test_dds_acknowledgement_alone_does_not_prevent_loss(ros):
    """Why the player paces by the consumer's own output: a reliable publisher's samples are all
    acknowledged once they sit in the reader's queue, yet a keep-last queue drops the oldest."""
    from geometry_msgs.msg import TwistStamped
    from rclpy.duration import Duration
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    got: list = []
    ros.node("sink").create_subscription(TwistStamped, "t", got.append, QoSProfile(
        depth=2, reliability=ReliabilityPolicy.RELIABLE))
    pub = ros.node("source").create_publisher(TwistStamped, "t", QoSProfile(
        depth=100, reliability=ReliabilityPolicy.RELIABLE))
    ros.wait_for_subscribers([pub])
    for i in range(50):
        msg = TwistStamped()
        msg.twist.linear.x = float(i)
        pub.publish(msg)
    assert pub.wait_for_all_acked(Duration(seconds=5))
    ros.spin_until(lambda: got and got[-1].twist.linear.x == 49.0, what="the last message")
    assert len(got) == 2  # 48 of 50 acknowledged messages were dropped by the reader's queue


def test_fast_replay_without_ack_paces_one_message_per_cycle(ros, tmp_path):
    """In one process on one single-threaded executor, depth-2 queues lose nothing."""
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    from flight_fdi.nodes.bag_player import BagPlayer

    _write_flight(tmp_path / "b", seconds=4.0)
    sink = ros.node("sink")
    qos = QoSProfile(depth=2, reliability=ReliabilityPolicy.RELIABLE)
    got = {INS: [], REF: []}
    sink.create_subscription(TwistStamped, INS, got[INS].append, qos)
    sink.create_subscription(TwistWithCovarianceStamped, REF, got[REF].append, qos)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "fast": True,
                                  "publish_clock": False})
    ros.spin_until(player.done, timeout=30)
    ros.spin_until(lambda: len(got[INS]) == 200 and len(got[REF]) == 40, what="delivery")
    assert [m.twist.linear.x for m in got[INS]] == pytest.approx(np.arange(200) * 0.01)


def test_clock_follows_the_bag_time(ros, tmp_path):
    from rosgraph_msgs.msg import Clock

    from flight_fdi.nodes.bag_player import BagPlayer

    written = _write_flight(tmp_path / "b", seconds=1.0)
    sink = ros.node("sink")
    clocks: list[int] = []
    sink.create_subscription(Clock, "/clock",
                             lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec), 100)
    _raw_sub(sink, INS)
    _raw_sub(sink, REF)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "fast": True,
                                  "clock_frequency": 20.0})
    ros.spin_until(player.done, timeout=20)
    last = max(t for msgs in written.values() for t, _ in msgs)
    ros.spin_until(lambda: clocks and clocks[-1] >= last - 50_000_000, what="/clock")
    steps = np.diff(clocks)
    assert clocks[0] == T0_NS and np.all(steps >= 50_000_000)  # at most 20 Hz of bag time
    # ... and at least every 50 ms + one message interval (20 ms), up to the last message
    assert np.all(steps <= 70_000_000) and last - 70_000_000 <= clocks[-1] <= last


def test_ack_timeout_lets_the_replay_continue(ros, tmp_path):
    """A consumer that never acknowledges (the topic exists, nobody answers)."""
    from flight_fdi.nodes.bag_player import BagPlayer
    from flight_fdi_msgs.msg import FilterState

    _write_flight(tmp_path / "b", seconds=0.5)
    mute = ros.node("mute")
    mute.create_publisher(FilterState, "fdi/state", 10)
    got = _raw_sub(mute, INS)
    _raw_sub(mute, REF)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "fast": True,
                                  "ack_topic": "fdi/state", "ack_window": 10,
                                  "ack_timeout": 0.2, "publish_clock": False})
    ros.spin_until(player.done, timeout=20)
    assert player.published == 30 and player.ack_timeouts >= 2
    ros.spin_until(lambda: len(got) == 25, what="all INS messages")


def test_waiting_for_subscribers_times_out_with_an_error(ros, tmp_path):
    from flight_fdi.nodes.bag_player import BagPlayer

    _write_flight(tmp_path / "b", seconds=0.2)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "wait_timeout": 0.3})
    ros.spin_until(player.done, timeout=10)
    assert player.published == 0 and "no subscriber" in player.error


@pytest.mark.parametrize("storage", ["sqlite3"])
def test_plays_sqlite3_and_chosen_topics_only(ros, tmp_path, storage):
    from flight_fdi.nodes.bag_player import BagPlayer

    written = _write_flight(tmp_path / "b", seconds=0.5, storage=storage, extra=True)
    sink = ros.node("sink")
    ref = _raw_sub(sink, REF)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "topics": [REF], "fast": True,
                                  "publish_clock": False})
    assert list(player.publishers_by_topic) == [REF]
    ros.spin_until(player.done, timeout=20)
    ros.spin_until(lambda: len(ref) == 5, what="reference messages")
    assert [d for _, d in ref] == [d for _, d in written[REF]] and player.published == 5


def test_bad_bags_and_parameters_are_reported(ros, tmp_path):
    from flight_fdi.nodes.bag_player import BagPlayer

    _write_flight(tmp_path / "b", seconds=0.2)
    cases = [({}, "'bag'.*required"),
             ({"bag": str(tmp_path / "missing")}, "'bag'.*does not exist"),
             ({"bag": str(tmp_path / "b"), "topics": ["/nope"]}, "'bag'.*no topic /nope"),
             ({"bag": str(tmp_path / "b"), "rate": 0.0}, "'rate'"),
             ({"bag": str(tmp_path / "b"), "ack_window": 1}, "'ack_window'"),
             ({"bag": str(tmp_path / "b"), "fast": True, "ack_topic": "not a topic"},
              "'ack_topic'")]
    for params, pattern in cases:
        with pytest.raises(ParameterError, match=pattern):
            ros.node(BagPlayer, params)
    junk = tmp_path / "junk"
    junk.mkdir()
    (junk / "metadata.yaml").write_text("rosbag2_bagfile_information: {version: 9}\n")
    with pytest.raises(ParameterError, match="'bag'.*cannot be opened"):
        ros.node(BagPlayer, {"bag": str(junk)})


def test_a_bag_corrupt_inside_stops_the_replay_with_an_error(ros, tmp_path):
    """Metadata and index intact, the compressed chunk damaged: detected while playing."""
    from mcap.reader import make_reader

    from flight_fdi.nodes.bag_player import BagPlayer

    _write_flight(tmp_path / "b", seconds=2.0, compression="zstd")
    mcap = tmp_path / "b" / "b.mcap"
    with open(mcap, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[0]
    data = bytearray(mcap.read_bytes())
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2  # inside the zstd frame
    data[mid:mid + 32] = bytes(32)
    mcap.write_bytes(bytes(data))
    sink = ros.node("sink")
    _raw_sub(sink, INS)
    _raw_sub(sink, REF)
    player = ros.node(BagPlayer, {"bag": str(tmp_path / "b"), "fast": True,
                                  "publish_clock": False})
    ros.spin_until(player.done, timeout=20)
    assert player.error.startswith(f"bag '{tmp_path / 'b'}' is corrupt")
    assert player.published < 120
    status = player._statuses()[0]
    assert status.level == b"\x02" and "corrupt" in status.message


def test_the_executable_exits_after_the_bag_with_its_status(tmp_path):
    """``bag_player`` with exit_when_done (the default): 0 after a good bag, 1 and an error line
    for a bag corrupt inside, 1 (FATAL) for a missing one or for the guard-condition pacing on
    the EventsExecutor -- no traceback in any case."""
    import os
    import subprocess
    import sys

    from mcap.reader import make_reader

    repo = Path(__file__).resolve().parents[2]
    _write_flight(tmp_path / "good", seconds=0.5)
    _write_flight(tmp_path / "bad", seconds=2.0, compression="zstd")
    mcap = tmp_path / "bad" / "bad.mcap"
    with open(mcap, "rb") as f:
        chunk = make_reader(f).get_summary().chunk_indexes[0]
    data = bytearray(mcap.read_bytes())
    mid = chunk.chunk_start_offset + chunk.chunk_length // 2
    data[mid:mid + 32] = bytes(32)
    mcap.write_bytes(bytes(data))
    env = dict(os.environ, PYTHONPATH=str(repo), ROS_AUTOMATIC_DISCOVERY_RANGE="OFF")
    for bag, executor, status, text in (
            (tmp_path / "good", "single", 0, ""), (tmp_path / "bad", "single", 1, "is corrupt"),
            (tmp_path / "missing", "single", 1, "does not exist"),
            (tmp_path / "good", "events", 1, "EventsExecutor does not support")):
        proc = subprocess.run(
            [sys.executable, "-m", "flight_fdi.nodes.bag_player", "--executor", executor,
             "--ros-args", "-p", f"bag:={bag}", "-p", "fast:=true", "-p",
             "wait_for_subscribers:=false", "-p", "publish_clock:=false"],
            capture_output=True, text=True, timeout=60, env=env, cwd=tmp_path)
        assert proc.returncode == status, proc.stderr
        assert text in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
