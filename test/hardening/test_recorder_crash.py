"""Crash safety of the recorder under load, tested with real signals on the installed executable.

Five recorder processes (``install/flight_fdi/lib/flight_fdi/recorder_node``, started as
``test/nodes/test_recorder.py`` does) record one stream of FilterState messages published by this
process at ``RATE`` messages per second. Three of them (mcap, sqlite3, mcap + zstd) get SIGKILL at
seeded random moments under load; two (mcap, sqlite3) get SIGINT after the stream ended. Then:

The load starts after every recorder has recorded ``WARMUP`` messages: the first message of a
topic costs a recorder its message definition, type hash and metadata, hundreds of milliseconds
on a loaded machine, during which nothing is flushed.

* every killed bag opens with rosbags, and an mcap one also with the independent ``mcap``
  library (CRCs validated); its messages are a gap-free prefix of what was sent, in order, and
  hold every message published more than ``flush_interval + MARGIN`` before the kill;
  ``metadata.yaml`` is complete and counts at most what the file holds (it is replaced after
  the data of a flush, so a kill between the two leaves it one flush behind);
* every interrupted bag holds all messages, in order, with complete metadata (counts, clean
  close) and, for mcap, a summary whose statistics count them.

How old the newest lost message was at each kill is printed (``-s`` shows it) and asserted
against the bound.
"""
from __future__ import annotations

import signal
import time
from pathlib import Path

import harness  # noqa: F401  (the private ROS domain, before rclpy starts)
import numpy as np
import pytest

from nodes.test_recorder import (_mcap_messages, _metadata, _qos, _raw, _start_recorder,
                                 _state, _stop)

RATE = 400.0            # messages per second
DURATION_S = 3.0        # of the stream
FLUSH_S = 0.2           # the recorders' flush_interval
MARGIN_S = 0.5          # receive latency and the flush's own duration, under load
WARMUP = 20             # messages recorded before the load starts
SEED = 20240611
RECORDERS = [  # (output, storage, compression, signal)
    ("kill_mcap", "mcap", "none", signal.SIGKILL),
    ("kill_sqlite3", "sqlite3", "none", signal.SIGKILL),
    ("kill_mcap_zstd", "mcap", "zstd", signal.SIGKILL),
    ("int_mcap", "mcap", "none", signal.SIGINT),
    ("int_sqlite3", "sqlite3", "none", signal.SIGINT),
]


def _counts_by_bag(node) -> dict:
    """{bag path: messages on /fdi/state} from the recorders' /diagnostics."""
    from diagnostic_msgs.msg import DiagnosticArray

    latest: dict[str, int] = {}

    def on_diag(msg):
        for st in msg.status:
            if st.name.endswith(": recording"):
                kv = {k.key: k.value for k in st.values}
                latest[Path(kv["bag"]).name] = int(kv.get("/fdi/state count", 0))

    node.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 100)
    return latest


def _indices(bag: Path) -> list[int]:
    """Sample index of every /fdi/state message in the bag (rosbags), in bag order."""
    from rclpy.serialization import deserialize_message

    from flight_fdi_msgs.msg import FilterState

    out = []
    for topic, _, data in _raw(bag):
        assert topic == "/fdi/state"
        msg = deserialize_message(data, FilterState)
        i = int(round(msg.x[0] / 0.1))
        assert msg == _state(i), f"message {i} damaged"
        out.append(i)
    return out


