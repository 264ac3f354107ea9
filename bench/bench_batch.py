#!/usr/bin/env python3
"""Benchmark: ``flight-fdi batch`` on a fleet of sample-sized flights (a script, not a test).

N copies (default 50) of the sample bags (1000-s flights, 50 Hz INS, 10 Hz reference) are
analysed, each time from scratch, by the same batch (flight_fdi.campaign.batch.Batch) on

* ``loop``: the inline engine -- a plain loop over the flights in this process;
* ``1 worker``: a local Dask cluster of one worker process;
* ``2 workers``: a local Dask cluster of two worker processes;

in ``--rounds`` interleaved rounds (default 5). Each ratio is taken within a round (the two
runs one after the other) and the median over the rounds is the result; every round is printed
(the machine may be shared: say its load). The workers and this process are warmed up first
(imports, one analysis), and the clusters' start-up is reported apart. Targets on a 2-core
machine: speed-up 2 workers / 1 worker >= 1.7; the engine's overhead per flight (1 worker
against the loop) <= 10 %. Also prints the CPU time of
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
import statistics
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
    for t in os.listdir("/proc/self/task"):
        try:
            os.sched_setaffinity(int(t), every[:n])
        except OSError:  # the thread has ended since the listing
            pass
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
ONLY = {"overhead": ("loop, 1 core", "1 worker, 1 core"),
        "speedup": ("1 worker, 1 core", "2 workers")}


def run_rounds(a: argparse.Namespace, fleet: pathlib.Path, tmp: pathlib.Path,
               configs: dict) -> dict:
    """Every configuration once per round; per configuration the list of its rounds."""
    first = str(next(iter(sorted(fleet.iterdir()))))
    runs: dict[str, list[dict]] = {k: [] for k in configs}
    for r in range(a.rounds):
        for name, (spec, n_cores) in configs.items():
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


def ratios(runs: dict, a: str, b: str, key: str = "wall") -> list[float]:
    """Per round: ``a`` / ``b`` (both measured in that round, one after the other)."""
    return [x[key] / y[key] for x, y in zip(runs[a], runs[b])]


def summarize(a: argparse.Namespace, runs: dict, load: list) -> dict:
    """Print the targets (the median of the per-round ratios, each round listed) and return the
    numbers."""
    med = statistics.median
    one, loop, two = "1 worker, 1 core", "loop, 1 core", "2 workers"
    out: dict = {"flights": a.flights, "rounds": a.rounds, "loadavg": load, "runs": runs,
                 "median_wall_s": {k: med(r["wall"] for r in v) for k, v in runs.items()},
                 "median_cpu_s": {k: med(r["cpu"] for r in v) for k, v in runs.items()},
                 "loop_blas_threads": os.environ.get("OPENBLAS_NUM_THREADS", "default")}
    print(f"\nmedian of {a.rounds} rounds, wall s: " + ", ".join(
        f"{k} {v:.2f}" for k, v in out["median_wall_s"].items()))
    ok = True
    if one in runs and loop in runs:
        over = [x - 1.0 for x in ratios(runs, one, loop)]
        cpu_over = [x - 1.0 for x in ratios(runs, one, loop, "cpu")]
        out["overhead"], out["overhead_rounds"] = med(over), over
        out["cpu_overhead"], out["cpu_overhead_rounds"] = med(cpu_over), cpu_over
        ok &= out["overhead"] <= 0.10
        print(f"engine overhead per flight (1 worker / loop - 1, both on 1 core, wall): median "
              f"{100 * out['overhead']:+.1f} %  (target <= 10 %)  "
              f"{'PASS' if out['overhead'] <= 0.10 else 'MISS'}; rounds: "
              + ", ".join(f"{100 * x:+.1f} %" for x in over))
        print(f"  the same in CPU time of the process tree: median {100 * out['cpu_overhead']:+.1f}"
              " %; rounds: " + ", ".join(f"{100 * x:+.1f} %" for x in cpu_over))
        cost = out["median_cpu_s"][loop] / a.flights
        out["cost_s_per_flight"] = cost
        print(f"per-flight cost (loop on 1 core, CPU): {cost:.3f} s per 1000-s flight -> 10 000 "
              f"flights: {10_000 * cost / 3600:.2f} core-hours")
    if one in runs and two in runs:
        sp = ratios(runs, one, two)
        out["speedup"], out["speedup_rounds"] = med(sp), sp
        ok &= out["speedup"] >= 1.7
        print(f"speed-up 2 workers (2 cores) / 1 worker (1 core): median {out['speedup']:.2f}  "
              f"(target >= 1.7)  {'PASS' if out['speedup'] >= 1.7 else 'MISS'}; rounds: "
              + ", ".join(f"{x:.2f}" for x in sp))
    for k, v in runs.items():
        print(f"  {k:<19} CPU per flight (process tree) {out['median_cpu_s'][k] / a.flights:.3f}"
              f" s; on the worker {med(r['worker_s'] for r in v):.3f} s wall, "
              f"{med(r['worker_cpu_s'] for r in v):.3f} s CPU, "
              f"{med(r['faults'] for r in v):.0f} page faults per flight (medians)")
    print(f"load average before / after: {load[0][0]:.2f} / {load[1][0]:.2f} on "
          f"{os.cpu_count()} cores")
    out["ok"] = ok
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=50)
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--only", choices=["all", "overhead", "speedup"], default="all",
                    help="overhead: the loop and 1 worker on 1 core; speedup: 1 worker on 1 "
                         "core and 2 workers; all (default): those and both on all cores")
    ap.add_argument("--loop-blas-threads", type=int, default=1,
                    help="BLAS threads of this process's loop (default 1, as a Dask worker; "
                         "0: OpenBLAS's default)")
    ap.add_argument("--json", default=None, help="also write the numbers to this file")
    ap.add_argument("--strict", action="store_true", help="exit 1 when a target is missed")
    a = ap.parse_args()
    configs = {k: v for k, v in CONFIGS.items() if a.only == "all" or k in ONLY[a.only]}
    load = [os.getloadavg()]
    with tempfile.TemporaryDirectory(prefix="bench_batch_") as tmp:
        fleet = pathlib.Path(tmp) / "fleet"
        make_fleet(fleet, a.flights)
        print(f"{a.flights} flights of 1000 s (copies of bags/*), {os.cpu_count()} cores "
              f"({len(os.sched_getaffinity(0))} usable), load average {load[0][0]:.2f}; loop "
              f"BLAS threads {os.environ.get('OPENBLAS_NUM_THREADS', 'default')}")
        runs = run_rounds(a, fleet, pathlib.Path(tmp), configs)
    load.append(os.getloadavg())
    out = summarize(a, runs, load)
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps(out, indent=1))
    return 0 if out["ok"] or not a.strict else 1


if __name__ == "__main__":
    sys.exit(main())
