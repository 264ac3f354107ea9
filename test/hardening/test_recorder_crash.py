"""Crash safety of the recorder under load, tested with real signals on the installed executable.

Five recorder processes (``install/flight_fdi/lib/flight_fdi/recorder_node``, started as
``test/nodes/test_recorder.py`` does) record one stream of FilterState messages published by this
process at ``RATE`` messages per second. Three of them (mcap, sqlite3, mcap + zstd) get SIGKILL in
the middle of the stream; two (mcap, sqlite3) get SIGINT after the stream ended.

The load starts after every recorder has recorded ``WARMUP`` messages: the first message of a
topic costs a recorder its message definition, type hash and metadata, hundreds of milliseconds
on a loaded machine, during which nothing is flushed.

When a recorder is killed is decided by what it has done, never by the clock (so the test proves
the same on a quiet and on a loaded machine): once message ``k`` (seeded) was sent, the test waits,
the stream going on, until the bag on disk holds it -- the recorder flushed it by itself, while
recording, no stop requested (``metadata.yaml`` is replaced after the data of every flush: its
``message_count`` is what the storage file holds at least) -- then sends a seeded number of further
messages (up to two flush intervals of the stream, so the kill falls anywhere between flushes, in
the middle of one too) and kills it. Then:

* every killed bag opens with rosbags, and an mcap one also with the independent ``mcap``
  library (CRCs validated); its messages are a gap-free prefix of what was sent, in order, and
  hold every message that was on disk when the kill came (at least message ``k``: a kill loses
  only what the recorder buffered since its last flush); ``metadata.yaml`` says the bag was not closed
  cleanly, is complete and counts at most what the file holds (it is replaced after the data of a
  flush, so a kill between the two leaves it one flush behind);
* every interrupted bag holds all messages, in order, with complete metadata (counts, clean
  close) and, for mcap, a summary whose statistics count them.

How long message ``k`` took to reach the disk and how old the oldest lost message was at each
kill are printed (``-s`` shows them; they depend on the load, so they are not asserted).
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


def _on_disk(bag: Path) -> int:
    """Messages the storage file holds at least: ``message_count`` of ``metadata.yaml``, which a
    flush replaces (atomically) after writing its data."""
    return int(_metadata(bag)["message_count"])


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


class _Killer:
    """Kills recorder ``name`` when what it did allows: message ``k`` on disk (a flush by the
    recorder itself), then ``extra`` more messages sent (the kill lands anywhere between flushes)."""

    def __init__(self, name: str, proc, bag: Path, k: int, extra: int) -> None:
        self.name, self.proc, self.bag, self.k, self.extra = name, proc, bag, k, extra
        self.flushed_at: int | None = None    # messages sent when message k was seen on disk
        self.latency = float("nan")           # s from sending message k to seeing it on disk
        self.on_disk = 0                      # what the disk held just before the kill
        self.killed: float | None = None      # time.monotonic() of the kill
        self.sent = 0                         # messages sent before the kill

    def step(self, sent_at: list[float], done: bool) -> None:
        """Called as the stream goes on (``done``: it has ended)."""
        n = len(sent_at)
        if self.killed is not None or n <= self.k:
            return
        if self.flushed_at is None:
            if _on_disk(self.bag) <= self.k:
                return
            self.flushed_at, self.latency = n, time.monotonic() - sent_at[self.k]
        if n < self.flushed_at + self.extra and not done:
            return
        self.on_disk = _on_disk(self.bag)
        self.proc.send_signal(signal.SIGKILL)
        self.killed, self.sent = time.monotonic(), n


@pytest.mark.slow
def test_sigkill_under_load_keeps_all_flushed_messages_and_sigint_closes(ros, tmp_path):
    from flight_fdi_msgs.msg import FilterState

    src = ros.node("crash_source")
    pub = src.create_publisher(FilterState, "fdi/state", _qos(depth=5000))
    counts = _counts_by_bag(src)
    rng = np.random.default_rng(SEED)
    n = int(RATE * DURATION_S)
    procs = {name: _start_recorder(tmp_path, f"output:={name}", f"storage:={storage}",
                                   f"compression:={compression}", f"flush_interval:={FLUSH_S}")
             for name, storage, compression, _ in RECORDERS}
    killers = [_Killer(name, procs[name], tmp_path / name, int(rng.integers(WARMUP, n // 2)),
                       int(rng.integers(0, int(2 * FLUSH_S * RATE))))
               for name, *_, sig in RECORDERS if sig == signal.SIGKILL]
    messages = [_state(i) for i in range(n)]
    sent_at: list[float] = []
    try:
        ros.wait_for_subscribers([pub], count=len(RECORDERS), timeout=60)
        # warm-up: the first message of a topic costs a recorder its type definition, hash and
        # metadata (hundreds of ms on a loaded machine); the guarantee is for a running recorder
        for i in range(WARMUP):
            pub.publish(messages[i])
            sent_at.append(time.monotonic())
        ros.spin_until(lambda: len(counts) == len(RECORDERS)
                       and all(c >= WARMUP for c in counts.values()), timeout=30,
                       what="every recorder reporting the warm-up messages")
        t0 = time.monotonic() - WARMUP / RATE
        while len(sent_at) < n:
            due = min(n, int((time.monotonic() - t0) * RATE) + 1)
            while len(sent_at) < due:
                pub.publish(messages[len(sent_at)])
                sent_at.append(time.monotonic())
            for killer in killers:
                killer.step(sent_at, done=False)
            ros.executor.spin_once(timeout_sec=0.0005)

        def all_killed() -> bool:  # (a loaded recorder may flush message k after the stream)
            for killer in killers:
                killer.step(sent_at, done=True)
            return all(killer.killed is not None for killer in killers)

        ros.spin_until(all_killed, timeout=60, what="every killed recorder flushing message k")
        interrupted = [name for name, *_, sig in RECORDERS if sig == signal.SIGINT]
        ros.spin_until(lambda: all(counts.get(k) == n for k in interrupted), timeout=60,
                       what="the interrupted recorders report every message")
        for name in interrupted:
            procs[name].send_signal(signal.SIGINT)
        for name in interrupted:
            rc = procs[name].wait(timeout=30)
            assert rc == 0, _stop(procs[name])[-4000:]
        for killer in killers:
            killer.proc.wait(timeout=10)
    finally:
        outputs = {name: _stop(p) for name, p in procs.items()}

    sent_at_arr = np.array(sent_at)
    by_name = {killer.name: killer for killer in killers}
    for name, storage, compression, sig in RECORDERS:
        bag = tmp_path / name
        got = _indices(bag)  # rosbags opens and reads it
        assert got == list(range(len(got))), f"{name}: not a gap-free prefix in order"
        meta = _metadata(bag)
        if sig == signal.SIGKILL:
            kl = by_name[name]
            lost_age = kl.killed - sent_at_arr[len(got)] if len(got) < kl.sent else 0.0
            print(f"{name}: message {kl.k} on disk {kl.latency * 1e3:.0f} ms after it was "
                  f"sent; killed after {kl.sent} messages, {kl.on_disk} on disk then, "
                  f"{len(got)} after the kill; the oldest lost one was {lost_age * 1e3:.0f} ms old")
            assert len(got) >= kl.on_disk > kl.k, (name, len(got), kl.on_disk, kl.k)
            assert meta["custom_data"]["closed_cleanly"] == "false"
            assert kl.on_disk <= meta["message_count"] <= len(got), (meta["message_count"],
                                                                     len(got))
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
