"""Soak: a long stream of input messages through filter_node and recorder_node in one process.

    .venv/bin/python bench/soak.py [--messages 1000000] [--block 50000] [--executor events]
                                   [--storage mcap] [--jitter-ms 0] [--json]

A driver node publishes INS velocity (50 Hz of stamp time) and reference velocity (10 Hz, 4 ms
after an INS sample) -- 6 input messages per 0.1 s of flight; one million is a 4.6-hour flight --
into ``filter_node`` (channels x and y, reliable inputs); ``recorder_node`` records its
``fdi/innovation``, ``fdi/state`` and ``fdi/model`` into a bag in a temporary directory (deleted
at the end). All three nodes share one executor in a private rclpy Context (nothing leaves the
process), as ``flight-fdi run`` does. The driver keeps at most ``--window`` input messages not yet
received by the filter (no queue overflows, no loss), so the stream runs as fast as the nodes go.

Every ``--block`` input messages it prints one row of the curve: messages so far, resident set
size (VmRSS), the growth since the end of the first block (the warm-up: imports, caches, DDS
buffers), and the wall time per input message over the block. Verdict:

* memory: RSS growth from the end of the first block to the end <= ``--max-growth-mb`` (20 MB);
* time: the time per message of the second half of the blocks is within ``--max-slowdown``
  (default 15 %) of the first half (blocks after the first), and a least-squares line through the
  blocks changes by less than that over the run;
* every input message was received by the filter, every output recorded.

Exit status 0 when the verdict passes, 1 otherwise. ``run_soak`` is also used by the short soak
test (``test/hardening/test_soak_short.py``).
"""
from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
os.environ.setdefault("ROS_DOMAIN_ID", str(100 + os.getpid() % 100))

import numpy as np  # noqa: E402

T0_NS = 1_700_000_000 * 1_000_000_000
INS_PERIOD_NS = 20_000_000   # 50 Hz
REF_EVERY = 5                # a reference after every 5th INS sample (10 Hz)
REF_OFFSET_NS = 4_000_000


def rss_mb() -> float:
    """Resident set size of this process [MB] (VmRSS)."""
    with open("/proc/self/status") as f:
        for line in f:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) / 1024.0
    raise RuntimeError("no VmRSS in /proc/self/status")


class Stream:
    """The input messages, generated on the fly (two message objects reused; rclpy copies on
    publish): INS at 50 Hz, a reference 4 ms after every 5th INS sample, velocities a slow
    manoeuvre plus seeded noise, reference variance 0.01 m^2/s^2."""

    def __init__(self, seed: int = 0, jitter_ms: float = 0.0) -> None:
        from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped

        self.rng = np.random.default_rng(seed)
        self.jitter_ns = int(jitter_ms * 1e6)
        self.ins = TwistStamped()
        self.ref = TwistWithCovarianceStamped()
        cov = np.zeros(36)
        cov[[0, 7, 14]] = 0.01
        self.ref.twist.covariance = cov
        self.k = 0          # messages produced
        self.i = 0          # INS samples produced
        self.refs = 0       # reference samples produced
        self._ref_ns: int | None = None
        self._noise = np.zeros((0, 3))

    def _draw(self) -> np.ndarray:
        if not len(self._noise):
            self._noise = self.rng.normal(0.0, 0.05, (4096, 3))
        row, self._noise = self._noise[0], self._noise[1:]
        return row

    @staticmethod
    def _stamp(msg, ns: int) -> None:
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)

    def next(self):
        """(kind, message) in stamp order: INS i, [reference at INS i + 4 ms], INS i + 1 ..."""
        self.k += 1
        if self._ref_ns is not None:
            t_ns, self._ref_ns = self._ref_ns, None
            t = (t_ns - T0_NS) * 1e-9
            n = self._draw()
            lin = self.ref.twist.twist.linear
            lin.x, lin.y, lin.z = 50.0 + 5.0 * np.sin(t / 600.0) + n[0], -20.0 + n[1], 1.0 + n[2]
            self._stamp(self.ref, t_ns)
            self.refs += 1
            return "ref", self.ref
        i = self.i
        t_ns = T0_NS + i * INS_PERIOD_NS
        lin = self.ins.twist.linear
        lin.x, lin.y, lin.z = 50.0 + 5.0 * np.sin(i * INS_PERIOD_NS * 1e-9 / 600.0), -20.0, 1.0
        self._stamp(self.ins, t_ns)
        self.i += 1
        if i % REF_EVERY == 0:
            jitter = int(self.rng.integers(-self.jitter_ns, self.jitter_ns + 1)) \
                if self.jitter_ns else 0
            self._ref_ns = t_ns + REF_OFFSET_NS + jitter
        return "ins", self.ins


