"""Inputs lost at 10x real time across processes: the filter's old input defaults against its new
ones, in one run.

    .venv/bin/python bench/bench_replay_10x.py [--duration 120] [--repeat 3] [--stall 0.5]

bag_player (``rate:=10``: 600 messages/s of a 50 Hz INS + 10 Hz reference flight) and
filter_node run as two processes (the installed executables); the filter's ``/diagnostics``
give what it received, dropped and fused. Each repetition runs

1. baseline: the old defaults ``input_qos:=sensor_data input_queue_depth:=100``;
2. the defaults of this version (``input_qos`` auto -> reliable, ``input_queue_depth`` 2000).

``--stall S`` stops the filter process (SIGSTOP) for S seconds in the middle of each replay: a
loaded machine descheduling it, exaggerated, so the difference shows on a quiet machine too.
Prints, per configuration, the INS and reference messages missing (sent - received) and the
drop counts, summed over the repetitions.
"""
from __future__ import annotations

import argparse
import os
import signal
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path[:0] = [str(HERE.parent / "test"), str(HERE.parent / "test" / "nodes")]

import harness  # noqa: E402  (private ROS domain for this run and its processes)
from test_graph import DiagnosticsProbe, start, stop  # noqa: E402

CONFIGS = {"old defaults (sensor_data, depth 100)": ["-p", "input_qos:=sensor_data",
                                                     "-p", "input_queue_depth:=100"],
           "new defaults (auto, depth 2000)": []}


def one(ros, probe, bag: Path, work: Path, run: int, extra: list[str], n_ins: int, n_ref: int,
        stall: float) -> dict:
    f = f"filter_b{run}"
    procs = [start("filter_node", work, "-r", f"__node:={f}", "-p", "diagnostics_period_s:=0.25",
                   *extra)]
    try:
        ros.spin_until(lambda: f"{f}: inputs" in probe.values, timeout=60, what="filter start")
        player = start("bag_player", work, "-p", f"bag:={bag}", "-p", "rate:=10.0")
        procs.append(player)
        if stall:
            ros.spin_until(lambda: int(probe.get(f"{f}: inputs", "received_ins", "0")) > n_ins // 3,
                           timeout=120, what="a third of the replay")
            os.kill(procs[0].pid, signal.SIGSTOP)
            time.sleep(stall)
            os.kill(procs[0].pid, signal.SIGCONT)
        ros.spin_until(lambda: player.poll() is not None, timeout=600, what="the replay")
        # the filter's counts stop changing: it has taken what reached it
        last, since = None, time.monotonic()
        while time.monotonic() - since < 1.5:
            ros.executor.spin_once(timeout_sec=0.1)
            now = (probe.get(f"{f}: inputs", "received_ins"),
                   probe.get(f"{f}: inputs", "received_reference"))
            if now != last:
                last, since = now, time.monotonic()
    finally:
        stop(procs)
    v = probe.values[f"{f}: inputs"]
    drops = {k: int(x) for k, x in v.items() if k.startswith("dropped_") and x != "0"}
    return {"missing_ins": n_ins - int(v["received_ins"]),
            "missing_reference": n_ref - int(v["received_reference"]), "drops": drops}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=120.0, help="flight seconds (wall: /10)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--stall", type=float, default=0.0, help="SIGSTOP the filter this long")
    args = ap.parse_args()
    from flight_fdi.sim import SimConfig, simulate_to_bag

    work = Path(tempfile.mkdtemp(prefix="bench10x_"))
    bag = work / "flight"
    simulate_to_bag(SimConfig(duration_s=args.duration, seed=5), str(bag))
    n_ins, n_ref = int(round(args.duration * 50)), int(round(args.duration * 10))
    ros = harness.RosHarness()
    try:
        probe = DiagnosticsProbe(ros)
        totals = {name: {"missing_ins": 0, "missing_reference": 0, "drops": {}}
                  for name in CONFIGS}
        run = 0
        for rep in range(args.repeat):
            for name, extra in CONFIGS.items():
                r = one(ros, probe, bag, work, run, extra, n_ins, n_ref, args.stall)
                run += 1
                print(f"run {rep + 1} {name}: {r}", flush=True)
                t = totals[name]
                t["missing_ins"] += r["missing_ins"]
                t["missing_reference"] += r["missing_reference"]
                for k, x in r["drops"].items():
                    t["drops"][k] = t["drops"].get(k, 0) + x
    finally:
        ros.close()
    print(f"\n{args.repeat} x {n_ins} INS + {n_ref} reference messages at 10x"
          f"{f', filter stopped {args.stall:g} s per run' if args.stall else ''}; "
          f"load average {os.getloadavg()[0]:.1f}")
    for name, t in totals.items():
        print(f"  {name}: missing INS {t['missing_ins']}, missing reference "
              f"{t['missing_reference']}, drops {t['drops'] or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
