"""``flight-fdi batch INPUT... --out DIR``: analyse a fleet's flights on Dask.

INPUT: bag folders or files, globs (quoted: 'campaign/**/flight_*'), or folders searched for
bags. Every flight is analysed as ``flight-fdi analyze`` does, with the same options (also
--model ins3d with its options, checked once as analyze checks them). DIR gets one
result JSON per flight (flights/<flight>.json), summary.csv (flight, bag, duration, verdict,
sensor, axis, kind, onset, magnitude, unit, confidence, dropped samples, error) and the fleet page
index.html. A second run analyses only flights whose bag is newer than their result (or all of
them when the analysis options changed); a bag that cannot be analysed is a row with its error.
Exit status 0 (errors are rows), 3 with --fail-on-fault when any flight declared a fault.

The flights run on an embedded local Dask cluster of one worker process per core (nothing to
start) -- by default no more workers than flights, and in this process when the work is too
small to pay for the cluster's start (a few flights) -- or with --scheduler tcp://HOST:PORT on
an existing cluster (``dask scheduler``, ``dask worker``) whose workers see the bags under the
same paths. See docs/scaling.md.
"""
from __future__ import annotations

import argparse
import json
import sys

from flight_fdi.cli.analyze import add_analysis_options
from flight_fdi.cli.errors import CliError


def add_engine_options(p: argparse.ArgumentParser, *flags: str) -> None:
    """Where the tasks run (read by :func:`engine_spec`): ``flags`` name the worker count
    (default ``--workers``), and ``--scheduler``."""
    from flight_fdi.campaign.engine import default_workers

    p.add_argument(*(flags or ("--workers",)), dest="workers", type=int, default=None,
                   metavar="N", help="worker processes of the local Dask cluster (default: one "
                   f"per core, {default_workers()} here; 1: in this process, no cluster)"
                   + _SMALL_BATCH.get(flags[0] if flags else "--workers", ""))
    p.add_argument("--scheduler", default=None, metavar="tcp://HOST:PORT",
                   help="run on this existing Dask cluster (its workers) instead of a local one")


#: what the default of ``batch --workers`` also does (:func:`batch_engine_spec`)
_SMALL_BATCH = {"--workers": "; by default a batch whose work is too small to pay for the "
                "cluster's start runs in this process, and never on more workers than flights "
                "(docs/scaling.md)"}


def engine_spec(args: argparse.Namespace):
    from flight_fdi.campaign.engine import EngineError, EngineSpec

    try:
        return EngineSpec(workers=args.workers, scheduler=args.scheduler)
    except EngineError as exc:
        raise CliError(f"--workers/--scheduler: {exc}") from None


def batch_engine_spec(args: argparse.Namespace, batch):
    """The engine of a batch: ``engine_spec``; without --workers and --scheduler, the local
    cluster's workers by the size of the work (``campaign.engine.auto_workers``: in this process
    when the cluster would not pay, at most one worker per flight)."""
    from flight_fdi.campaign.engine import CLUSTER_COST_S, EngineSpec, auto_workers

    spec = engine_spec(args)
    if args.workers is not None or args.scheduler is not None:
        return spec
    # (summing the bags' sizes stops once the work is surely worth a cluster)
    tasks, work_s = batch.estimated_work(getattr(args, "reports", None),
                                         enough=4 * CLUSTER_COST_S)
    return EngineSpec(workers=auto_workers(tasks, work_s))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("batch", help="analyse many bags (a fleet) on Dask, with a summary "
                       "table and a fleet page", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("inputs", nargs="+", metavar="INPUT",
                   help="bag folders/files, globs or folders searched for bags")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (created)")
    add_analysis_options(p)
    add_engine_options(p)
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--force", action="store_true",
                   help="analyse every flight again, even when its result is up to date")
    p.add_argument("--reports", default=None, metavar="WHICH",
                   help="also make per-flight reports: 'faults', 'all' or flight names A,B,...")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from flight_fdi.campaign.batch import Batch, BatchError
    from flight_fdi.campaign.engine import Engine, EngineError
    from flight_fdi.campaign.reports import make_reports
    from flight_fdi.campaign.worker import warm_for

    engine_spec(args)   # (a bad --workers / --scheduler: its line before the inputs')
    say = (lambda s: None) if args.json else (lambda s: print(s, file=sys.stderr))
    try:
        batch = Batch(args.inputs, args.out, args, force=args.force)
        spec = batch_engine_spec(args, batch)
        with Engine(spec, warm=warm_for(args.model)) as engine:
            if spec.scheduler:
                engine.wait_for_workers(1)
            res = batch.run(engine, progress=not args.no_progress, say=say)
            report_errors = (make_reports(batch, res, engine, args.reports,
                                          progress=not args.no_progress)
                             if args.reports else [])
    except (BatchError, EngineError) as exc:
        raise CliError(str(exc)) from None
    for line in [f"{r['flight']}: {r['error']}" for r in res.rows if r["error"]][:20] \
            + report_errors[:20]:
        print(f"flight-fdi batch: {line}", file=sys.stderr)
    if args.json:
        json.dump({"out": str(batch.out), "analysed": res.analysed, "skipped": res.skipped,
                   "failed": res.failed, "elapsed_s": res.elapsed_s, "engine": res.engine,
                   "flights": res.rows}, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        errors = sum(1 for r in res.rows if r["error"])
        print(f"{len(res.rows)} flights: {res.analysed} analysed, {res.skipped} up to date, "
              f"{errors} with an error, in {res.elapsed_s:.1f} s on {res.engine}\n"
              f"summary {batch.out / 'summary.csv'}, fleet page {batch.out / 'index.html'}")
    return batch_status(res.rows, args)


def batch_status(rows: list[dict], args: argparse.Namespace) -> int:
    """0, or analyze's EXIT_FAULT with --fail-on-fault when any flight declared a fault."""
    from flight_fdi.cli.analyze import EXIT_FAULT, FAULT_VERDICTS

    if getattr(args, "fail_on_fault", False) and \
            any(r["verdict"] in FAULT_VERDICTS for r in rows):
        return EXIT_FAULT
    return 0