def run_soak(n_messages: int = 1_000_000, block: int = 50_000, executor: str = "events",
             storage: str = "mcap", window: int = 50, jitter_ms: float = 0.0,
             out_dir: str | Path | None = None, progress=print,
             flush_interval: float = 1.0) -> dict:
    """Run the soak; returns {"rows": [...], "received": ..., "recorded": {...}, ...}.

    Each row: messages (cumulative), rss_mb, growth_mb (since the end of the first block),
    us_per_msg (over the block), elapsed_s. ``flush_interval``: the recorder's (its buffer of
    up to one interval of messages, ~2.5 MB at the default 1 s, shows as RSS noise)."""
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from rclpy.node import Node
    from rclpy.parameter import Parameter
    from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy

    from flight_fdi.nodes.filter_node import FilterNode
    from flight_fdi.nodes.pipeline import _private_context
    from flight_fdi.nodes.runner import make_executor
    from flight_fdi.nodes.recorder_node import RecorderNode

    tmp = Path(out_dir) if out_dir is not None else Path(tempfile.mkdtemp(prefix="fdi_soak_"))
    bag = tmp / "soak_bag"
    rows: list[dict] = []
    with _private_context(["--log-level", "error"]) as ctx:
        ex = make_executor(executor, ctx)
        kw = {"context": ctx, "start_parameter_services": False}
        flt = FilterNode(parameter_overrides=[Parameter("input_qos", value="reliable"),
                                              Parameter("input_queue_depth", value=1000)], **kw)
        rec = RecorderNode(parameter_overrides=[Parameter("output", value=str(bag)),
                                                Parameter("storage", value=storage),
                                                Parameter("flush_interval",
                                                          value=float(flush_interval))], **kw)
        drv = Node("soak_driver", **kw)
        nodes = [flt, rec, drv]
        for node in nodes:
            ex.add_node(node)
        try:
            qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=1000,
                             reliability=ReliabilityPolicy.RELIABLE)
            pubs = {"ins": drv.create_publisher(TwistStamped, "/ins/velocity", qos),
                    "ref": drv.create_publisher(TwistWithCovarianceStamped,
                                                "/reference/velocity", qos)}
            deadline = time.monotonic() + 30
            while any(p.get_subscription_count() < 1 for p in pubs.values()):
                if time.monotonic() > deadline:
                    raise RuntimeError("the filter did not subscribe within 30 s")
                ex.spin_once(timeout_sec=0.05)
            stream = Stream(jitter_ms=jitter_ms)
            c = flt.counters
            sent = 0

            def received() -> int:
                return c["received_ins"] + c["received_reference"]

            def refill() -> None:
                nonlocal sent
                while sent < n_messages and sent - received() < window:
                    kind, msg = stream.next()
                    pubs[kind].publish(msg)
                    sent += 1

            # refill from the filter's own output too, so the executor never waits for the loop
            from flight_fdi_msgs.msg import FilterState

            drv.create_subscription(FilterState, "fdi/state", lambda _m: refill(), qos)
            t_start = t_block = time.perf_counter()
            base_rss = None
            prev = 0
            while prev < n_messages:
                refill()
                ex.spin_once(timeout_sec=0.05)
                r = received()
                if r - prev < block and r < n_messages:
                    continue
                now = time.perf_counter()
                rss = rss_mb()
                if base_rss is None:
                    base_rss = rss  # the end of the first block: after the warm-up
                row = {"messages": r, "rss_mb": round(rss, 2), "growth_mb": round(rss - base_rss, 2),
                       "us_per_msg": round((now - t_block) / (r - prev) * 1e6, 2),
                       "elapsed_s": round(now - t_start, 1)}
                rows.append(row)
                progress(f"{row['messages']:>9d} msgs  RSS {row['rss_mb']:8.1f} MB  "
                         f"growth {row['growth_mb']:+6.1f} MB  {row['us_per_msg']:7.1f} us/msg  "
                         f"({row['elapsed_s']:.0f} s)")
                t_block, prev = now, r
            # the last outputs reach the recorder
            state_topic = rec.resolve_topic_name("fdi/state")
            want = 2 * stream.refs  # a state per reference sample on each of the two channels
            deadline = time.monotonic() + 60
            while rec.counts()[state_topic] < want and time.monotonic() < deadline:
                ex.spin_once(timeout_sec=0.05)
            rec.close()
            recorded = rec.counts()
            return {"rows": rows, "sent": sent, "received": received(), "references": stream.refs,
                    "recorded": recorded, "expected_states": want,
                    "bag_mb": round(sum(f.stat().st_size for f in bag.iterdir()) / 2**20, 1),
                    "executor": executor, "storage": storage, "jitter_ms": jitter_ms,
                    "dropped": {k: v for k, v in flt.counters.items() if k.startswith("dropped")}}
        finally:
            for node in nodes:
                ex.remove_node(node)
                node.destroy_node()
            ex.shutdown()
            if out_dir is None:
                shutil.rmtree(tmp, ignore_errors=True)


