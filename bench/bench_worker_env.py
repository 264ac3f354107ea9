#!/usr/bin/env python3
"""Benchmark: what a Dask worker's environment costs one flight's analysis (a script, not a test).

The same sample flights are analysed (``analyze_task``, as ``flight-fdi batch`` does) in fresh
processes that differ only in their environment, alternating settings so that a machine shared
with other work treats them alike:

* ``plain``: this shell's environment (OpenBLAS: one thread per core);
* ``blas1``: OMP/MKL/OPENBLAS_NUM_THREADS=1, what every Dask worker gets from its nanny;
* ``dask-default``: Dask's whole default worker environment, ``blas1`` plus
  ``MALLOC_TRIM_THRESHOLD_=65536`` (``distributed.nanny.pre-spawn-environ``);
* ``dask-default+restore``: the same, then the engine's worker setup
  (:func:`flight_fdi.campaign.worker.restore_malloc`) at process start.

Per flight: wall time, user and system CPU time, minor page faults (the last three do not depend
on the load). The campaign engine's local cluster uses ``blas1``; its workers on clusters started
with ``dask worker`` get ``dask-default+restore``.
"""
from __future__ import annotations

import argparse
import json
import os
import pathlib
import statistics
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
BLAS1 = {"OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1"}
SETTINGS = {"plain": {}, "blas1": BLAS1,
            "dask-default": {**BLAS1, "MALLOC_TRIM_THRESHOLD_": "65536"},
            "dask-default+restore": {**BLAS1, "MALLOC_TRIM_THRESHOLD_": "65536",
                                     "BENCH_RESTORE_MALLOC": "1"}}
CHILD = r'''
import json, os, resource, sys, time
sys.path.insert(0, sys.argv[2])
if os.environ.get("BENCH_RESTORE_MALLOC"):
    from flight_fdi.campaign.worker import restore_malloc
    assert restore_malloc()
from flight_fdi.campaign.batch import FlightTask, analyze_task
from flight_fdi.cli.main import build_parser
bags = [f"{sys.argv[2]}/bags/{b}" for b in ("nominal", "accel_fault_500s", "gyro_fault_500s")]
args = build_parser("batch").parse_args(["batch", bags[0], "--out", "-"]); args.jobs = 1
for b in bags[:2]:
    analyze_task(FlightTask("warm", b, args))
out = []
for i in range(int(sys.argv[1])):
    r0 = resource.getrusage(resource.RUSAGE_SELF); t0 = time.perf_counter()
    assert analyze_task(FlightTask("x", bags[i % 3], args))["error"] is None
    r1 = resource.getrusage(resource.RUSAGE_SELF)
    out.append({"wall": time.perf_counter() - t0, "user": r1.ru_utime - r0.ru_utime,
                "sys": r1.ru_stime - r0.ru_stime, "faults": r1.ru_minflt - r0.ru_minflt})
print(json.dumps(out))
'''


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="processes per setting (default 3)")
    ap.add_argument("--flights", type=int, default=6, help="flights per process (default 6)")
    ap.add_argument("--json", default=None, help="also write the numbers to this file")
    a = ap.parse_args()
    res: dict[str, list[dict]] = {k: [] for k in SETTINGS}
    load = [os.getloadavg()[0]]
    for _ in range(a.repeats):
        for name, env in SETTINGS.items():
            p = subprocess.run([sys.executable, "-c", CHILD, str(a.flights), str(ROOT)],
                               env={**os.environ, **env}, capture_output=True, text=True,
                               check=True)
            res[name] += json.loads(p.stdout.strip().splitlines()[-1])
    load.append(os.getloadavg()[0])
    print(f"{a.repeats} x {a.flights} flights per setting (1000-s sample flights), load average "
          f"{load[0]:.1f} -> {load[1]:.1f} on {os.cpu_count()} cores; min / median per flight")
    print(f"{'setting':<22} {'wall s':>13} {'user CPU s':>13} {'system CPU s':>13} "
          f"{'page faults':>11}")
    for name, rs in res.items():
        def col(key: str) -> str:
            v = [r[key] for r in rs]
            return f"{min(v):.3f} / {statistics.median(v):.3f}"
        print(f"{name:<22} {col('wall'):>13} {col('user'):>13} {col('sys'):>13} "
              f"{statistics.median(r['faults'] for r in rs):>11.0f}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"runs": res, "loadavg": load}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
