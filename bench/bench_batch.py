#!/usr/bin/env python3
"""Benchmark: ``flight-fdi batch`` on a fleet of sample-sized flights (a script, not a test).

N copies (default 50) of the sample bags (1000-s flights, 50 Hz INS, 10 Hz reference) are
analysed, each time from scratch, by the same batch (flight_fdi.campaign.batch.Batch) on

* ``loop``: the inline engine -- a plain loop over the flights in this process;
* ``1 worker``: a local Dask cluster of one worker process;
* ``2 workers``: a local Dask cluster of two worker processes;

in ``--rounds`` interleaved rounds (the best of each is kept: the machine may be shared). The
workers and this process are warmed up first (imports, one analysis), and the clusters' start-up
is reported apart. Targets on a 2-core machine: speed-up 2 workers / 1 worker >= 1.7; the
engine's overhead per flight (1 worker against the loop) <= 10 %. Also prints the CPU time of
the process tree per flight, and what a 10 000-flight study costs in core-hours (the loop's CPU
time per flight x 10 000).
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.campaign.batch import Batch  # noqa: E402
from flight_fdi.campaign.engine import Engine, EngineSpec  # noqa: E402
from flight_fdi.cli.main import build_parser  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[1]
SAMPLES = ["nominal", "accel_fault_500s", "gyro_fault_500s"]


def make_fleet(dest: pathlib.Path, n: int) -> list[pathlib.Path]:
    out = []
    for i in range(n):
        target = dest / f"flight_{i:03d}"
        shutil.copytree(ROOT / "bags" / SAMPLES[i % len(SAMPLES)], target)
        out.append(target)
    return out


def warm_up(bag: str) -> float:
    """Import the analysis and analyse one flight (in whatever process runs it)."""
    from flight_fdi.campaign.batch import FlightTask, analyze_task

    args = build_parser("batch").parse_args(["batch", bag, "--out", "-"])
    args.jobs = 1
    return analyze_task(FlightTask("warm", bag, args))["seconds"]


def tree_cpu() -> float:
    """CPU seconds (user + system) of this process and every process it started (the local
    cluster's nannies and workers) so far."""
    import psutil

    me = psutil.Process()
    total = 0.0
    for p in [me] + me.children(recursive=True):
        try:
            t = p.cpu_times()
        except psutil.Error:
            continue
        total += t.user + t.system
    return total


def run_once(engine: Engine, fleet: pathlib.Path, out: pathlib.Path) -> tuple[float, float, list]:
    """(wall s, CPU s of the whole process tree, per-flight wall s on the workers)."""
    args = build_parser("batch").parse_args(["batch", str(fleet), "--out", str(out)])
    cpu0, start = tree_cpu(), time.perf_counter()
    res = Batch([str(fleet)], out, args, force=True).run(engine)
    wall, cpu = time.perf_counter() - start, tree_cpu() - cpu0
    assert res.failed == 0 and res.analysed == len(res.rows), res
    return wall, cpu, res.seconds


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--json", default=None, help="also write the numbers to this file")
    ap.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    a = ap.parse_args()
    configs = {"loop": EngineSpec(workers=1), "1 worker": EngineSpec(workers=1, inline=False),
               "2 workers": EngineSpec(workers=2)}
    best: dict[str, float] = {}
    cpu_best: dict[str, float] = {}
    per_flight: dict[str, float] = {}
    rounds: list[dict[str, float]] = []
    startup: dict[str, float] = {}
    load = [os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        fleet = pathlib.Path(tmp) / "fleet"
        make_fleet(fleet, a.flights)
        first = str(next(iter(sorted(fleet.iterdir()))))
        print(f"{a.flights} flights of 1000 s (copies of bags/*), {os.cpu_count()} cores, "
              f"load average {load[0][0]:.2f}")
        for r in range(a.rounds):
            rounds.append({})
            for name, spec in configs.items():
                t0 = time.perf_counter()
                with Engine(spec) as engine:
                    startup[name] = time.perf_counter() - t0
                    if engine.client is None:
                        warm_up(first)
                    else:
                        engine.client.run(warm_up, first)
                    wall, cpu, seconds = run_once(engine, fleet,
                                                  pathlib.Path(tmp) / f"out{r}{name}")
                print(f"  round {r + 1} {name:<10} {wall:7.2f} s  ({wall / a.flights:.3f} s per "
                      f"flight; CPU {cpu / a.flights:.3f} s per flight; on the worker "
                      f"{sum(seconds) / len(seconds):.3f} s per flight; engine start "
                      f"{startup[name]:.1f} s)")
                if wall < best.get(name, float("inf")):
                    best[name], per_flight[name] = wall, sum(seconds) / len(seconds)
                cpu_best[name] = min(cpu, cpu_best.get(name, float("inf")))
                rounds[-1][name] = wall
    load.append(os.getloadavg())
    speedup = best["1 worker"] / best["2 workers"]
    overhead = best["1 worker"] / best["loop"] - 1.0
    cost = cpu_best["loop"] / a.flights  # CPU: what a core spends, whatever the load
    print(f"\nbest of {a.rounds}: loop {best['loop']:.2f} s, 1 worker {best['1 worker']:.2f} s, "
          f"2 workers {best['2 workers']:.2f} s")
    print(f"speed-up 2 workers / 1 worker: {speedup:.2f}  (target >= 1.7)  "
          f"{'PASS' if speedup >= 1.7 else 'MISS'}")
    print(f"engine overhead per flight (1 worker / loop - 1): {100 * overhead:+.1f} %  "
          f"(target <= 10 %)  {'PASS' if overhead <= 0.10 else 'MISS'}")
    cpu_overhead = {k: v / cpu_best["loop"] - 1.0 for k, v in cpu_best.items()}
    print("CPU per flight (this process and its workers): " + ", ".join(
        f"{k} {v / a.flights:.3f} s ({100 * cpu_overhead[k]:+.1f} %)" for k, v in cpu_best.items()))
    print(f"per-flight cost (loop, CPU): {cost:.3f} s per 1000-s flight -> 10 000 flights: "
          f"{10_000 * cost / 3600:.2f} core-hours")
    for r, walls in enumerate(rounds):
        print(f"round {r + 1} alone: speed-up {walls['1 worker'] / walls['2 workers']:.2f}, "
              f"overhead {100 * (walls['1 worker'] / walls['loop'] - 1):+.1f} %")
    print(f"load average before / after: {load[0][0]:.2f} / {load[1][0]:.2f} on "
          f"{os.cpu_count()} cores")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({
            "flights": a.flights, "rounds": a.rounds, "best_s": best,
            "worker_s_per_flight": per_flight, "engine_start_s": startup, "speedup": speedup,
            "cpu_s": cpu_best, "cpu_overhead": cpu_overhead,
            "overhead": overhead, "cost_s_per_flight": cost, "rounds": rounds,
            "loadavg": load}, indent=1))
    ok = speedup >= 1.7 and overhead <= 0.10
    return 0 if ok or not a.strict else 1


if __name__ == "__main__":
    sys.exit(main())
