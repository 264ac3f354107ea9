#!/usr/bin/env python3
"""Benchmark: what one Monte Carlo flight costs a core, for both models' studies, and so what a
10 000-flight study costs (a script, not a test; docs/scaling.md).

Runs the studies' own per-flight function (simulate in memory + analyse: ``run_case`` of
``eval.montecarlo`` and of ``eval.montecarlo3d``) in this process, one BLAS thread (as a Dask
worker), after one warm-up flight per model, and measures the CPU time of this process per flight
(the analysis's second thread included) -- CPU time, not wall time, so that a shared machine
changes it little (its load is printed). The 3-D flights are measured at several short durations
and the cost extrapolated to the study's default duration with a least-squares line
(a + b x duration: the simulator and the filters are linear in the samples); one flight at that
duration checks the line when ``--check`` is given.
"""
from __future__ import annotations

import os

for _k in ("OMP_NUM_THREADS", "MKL_NUM_THREADS", "OPENBLAS_NUM_THREADS"):
    os.environ.setdefault(_k, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import pathlib  # noqa: E402
import statistics  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))


def cpu_per_flight(run, cases, config) -> tuple[list[float], list[float]]:
    """(CPU s, wall s) of each flight."""
    cpu, wall = [], []
    for case in cases:
        c0, w0 = time.process_time(), time.perf_counter()
        run(case, config)
        cpu.append(time.process_time() - c0)
        wall.append(time.perf_counter() - w0)
    return cpu, wall


def single_axis(n: int, duration: float) -> dict:
    from flight_fdi.eval.montecarlo import StudyConfig, plan_study, run_case

    cfg = StudyConfig(nominal=n, per_fault=n, duration_s=duration, seed=1)
    cases = plan_study(cfg)
    run_case(cases[0], cfg)  # warm-up
    cpu, wall = cpu_per_flight(run_case, cases[1:], cfg)
    return {"duration_s": duration, "flights": len(cpu), "cpu_s": statistics.median(cpu),
            "wall_s": statistics.median(wall)}


def ins3d(n: int, durations: list[float], single: bool) -> list[dict]:
    from flight_fdi.eval.montecarlo3d import Study3DConfig, plan_study, run_case

    out = []
    for d in durations:
        cfg = Study3DConfig(nominal=1, per_scenario=max(1, n // 5), duration_s=d, seed=1,
                            single_axis=single)
        cases = plan_study(cfg)
        if not out:
            run_case(cases[0], cfg)  # warm-up (compiled kernels from numba's cache)
        cpu, wall = cpu_per_flight(run_case, cases[:n], cfg)
        out.append({"duration_s": d, "flights": len(cpu), "cpu_s": statistics.median(cpu),
                    "wall_s": statistics.median(wall)})
        print(f"  3-D {d:6.0f} s flight: CPU {out[-1]['cpu_s']:.2f} s (median of {len(cpu)}), "
              f"wall {out[-1]['wall_s']:.2f} s", flush=True)
    return out


def fit(points: list[dict]) -> tuple[float, float]:
    """Least squares cpu = a + b * duration."""
    x = [p["duration_s"] for p in points]
    y = [p["cpu_s"] for p in points]
    mx, my = statistics.fmean(x), statistics.fmean(y)
    b = sum((xi - mx) * (yi - my) for xi, yi in zip(x, y)) / sum((xi - mx) ** 2 for xi in x)
    return my - b * mx, b


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=5, help="flights per point (default 5)")
    ap.add_argument("--durations", default="60,120,240", help="3-D flight durations, s")
    ap.add_argument("--target", type=float, default=900.0,
                    help="duration to extrapolate the 3-D cost to (default 900: the study's)")
    ap.add_argument("--check", action="store_true", help="also run 3-D flights of --target s")
    ap.add_argument("--no-single-axis", action="store_true",
                    help="3-D flights without the single-axis model beside the 3-D one")
    ap.add_argument("--json", default=None)
    a = ap.parse_args()
    load0 = os.getloadavg()[0]
    print(f"load average {load0:.1f} on {os.cpu_count()} cores, "
          f"{len(os.sched_getaffinity(0))} usable; BLAS threads "
          f"{os.environ['OPENBLAS_NUM_THREADS']}")
    sa = single_axis(a.flights, 600.0)
    print(f"  single-axis 600-s flight: CPU {sa['cpu_s']:.3f} s (median of {sa['flights']})")
    pts = ins3d(a.flights, [float(d) for d in a.durations.split(",")], not a.no_single_axis)
    c, b = fit(pts)
    est = c + b * a.target
    print(f"3-D: CPU = {c:.2f} s + {1000 * b:.2f} ms per s of flight -> {a.target:.0f}-s flight "
          f"{est:.2f} s")
    check = ins3d(max(1, a.flights // 2), [a.target], not a.no_single_axis) if a.check else []
    for name, s in (("single-axis, 600-s flights", sa["cpu_s"]),
                    (f"3-D, {a.target:.0f}-s flights (extrapolated)", est)) + tuple(
            (f"3-D, {a.target:.0f}-s flights (measured)", p["cpu_s"]) for p in check):
        print(f"10 000 {name}: {10_000 * s / 3600:.1f} core-hours")
    print(f"load average before / after: {load0:.1f} / {os.getloadavg()[0]:.1f}")
    if a.json:
        pathlib.Path(a.json).write_text(json.dumps({"single_axis": sa, "ins3d": pts,
                                                    "fit": [c, b], "check": check}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
