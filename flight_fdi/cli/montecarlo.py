"""``flight-fdi montecarlo``: a seeded Monte Carlo study of the in-flight gate and both post-flight
isolation methods (the seed method: chi-square + UDU^T + Fisher; GLR).

Simulates nominal flights and flights with accelerometer and gyro bias steps over a grid of
magnitudes (random sign, random onset) in memory, analyses each with the same core as
``flight-fdi analyze``, and reports false-alarm rates (per sample and per flight), missed
detections, the in-flight detection delay, the isolation confusion matrix of both methods,
onset and magnitude errors, type I / II error rates, and per magnitude the detection and
isolation rates with the smallest fault each method isolates in 95 % of the runs.
The flights run on Dask: a local cluster of --jobs worker processes (default one per core;
1: in this process), or an existing cluster with --scheduler tcp://HOST:PORT. The result depends
only on the options (--seed included), not on where or on how many workers it ran. --records
streams every flight's record to a JSON-lines file as it arrives (for very large studies); run
the same command again after an interruption and it resumes: the flights already in the file
are not run again, and the result is that of an uninterrupted run.
"""
from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import sys
from pathlib import Path

from flight_fdi.cli.analyze import add_gate_options
from flight_fdi.cli.batch import add_engine_options, engine_spec
from flight_fdi.cli.errors import CliError
from flight_fdi.cli.montecarlo3d import add_ins3d_options, check_model, run_ins3d


def _levels(text: str) -> tuple[float, ...]:
    try:
        values = tuple(float(v) for v in text.split(",") if v.strip())
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected comma-separated numbers, got {text!r}") from None
    if not values:
        raise argparse.ArgumentTypeError("expected at least one number")
    return values


def _window(text: str) -> tuple[float, float]:
    values = _levels(text)
    if len(values) != 2:
        raise argparse.ArgumentTypeError(f"expected two fractions A,B, got {text!r}")
    return values  # type: ignore[return-value]


def register(sub: argparse._SubParsersAction) -> None:
    from flight_fdi.eval.montecarlo import (DEFAULT_ACCEL_LEVELS_MG,
                                            DEFAULT_GYRO_LEVELS_DEG_H)

    p = sub.add_parser("montecarlo", help="Monte Carlo study of detection and isolation "
                       "(false alarms, delays, confusion matrices, type I/II errors)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--nominal", type=int, default=200, help="nominal flights (default 200)")
    p.add_argument("--per-fault", type=int, default=200,
                   help="flights per fault kind, accelerometer and gyro (default 200)")
    p.add_argument("--accel-levels", type=_levels, default=DEFAULT_ACCEL_LEVELS_MG,
                   metavar="MG,...", help="accelerometer step magnitudes in mg (default "
                   + ",".join(f"{v:g}" for v in DEFAULT_ACCEL_LEVELS_MG) + ")")
    p.add_argument("--gyro-levels", type=_levels, default=DEFAULT_GYRO_LEVELS_DEG_H,
                   metavar="DEG_H,...", help="gyro step magnitudes in deg/h (default "
                   + ",".join(f"{v:g}" for v in DEFAULT_GYRO_LEVELS_DEG_H) + ")")
    p.add_argument("--duration", type=float, default=600.0, metavar="S",
                   help="flight duration in seconds (default 600)")
    p.add_argument("--onset", type=_window, default=(0.1, 0.8), metavar="A,B",
                   help="fault onset uniform in [A, B] x duration (default 0.1,0.8)")
    p.add_argument("--channel", choices=("x", "y"), default="x", help="axis (default x)")
    p.add_argument("--seed", type=int, default=0, help="seed of the study (default 0)")
    add_engine_options(p, "--jobs", "--workers")
    add_gate_options(p)
    p.add_argument("--glr-p-false-alarm", type=float, default=1e-3,
                   help="GLR per-flight false-alarm probability (default 1e-3)")
    p.add_argument("--out", default=None, metavar="FILE",
                   help="also write the full result (settings, metrics, every flight) as JSON")
    p.add_argument("--records", default=None, metavar="FILE.jsonl",
                   help="stream every flight's record to this file as it arrives (JSON lines, "
                        "completion order); when FILE already holds records of the same study, "
                        "resume: only the flights not in it run")
    p.add_argument("--restart", action="store_true",
                   help="with --records: start FILE anew instead of resuming from it")
    p.add_argument("--json", action="store_true",
                   help="print the settings and metrics as one JSON object instead of tables")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_ins3d_options(p)
    p.set_defaults(func=run, gate_action="flag")


def study_config(args: argparse.Namespace):
    """StudyConfig from the options (validated by the evaluation package)."""
    from flight_fdi.cli.analyze import analysis_config
    from flight_fdi.eval.montecarlo import StudyConfig

    analysis = dataclasses.replace(analysis_config(args),
                                   glr_p_false_alarm=args.glr_p_false_alarm)
    return StudyConfig(nominal=args.nominal, per_fault=args.per_fault,
                       accel_levels_mg=tuple(args.accel_levels),
                       gyro_levels_deg_h=tuple(args.gyro_levels), duration_s=args.duration,
                       onset_window=tuple(args.onset), seed=args.seed, channel=args.channel,
                       analysis=analysis)


def writable(path: str | None, option: str) -> Path | None:
    out = Path(path) if path else None
    if out is not None and not out.parent.is_dir():
        raise CliError(f"{option}: cannot write {out}: directory '{out.parent}' does not exist")
    return out


def run(args: argparse.Namespace) -> int:
    from flight_fdi.campaign.engine import default_workers
    from flight_fdi.eval.montecarlo import format_metrics, run_study

    if check_model(args) == "ins3d":
        return run_ins3d(args)
    config = study_config(args)
    spec = engine_spec(args)
    out = writable(args.out, "--out")
    with open_records(args, config.describe()) as records:
        result = run_study(config, jobs=spec.workers or default_workers(),
                           progress=not args.no_progress,
                           on_record=records.write if records else None,
                           scheduler=spec.scheduler, done=records.done if records else None)
    emit_result(result, out, args, format_metrics(result.metrics),
                f"{len(result.records)} flights of {config.duration_s:g} s")
    return 0


def emit_result(result, out: Path | None, args: argparse.Namespace, table: str,
                what: str) -> None:
    """A study's output (both models): the full result to ``--out``; on stdout ``--json``'s
    document, or the metrics ``table`` and a summary line: ``what`` ran (e.g. "200 flights of
    600 s"), how long and on which engine, what was resumed and where the files are."""
    if out is not None:
        out.write_text(json.dumps(result.to_dict(with_records=True), indent=1) + "\n")
    if args.json:
        json.dump(result.to_dict(with_records=False), sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
        return
    print(table)
    where = f" on {result.engine}" if result.engine else " (no flight left to run)"
    print(f"\n{what} in {result.elapsed_s:.1f} s{where}"
          + (f" ({result.resumed} resumed from {args.records})" if result.resumed else "")
          + (f"; full result in {out}" if out else "")
          + (f"; records in {args.records}" if args.records else ""))


def open_records(args: argparse.Namespace, study: dict):
    """The ``--records`` file of a study (a context manager; ``None`` inside without
    ``--records``): resumes from it unless ``--restart``. Any study's CLI can use it."""
    from flight_fdi.eval.records import RecordsFile

    path = writable(args.records, "--records")
    if path is None:
        return contextlib.nullcontext(None)
    return RecordsFile(path, study, restart=args.restart)