def verdict(result: dict, max_growth_mb: float = 20.0, max_slowdown: float = 0.15) -> dict:
    """Memory growth, time-per-message trend and completeness against the limits."""
    rows = result["rows"]
    growth = rows[-1]["growth_mb"]
    peak_growth = max(r["growth_mb"] for r in rows)
    steady = rows[1:]  # the first block is the warm-up
    us = np.array([r["us_per_msg"] for r in steady]) if steady else np.array([np.nan])
    x = np.array([r["messages"] for r in steady], dtype=float) if steady else np.array([0.0])
    half = max(1, len(us) // 2)
    first = float(np.median(us[:half]))
    second = float(np.median(us[half:])) if len(us) > 1 else first
    slope_change = np.nan
    if len(us) >= 3:
        a, b = np.polyfit(x, us, 1)
        slope_change = float(a * (x[-1] - x[0]) / np.median(us))
    recorded_ok = (result["received"] == result["sent"]
                   and result["recorded"].get("/fdi/state", 0) == result["expected_states"]
                   and result["recorded"].get("/fdi/innovation", 0) == result["expected_states"])
    ok_mem = peak_growth <= max_growth_mb
    ok_time = (second / first - 1.0 <= max_slowdown
               and (np.isnan(slope_change) or slope_change <= max_slowdown))
    return {"growth_mb": growth, "peak_growth_mb": peak_growth, "max_growth_mb": max_growth_mb,
            "us_per_msg_first_half": round(first, 2), "us_per_msg_second_half": round(second, 2),
            "trend_over_run": None if np.isnan(slope_change) else round(slope_change, 4),
            "max_slowdown": max_slowdown, "complete": bool(recorded_ok),
            "memory_ok": bool(ok_mem), "time_flat": bool(ok_time),
            "passed": bool(ok_mem and ok_time and recorded_ok)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--messages", type=int, default=1_000_000)
    ap.add_argument("--block", type=int, default=50_000)
    ap.add_argument("--executor", choices=("events", "single"), default="events")
    ap.add_argument("--storage", choices=("mcap", "sqlite3"), default="mcap")
    ap.add_argument("--window", type=int, default=50)
    ap.add_argument("--jitter-ms", type=float, default=0.0,
                    help="uniform jitter of the reference stamps (default 0)")
    ap.add_argument("--max-growth-mb", type=float, default=20.0)
    ap.add_argument("--max-slowdown", type=float, default=0.15)
    ap.add_argument("--json", action="store_true", help="print the result as JSON at the end")
    args = ap.parse_args(argv)
    print(f"soak: {args.messages} input messages, executor {args.executor}, storage "
          f"{args.storage}, jitter {args.jitter_ms} ms; RSS at start {rss_mb():.1f} MB")
    result = run_soak(args.messages, args.block, args.executor, args.storage, args.window,
                      args.jitter_ms)
    v = verdict(result, args.max_growth_mb, args.max_slowdown)
    result["verdict"] = v
    print(f"received {result['received']} of {result['sent']} input messages; recorded "
          f"{result['recorded']} (expected {result['expected_states']} states); bag "
          f"{result['bag_mb']} MB; drops {result['dropped'] or 'none'}")
    print(f"memory: growth {v['growth_mb']:+.1f} MB at the end, peak {v['peak_growth_mb']:+.1f} "
          f"MB (limit {v['max_growth_mb']} MB) -> {'OK' if v['memory_ok'] else 'FAIL'}")
    print(f"time per message: {v['us_per_msg_first_half']} us (first half) -> "
          f"{v['us_per_msg_second_half']} us (second half); linear trend over the run "
          f"{v['trend_over_run']} (limit {v['max_slowdown']}) -> "
          f"{'flat' if v['time_flat'] else 'NOT FLAT'}")
    print(f"verdict: {'PASS' if v['passed'] else 'FAIL'}")
    if args.json:
        print(json.dumps(result, indent=1))
    return 0 if v["passed"] else 1


if __name__ == "__main__":
    sys.exit(main())