@pytest.mark.slow
def test_sigkill_under_load_keeps_all_but_the_last_flush_and_sigint_closes(ros, tmp_path):
    from flight_fdi_msgs.msg import FilterState

    src = ros.node("crash_source")
    pub = src.create_publisher(FilterState, "fdi/state", _qos(depth=5000))
    counts = _counts_by_bag(src)
    rng = np.random.default_rng(SEED)
    kill_at = {name: float(rng.uniform(0.6, DURATION_S - 0.2))
               for name, *_, sig in RECORDERS if sig == signal.SIGKILL}
    procs = {name: _start_recorder(tmp_path, f"output:={name}", f"storage:={storage}",
                                   f"compression:={compression}", f"flush_interval:={FLUSH_S}")
             for name, storage, compression, _ in RECORDERS}
    messages = [_state(i) for i in range(int(RATE * DURATION_S))]
    sent_at: list[float] = []
    killed: dict[str, float] = {}
    try:
        ros.wait_for_subscribers([pub], count=len(RECORDERS), timeout=60)
        # warm-up: the first message of a topic costs a recorder its type definition, hash and
        # metadata (hundreds of ms on a loaded machine); the guarantee is for a running recorder
        for i in range(WARMUP):
            pub.publish(messages[i])
            sent_at.append(time.monotonic())
        ros.spin_until(lambda: len(counts) == len(RECORDERS)
                       and all(n >= WARMUP for n in counts.values()), timeout=30,
                       what="every recorder reporting the warm-up messages")
        t0 = time.monotonic() - WARMUP / RATE
        while len(sent_at) < len(messages):
            now = time.monotonic()
            due = min(len(messages), int((now - t0) * RATE) + 1)
            while len(sent_at) < due:
                pub.publish(messages[len(sent_at)])
                sent_at.append(time.monotonic())
            for name, at in kill_at.items():
                if name not in killed and now - t0 >= at:
                    procs[name].send_signal(signal.SIGKILL)
                    killed[name] = time.monotonic()
            ros.executor.spin_once(timeout_sec=0.0005)
        n = len(messages)
        interrupted = [name for name, *_, sig in RECORDERS if sig == signal.SIGINT]
        ros.spin_until(lambda: all(counts.get(k) == n for k in interrupted), timeout=60,
                       what="the interrupted recorders report every message")
        for name in interrupted:
            procs[name].send_signal(signal.SIGINT)
        for name in interrupted:
            rc = procs[name].wait(timeout=30)
            assert rc == 0, _stop(procs[name])[-4000:]
        for name in killed:
            procs[name].wait(timeout=10)
    finally:
        outputs = {name: _stop(p) for name, p in procs.items()}

    sent_at_arr = np.array(sent_at)
    for name, storage, compression, sig in RECORDERS:
        bag = tmp_path / name
        got = _indices(bag)  # rosbags opens and reads it
        assert got == list(range(len(got))), f"{name}: not a gap-free prefix in order"
        meta = _metadata(bag)
        if sig == signal.SIGKILL:
            t_kill = killed[name]
            must = int(np.sum(sent_at_arr < t_kill - FLUSH_S - MARGIN_S))
            lost_age = t_kill - sent_at_arr[len(got)] if len(got) < n else 0.0
            print(f"{name}: killed {t_kill - t0:.3f} s after the load started; "
                  f"{len(got)} of {int(np.sum(sent_at_arr < t_kill))} sent messages on disk; "
                  f"the oldest lost one was {lost_age * 1e3:.0f} ms old")
            assert len(got) >= must, (name, len(got), must)
            assert meta["custom_data"]["closed_cleanly"] == "false"
            assert must <= meta["message_count"] <= len(got), (meta["message_count"], len(got))
        else:
            assert len(got) == n, (name, len(got), outputs[name])
            assert meta["custom_data"]["closed_cleanly"] == "true"
            assert meta["message_count"] == n
            assert meta["topics_with_message_count"][0]["message_count"] == n
            assert f"{n} messages" in outputs[name]
        if storage == "mcap":
            mc = _mcap_messages(bag / f"{name}_0.mcap")  # the independent reader, CRCs checked
            assert [d for _, _, d in mc] == [d for _, _, d in _raw(bag)]
            if sig == signal.SIGINT:
                from mcap.reader import make_reader

                with open(bag / f"{name}_0.mcap", "rb") as f:
                    summary = make_reader(f).get_summary()
                assert summary.statistics.message_count == n
