"""``flight-fdi run BAG``: the node pipeline on a bag, in one process.

bag_player -> filter_node -> recorder_node -> smoother_node on one executor: the player replays the
flight as fast as possible without losing messages, the filter runs the gated Kalman filter, the
recorder stores its outputs in a bag (OUT/recording), and the smoother replays that recording
backwards and localizes the fault. Prints the in-flight alarms and the localized-fault result (the
same numbers as ``flight-fdi analyze`` on the same bag: both go through one core).

Bounds (docs/hardening.md, section 5): a stage with work waiting that makes no progress for
--stall-timeout seconds ends the run with one line naming it (exit 1). The middleware teardown
after the run's work is bounded by --teardown-timeout: past it a WARN line and the threads'
stacks go to stderr, the result is still printed and the report written, and the process exits
with the status it would have had (0, or 3 with --fail-on-fault) without the teardown.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from flight_fdi.cli.analyze import (add_analysis_options, analysis_config, exit_status,
                                    format_result, input_spec)
from flight_fdi.cli.errors import CliError

#: the run's bounds a user can set: option -> (keyword of run_pipeline, least, most); their
#: defaults are the pipeline's (STALL_TIMEOUT_S, runner.TEARDOWN_TIMEOUT_S: 60 s, 10 s)
BOUNDS = {"--stall-timeout": ("stall_timeout_s", 1.0, 3600.0),
          "--teardown-timeout": ("teardown_timeout", 1.0, 600.0)}


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("run", help="the ROS node pipeline (player, filter, recorder, smoother) "
                       "on a bag in one process", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="input rosbag2 bag with an INS and a reference velocity (see "
                               "--ins-topic, --input-profile)")
    p.add_argument("--out", default=None,
                   help="output folder (default out/<bag name>): recording, result.json")
    p.add_argument("--storage", default="mcap", choices=("mcap", "sqlite3"),
                   help="storage of the recording (default mcap)")
    p.add_argument("--no-report", action="store_true",
                   help="skip the figures and HTML page (OUT/report/index.html)")
    p.add_argument("--no-progress", action="store_true",
                   help="no 'replay NN %%' lines on stderr")
    p.add_argument("--stall-timeout", metavar="S", default=None,
                   help="end the run with an error naming the stage when a stage with work "
                   "waiting makes no progress for S seconds (1 to 3600; default 60)")
    p.add_argument("--teardown-timeout", metavar="S", default=None,
                   help="bound on the middleware teardown after the run's work (1 to 600 s; "
                   "default 10): past it the result is still printed and the report written, "
                   "and the process exits without the teardown (docs/hardening.md section 5)")
    add_analysis_options(p)
    p.set_defaults(func=run)


def pipeline_bounds(args: argparse.Namespace) -> dict[str, float]:
    """The keywords of ``run_pipeline`` for the bounds given on the command line (BOUNDS;
    the pipeline's defaults for the others); CliError, one line, for a value that is not a
    number of seconds in its range."""
    import math

    out = {}
    for flag, (key, least, most) in BOUNDS.items():
        text = getattr(args, flag[2:].replace("-", "_"), None)
        if text is None:
            continue
        try:
            value = float(text)
        except (TypeError, ValueError):
            value = math.nan
        if not least <= value <= most:  # (NaN too)
            raise CliError(f"{flag}: expected a number of seconds from {least:g} to {most:g}, "
                           f"got {text!r}")
        out[key] = value
    return out


def run(args: argparse.Namespace) -> int:
    from flight_fdi.cli import ins3d
    from flight_fdi.nodes.errors import ParameterError
    from flight_fdi.nodes.pipeline import PipelineError, run_pipeline

    bounds = pipeline_bounds(args)
    if ins3d.is_ins3d(args):  # the 3-D model (cli/ins3d.py)
        if bounds:  # (ins3d.run_run does not pass them to run_pipeline3d yet: not ignored)
            raise CliError("--stall-timeout and --teardown-timeout apply to the single-axis "
                           "models only (not yet to --model ins3d)")
        return ins3d.run_run(args)
    bag = Path(args.bag)
    if not bag.exists():
        raise CliError(f"bag {str(bag)!r} does not exist")
    out = Path(args.out) if args.out else Path("out") / bag.resolve().name
    config = analysis_config(args)
    spec = input_spec(args)
    try:
        res = run_pipeline(bag, out, config=config, model=args.model, storage=args.storage,
                           overwrite=True, spec=spec,
                           progress=None if args.no_progress else sys.stderr,
                           on_teardown_timeout=after_blocked_teardown(out, args), **bounds)
    except (PipelineError, ParameterError) as exc:
        raise CliError(str(exc)) from None
    return complete(res, out, args)


def after_blocked_teardown(out: Path, args: argparse.Namespace):
    """The pipeline's ``on_teardown_timeout``: :func:`complete` of the result, in the
    watchdog's thread, with the one-line error of ``main`` for a user error (status 1)."""
    def finish(res: dict) -> int:
        from flight_fdi.cli.main import EXIT_ERROR, _user_errors

        try:
            return complete(res, out, args)
        except _user_errors() as exc:
            print(f"flight-fdi run: error: {exc}", file=sys.stderr, flush=True)
            return EXIT_ERROR

    return finish


def complete(res: dict, out: Path, args: argparse.Namespace) -> int:
    """What ``run`` does with the pipeline's result: the report (unless --no-report), the
    result printed; the exit status."""
    index = None
    if not args.no_report:
        from flight_fdi.cli.report import analyse_run_folder
        from flight_fdi.report import write_report

        analysis, truth, model, notes = analyse_run_folder(out, args)
        index = write_report(analysis, out / "report", truth=truth, model=model, notes=notes)
    if args.json:
        json.dump(res, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(format_result(res))
        print(f"\nrecording and result.json in {out}/")
        if index is not None:
            print(f"report (figures and verdict): {index}")
    return exit_status(res, args)
