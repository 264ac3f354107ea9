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
the process tree per flight, what each flight cost on its worker (wall, CPU, minor page
faults), and what a 10 000-flight study costs in core-hours (the loop's CPU time per flight x
10 000).

Apples to apples: a Dask worker runs with one thread per BLAS pool (Dask's nanny sets
OMP/MKL/OPENBLAS_NUM_THREADS=1: a worker is one core), so the loop in this process does too
(set below, before numpy loads; ``--loop-blas-threads 0`` leaves OpenBLAS its default, one
thread per core). Both keep the analysis's own second thread (GLR beside the backward pass).
"""
from __future__ import annotations

import argparse
import contextlib
import json
import os
import pathlib
import shutil
import sys
import tempfile
import time


def _blas_threads_from_argv() -> None:
    """OpenBLAS reads its thread count when numpy loads: set it before any import."""
    n = "1"
    if "--loop-blas-threads" in sys.argv[:-1]:
        n = sys.argv[sys.argv.index("--loop-blas-threads") + 1]
    if n != "0":
        for k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
            os.environ[k] = n


_blas_threads_from_argv()
sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

from flight_fdi.campaign.batch import Batch  # noqa: E402
from flight_fdi.campaign.engine import Engine, EngineSpec  # noqa: E402
from flight_fdi.campaign.worker import warm_analysis  # noqa: E402
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


def run_once(engine: Engine, fleet: pathlib.Path, out: pathlib.Path):
    """(wall s, CPU s of the whole process tree, the BatchResult: per-flight wall s, CPU s and
    page faults on the workers)."""
    args = build_parser("batch").parse_args(["batch", str(fleet), "--out", str(out)])
    cpu0, start = tree_cpu(), time.perf_counter()
    res = Batch([str(fleet)], out, args, force=True).run(engine)
    wall, cpu = time.perf_counter() - start, tree_cpu() - cpu0
    assert res.failed == 0 and res.analysed == len(res.rows), res
    return wall, cpu, res


def _mean(values: list) -> float:
    return sum(values) / len(values)


@contextlib.contextmanager
def cores(n: int | None):
    """Run this process -- every thread of it, and the processes it starts meanwhile (a local
    cluster's scheduler, nannies and workers inherit it) -- on its first ``n`` CPUs (None: on
    all)."""
    every = sorted(os.sched_getaffinity(0))
    if n is None or n >= len(every):
        yield
        return
    tasks = [int(t) for t in os.listdir("/proc/self/task")]
    for t in tasks:
        os.sched_setaffinity(t, every[:n])
    try:
        yield
    finally:
        for t in os.listdir("/proc/self/task"):
            try:
                os.sched_setaffinity(int(t), every)
            except OSError:  # the thread has ended
                pass


#: name -> (engine, cores it may use: None = all)
CONFIGS = {"loop, 1 core": (EngineSpec(workers=1), 1),
           "1 worker, 1 core": (EngineSpec(workers=1, inline=False), 1),
           "2 workers": (EngineSpec(workers=2), None),
           "loop, all cores": (EngineSpec(workers=1), None),
           "1 worker, all cores": (EngineSpec(workers=1, inline=False), None)}


def run_rounds(a: argparse.Namespace, fleet: pathlib.Path, tmp: pathlib.Path) -> dict:
    """Every configuration once per round; per configuration the list of its rounds."""
    first = str(next(iter(sorted(fleet.iterdir()))))
    runs: dict[str, list[dict]] = {k: [] for k in CONFIGS}
    for r in range(a.rounds):
        for name, (spec, n_cores) in CONFIGS.items():
            t0 = time.perf_counter()
            with cores(n_cores), Engine(spec, warm=warm_analysis) as engine:
                start = time.perf_counter() - t0
                if engine.client is None:
                    warm_up(first)
                else:
                    engine.client.run(warm_up, first)
                wall, cpu, res = run_once(engine, fleet, tmp / f"out{r}{name}")
            run = {"wall": wall, "cpu": cpu, "start": start, "worker_s": _mean(res.seconds),
                   "worker_cpu_s": _mean(res.cpu_s), "faults": _mean(res.page_faults),
                   "load": os.getloadavg()[0]}
            runs[name].append(run)
            print(f"  round {r + 1} {name:<19} {wall:7.2f} s  ({wall / a.flights:.3f} s per "
                  f"flight; CPU {cpu / a.flights:.3f} s per flight; on the worker "
                  f"{run['worker_s']:.3f} s wall, {run['worker_cpu_s']:.3f} s CPU, "
                  f"{run['faults']:.0f} page faults per flight; engine start {start:.1f} s; "
                  f"load {run['load']:.1f})", flush=True)
    return runs


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=2)
    ap.add_argument("--loop-blas-threads", type=int, default=1,
                    help="BLAS threads of this process's loop (default 1, as a Dask worker; "
                         "0: OpenBLAS's default)")
    ap.add_argument("--json", default=None, help="also write the numbers to this file")
    ap.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    a = ap.parse_args()
    load = [os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        fleet = pathlib.Path(tmp) / "fleet"
        make_fleet(fleet, a.flights)
        print(f"{a.flights} flights of 1000 s (copies of bags/*), {os.cpu_count()} cores, "
              f"load average {load[0][0]:.2f}; loop BLAS threads "
              f"{os.environ.get('OPENBLAS_NUM_THREADS', 'default')}")
        runs = run_rounds(a, fleet, pathlib.Path(tmp))
    load.append(os.getloadavg())
    best = {k: min(r["wall"] for r in v) for k, v in runs.items()}
    cpu_best = {k: min(r["cpu"] for r in v) for k, v in runs.items()}
    one, loop = "1 worker, 1 core", "loop, 1 core"
    speedup = best[one] / best["2 workers"]
    overhead = best[one] / best[loop] - 1.0
    overhead_all = best["1 worker, all cores"] / best["loop, all cores"] - 1.0
    cost = cpu_best[loop] / a.flights  # CPU: what a core spends, whatever the load
    print(f"\nbest of {a.rounds} (s): " + ", ".join(f"{k} {v:.2f}" for k, v in best.items()))
    print(f"speed-up 2 workers (2 cores) / 1 worker (1 core): {speedup:.2f}  (target >= 1.7)  "
          f"{'PASS' if speedup >= 1.7 else 'MISS'}; 2 workers / 1 worker on all cores: "
          f"{best['1 worker, all cores'] / best['2 workers']:.2f}; 2 workers / loop on all "
          f"cores: {best['loop, all cores'] / best['2 workers']:.2f}")
    print(f"engine overhead per flight (1 worker / loop - 1, both on 1 core): "
          f"{100 * overhead:+.1f} %  (target <= 10 %)  {'PASS' if overhead <= 0.10 else 'MISS'}"
          f"; on all cores {100 * overhead_all:+.1f} %")
    cpu_overhead = {k: v / cpu_best[loop] - 1.0 for k, v in cpu_best.items()}
    print("CPU per flight (this process and its workers): " + ", ".join(
        f"{k} {v / a.flights:.3f} s ({100 * cpu_overhead[k]:+.1f} %)" for k, v in cpu_best.items()))
    print(f"per-flight cost (loop on 1 core, CPU): {cost:.3f} s per 1000-s flight -> 10 000 "
          f"flights: {10_000 * cost / 3600:.2f} core-hours")
    for r in range(a.rounds):
        w = {k: v[r]["wall"] for k, v in runs.items()}
        print(f"round {r + 1} alone: speed-up {w[one] / w['2 workers']:.2f}, "
              f"overhead {100 * (w[one] / w[loop] - 1):+.1f} % (1 core), "
              f"{100 * (w['1 worker, all cores'] / w['loop, all cores'] - 1):+.1f} % (all cores)")
    print(f"load average before / after: {load[0][0]:.2f} / {load[1][0]:.2f} on "
          f"{os.cpu_count()} cores")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({
            "flights": a.flights, "rounds": a.rounds, "best_s": best, "runs": runs,
            "speedup": speedup, "cpu_s": cpu_best, "cpu_overhead": cpu_overhead,
            "overhead": overhead, "overhead_all_cores": overhead_all,
            "cost_s_per_flight": cost, "loadavg": load,
            "loop_blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default")}, indent=1))
    ok = speedup >= 1.7 and overhead <= 0.10
    return 0 if ok or not a.strict else 1


if __name__ == "__main__":
    sys.exit(main())
