#!/usr/bin/env python3
"""Benchmark: the whole ``flight-fdi analyze`` of a 3-hour flight (a script, not a test).

INS at 50 Hz and reference at 10 Hz for 3 h: 540 000 + 108 000 messages (plus truth). The flight
is simulated once into ``--bag`` (default /tmp/flight_fdi_bench_3h) and reused. Reports the time
of each stage (bag reading, forward filter, backward pass + seed statistics, GLR) and of the
whole command in a fresh process. Target: <= 5 s for the whole analysis on a 2-core machine.
"""
from __future__ import annotations

import argparse
import os
import pathlib
import resource
import subprocess
import sys
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.bagio import read_flight  # noqa: E402
from flight_fdi.core.align import align_to_reference  # noqa: E402
from flight_fdi.core.analysis import AnalysisConfig, analyze_forward  # noqa: E402
from flight_fdi.core.diagnosis import diagnose  # noqa: E402
from flight_fdi.core.glr import isolate  # noqa: E402
from flight_fdi.core.kalman import run_forward  # noqa: E402
from flight_fdi.core.models import ins_channel  # noqa: E402
from flight_fdi.core.smoother import run_backward  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
CLI = ROOT / ".venv" / "bin" / "flight-fdi"


def timed(label, fn, *a, **k):
    t0 = time.perf_counter()
    out = fn(*a, **k)
    dt = time.perf_counter() - t0
    print(f"  {label:<34}{dt:7.2f} s")
    return out, dt


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--bag", default="/tmp/flight_fdi_bench_3h")
    ap.add_argument("--duration", type=float, default=10800.0)
    args = ap.parse_args()
    bag = pathlib.Path(args.bag)
    if not bag.exists():
        print(f"simulating a {args.duration:.0f}-s flight into {bag} ...")
        subprocess.run([str(CLI), "simulate", str(bag), "--duration", str(args.duration),
                        "--seed", "3", "--fault", "accel:step:t=5000,mag=0.01"], check=True)
    model = ins_channel()
    config = AnalysisConfig()
    print(f"stages on {bag}:")
    flight, t_read = timed("read_flight", read_flight, bag, "x", with_truth=False)
    (valid, v_at), t_align = timed("align", align_to_reference, flight.ins_rel_s, flight.v_ins,
                                   flight.ref_rel_s, config.max_gap_s)
    z = (v_at - flight.v_ref)[valid][:, None]
    fwd, t_fwd = timed(f"forward filter ({z.shape[0]} steps)", run_forward, model,
                       flight.ref_rel_s[valid], z, gate=config.gate)
    bwd, t_bwd = timed("backward pass", run_backward, model, fwd)
    _, t_diag = timed("seed statistics", diagnose, model, fwd, bwd)
    _, t_glr = timed("GLR isolation", isolate, model, fwd)
    res, t_post = timed("analyze_forward (all post-flight)", analyze_forward, model, fwd, config,
                        str(bag), "x", 0.0)
    # wall time, and the CPU time of the process (less sensitive to other load on the machine);
    # the default uses two processes (--jobs 2), --jobs 1 is the one-process baseline
    for jobs in ("2", "1"):
        ru0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        subprocess.run([str(CLI), "analyze", str(bag), "--json", "--jobs", jobs], check=True,
                       stdout=subprocess.DEVNULL)
        t_cli = time.perf_counter() - t0
        ru1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (ru1.ru_utime - ru0.ru_utime) + (ru1.ru_stime - ru0.ru_stime)
        label = f"flight-fdi analyze --jobs {jobs}"
        print(f"  {label:<34}{t_cli:7.2f} s wall, {cpu:.2f} s CPU; target <= 5 s: "
              f"{'met' if t_cli <= 5.0 else 'NOT met'} (load average {os.getloadavg()[0]:.1f})")
    s = res.summary
    print(f"verdict: {s['post_flight']['verdict']} {s['post_flight']['element']} "
          f"onset {s['post_flight']['onset_s']}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
