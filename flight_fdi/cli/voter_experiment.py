"""``flight-fdi voter-experiment``: the seed-002 voter experiment, reproduced.

A square-wave bias fault on one IMU's quantity (default IMU3, gyro z) from ``--onset`` (20 s),
for every amplitude (5, 10, 20, 50, 100 deg/h) and frequency (1, 5, 20 Hz), ``--runs`` (100)
seeded runs each, voted with threshold tables calibrated at every ``--alphas`` (0.05, 0.002) on
``--calibration-flights`` (1000) independent nominal flights. Reported per alpha and cell:

* false alarms: runs with a fault declared (epsilon sum <= 1) before the onset, and the fraction
  of decisions before the onset that declared one;
* missed detections: runs with no fault declared from the onset to the end;
* earliest and mean detection time (from the onset), over the detected runs;
* correct isolation: detected runs whose first declaration names the faulty IMU.

A nominal cell (no fault) gives the false-alarm rate over whole flights. The voter decides at
every sample; the runs of a cell are simulated and voted together (numpy, vectorised over runs),
and every cell uses the same runs' noise (common random numbers), so cells differ only by the
fault.
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time
from typing import Any

import numpy as np

from flight_fdi.cli.voter_calibrate import (_check_int, add_calibration_options, add_imu_options,
                                            calibrate_from_means, imu_config, simulate_means)


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("voter-experiment", help="reproduce the seed-002 square-wave fault "
                       "experiment (false alarms, missed detections, detection time)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--runs", type=int, default=100, help="runs per cell (default 100)")
    p.add_argument("--calibration-flights", type=int, default=1000, metavar="N",
                   help="nominal flights of the threshold calibration (default 1000)")
    p.add_argument("--amplitudes", default="5,10,20,50,100", metavar="LIST",
                   help="fault amplitudes, deg/h for a gyro, ug for an accelerometer "
                        "(default 5,10,20,50,100)")
    p.add_argument("--frequencies", default="1,5,20", metavar="LIST",
                   help="square-wave frequencies in Hz (default 1,5,20)")
    p.add_argument("--alphas", default="0.05,0.002", metavar="LIST",
                   help="confidence levels of the thresholds (default 0.05,0.002)")
    p.add_argument("--onset", type=float, default=20.0, metavar="S",
                   help="fault start in seconds (default 20)")
    p.add_argument("--imu", type=int, choices=(1, 2, 3), default=3,
                   help="the faulty IMU (default 3)")
    p.add_argument("--quantity", default="gyro_z", help="the faulty quantity (default gyro_z)")
    p.add_argument("--shape", choices=("square", "square_onoff"), default="square_onoff",
                   help="square: bias +-A (flight_fdi.sim.faults); square_onoff: bias switching "
                        "between 0 and A (default; see docs/seed002_experiment.md)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    add_imu_options(p)
    add_calibration_options(p)
    p.set_defaults(func=run)


def _floats(text: str, name: str) -> list[float]:
    from flight_fdi.cli.errors import CliError

    try:
        vals = [float(v) for v in text.split(",") if v.strip()]
    except ValueError:
        raise CliError(f"--{name}: {text!r} is not a comma-separated list of numbers") from None
    if not vals or not all(math.isfinite(v) and v > 0 for v in vals):
        raise CliError(f"--{name}: give positive numbers, got {text!r}")
    return vals


def cell_metrics(status: np.ndarray, faulty: np.ndarray, t: np.ndarray, onset: float,
                 imu: int) -> dict[str, Any]:
    """Metrics of one cell from the decisions (runs, T) of the faulty quantity."""
    from flight_fdi.core.voting import SINGLE_FAULT

    fault = status >= SINGLE_FAULT
    before = t < onset
    R = status.shape[0]
    out: dict[str, Any] = {"runs": int(R)}
    if before.any():
        out["false_alarm_runs"] = float(fault[:, before].any(axis=1).mean())
        out["false_alarm_decisions"] = float(fault[:, before].mean())
    after = ~before
    if after.any():
        fa = fault[:, after]
        detected = fa.any(axis=1)
        first = np.argmax(fa, axis=1)
        delay = t[after][first] - onset
        iso = faulty[:, after][np.arange(R), first]
        out["missed"] = float(1.0 - detected.mean())
        out["detected_runs"] = int(detected.sum())
        if detected.any():
            out["earliest_s"] = float(delay[detected].min())
            out["mean_s"] = float(delay[detected].mean())
            out["correct_isolation"] = float((iso[detected] == imu).mean())
        else:
            out["earliest_s"] = out["mean_s"] = out["correct_isolation"] = None
    return out


def run_experiment(config, args: argparse.Namespace, amplitudes: list[float],
                   frequencies: list[float], alphas: list[float], progress: Any = None
                   ) -> dict[str, Any]:
    """The whole experiment (calibration + cells); returns plain data."""
    from flight_fdi.core.voting import QUANTITIES, vote_array
    from flight_fdi.sim.faults import DEG_PER_HOUR, G0
    from flight_fdi.sim.imu import ImuBatch, ImuFault, pair_window_means, simulate_quantity

    q = args.quantity
    j = QUANTITIES.index(q)
    unit, unit_name = (DEG_PER_HOUR, "deg/h") if q.startswith("gyro") else (1e-6 * G0, "ug")
    t_cal, means = simulate_means(config, args.calibration_flights, args, (q,))
    tables = {a: calibrate_from_means(t_cal, means, args, a, config, (q,)).table for a in alphas}
    del means
    batch = ImuBatch(config, args.runs, first_run=args.calibration_flights)
    draws = batch.continuous(j)
    t = batch.t
    bounds = {a: tables[a].bounds_at(t) for a in alphas}  # (T, 1, 3) each

    def decide(faults) -> dict[float, tuple[np.ndarray, np.ndarray]]:
        counts = simulate_quantity(batch, q, faults, draws)
        wm = pair_window_means(counts, batch, j, args.window)        # (R, T, 3)
        out = {}
        for a in alphas:
            lo, up = bounds[a]
            eps = (wm >= lo[None, :, 0, :]) & (wm <= up[None, :, 0, :])
            status, faulty, _ = vote_array(eps)
            out[a] = (status, faulty)
        return out

    cells = []
    nominal = decide([])
    for a in alphas:
        m = cell_metrics(nominal[a][0], nominal[a][1], t, config.duration_s + 1.0, args.imu)
        cells.append({"alpha": a, "amplitude": 0.0, "frequency_hz": None,
                      "false_alarm_runs": m["false_alarm_runs"],
                      "false_alarm_decisions": m["false_alarm_decisions"], "runs": m["runs"]})
    if progress:
        progress(1)
    for amp in amplitudes:
        for f in frequencies:
            fault = ImuFault(args.imu, q, args.shape, args.onset, None, amp * unit, f)
            fault.check_against(config.duration_s, config.rate_hz)
            res = decide([fault])
            for a in alphas:
                m = cell_metrics(res[a][0], res[a][1], t, args.onset, args.imu)
                cells.append({"alpha": a, "amplitude": amp, "frequency_hz": f, **m})
            if progress:
                progress(1)
    first_window_s = args.window / config.rate_hz
    return {
        "experiment": "seed-002 square-wave bias fault",
        "quantity": q, "imu": args.imu, "shape": args.shape, "onset_s": args.onset,
        "amplitude_unit": unit_name, "runs": args.runs,
        "calibration_flights": args.calibration_flights, "window": args.window,
        "rate_hz": config.rate_hz, "duration_s": config.duration_s, "seed": config.seed,
        "errors": tables[alphas[0]].calibration.get("errors"),
        "thresholds": {str(a): {
            "upper_after_first_window": float(tables[a].upper_grid[
                tables[a].grid >= first_window_s][:, 0, :].max())
            if (tables[a].grid >= first_window_s).any() else None,
            "segments": {p: int(len(tables[a].entries[q][p][0])) for p in ("x1", "x2", "x3")},
            "normal_fraction": {p: tables[a].stats[q][p]["normal_fraction"]
                                for p in ("x1", "x2", "x3")}} for a in alphas},
        "threshold_unit": "rad/s" if q.startswith("gyro") else "m/s^2",
        "cells": cells,
    }


def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.0f}%"


def _sec(x: float | None) -> str:
    return "-" if x is None else f"{x:.2f}"


def markdown_table(result: dict[str, Any]) -> str:
    """The cells as a markdown table (the form used in docs/seed002_experiment.md)."""
    unit = result["amplitude_unit"]
    lines = [f"| alpha | amplitude ({unit}) | freq (Hz) | false alarms (runs) | "
             "false alarms (decisions) | missed | earliest (s) | mean (s) | isolated IMU"
             f"{result['imu']} |",
             "|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for c in result["cells"]:
        if c["frequency_hz"] is None:
            lines.append(f"| {c['alpha']:g} | nominal | - | {_pct(c['false_alarm_runs'])} | "
                         f"{100 * c['false_alarm_decisions']:.3f}% | - | - | - | - |")
            continue
        lines.append(
            f"| {c['alpha']:g} | {c['amplitude']:g} | {c['frequency_hz']:g} | "
            f"{_pct(c.get('false_alarm_runs'))} | "
            f"{100 * c.get('false_alarm_decisions', 0.0):.3f}% | {_pct(c.get('missed'))} | "
            f"{_sec(c.get('earliest_s'))} | {_sec(c.get('mean_s'))} | "
            f"{_pct(c.get('correct_isolation'))} |")
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from tqdm import tqdm

    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.voting import QUANTITIES

    for name in ("runs", "calibration_flights", "window", "segments", "eval_every", "batch"):
        _check_int(getattr(args, name), "--" + name.replace("_", "-"))
    if args.calibration_flights < 10:
        raise CliError("--calibration-flights must be >= 10")
    if args.quantity not in QUANTITIES:
        raise CliError(f"--quantity must be one of {', '.join(QUANTITIES)}, got "
                       f"{args.quantity!r}")
    amplitudes = _floats(args.amplitudes, "amplitudes")
    frequencies = _floats(args.frequencies, "frequencies")
    alphas = _floats(args.alphas, "alphas")
    if any(a >= 1 for a in alphas):
        raise CliError(f"--alphas must be in (0, 1), got {args.alphas!r}")
    if not (math.isfinite(args.onset) and 0 < args.onset < args.duration):
        raise CliError(f"--onset must be inside the flight (0, {args.duration:g}) s, got "
                       f"{args.onset!r}")
    for name in ("min_segment", "smooth"):
        v = getattr(args, name)
        if not math.isfinite(v) or v < 0:
            raise CliError(f"--{name.replace('_', '-')} must be >= 0, got {v!r}")
    config = imu_config(args)
    start = time.perf_counter()
    with tqdm(total=1 + len(amplitudes) * len(frequencies), desc="fault cells", unit="cell",
              disable=args.no_progress, file=sys.stderr, leave=False) as bar:
        result = run_experiment(config, args, amplitudes, frequencies, alphas, bar.update)
    result["elapsed_s"] = round(time.perf_counter() - start, 2)
    if args.json:
        print(json.dumps(result, indent=1))
        return 0
    print(f"seed-002 experiment: {result['shape']} bias fault on IMU{args.imu} {args.quantity} "
          f"from {args.onset:g} s; {args.runs} runs per cell; thresholds from "
          f"{args.calibration_flights} nominal flights; window {args.window} at "
          f"{config.rate_hz:g} Hz; seed {config.seed}; {result['elapsed_s']:.1f} s")
    print(markdown_table(result))
    return 0
