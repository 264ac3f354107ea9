"""``flight-fdi run BAG``: the node pipeline on a bag, in one process.

bag_player -> filter_node -> recorder_node -> smoother_node on one executor: the player replays the
flight as fast as possible without losing messages, the filter runs the gated Kalman filter, the
recorder stores its outputs in a bag (OUT/recording), and the smoother replays that recording
backwards and localizes the fault. Prints the in-flight alarms and the localized-fault result (the
same numbers as ``flight-fdi analyze`` on the same bag: both go through one core).

Bounds (docs/hardening.md, section 5): a run whose work is not done after --timeout seconds,
or a stage with work waiting that makes no progress for --stall-timeout seconds, ends with one
line (naming the stage; exit 1). The middleware teardown
after the run's work is bounded by --teardown-timeout: past it a WARN line and the threads'
stacks go to stderr, the result is still printed and the report written, and the process exits
with the status it would have had (0, or 3 with --fail-on-fault) without the teardown. The same
for ``--model ins3d`` (:func:`run3d`). --out must be a folder or one that can be made: else one
line before any node. On the command line the process ends as soon as the result is printed
and the report written (``cli.main.exit_now``: no interpreter teardown; the pipeline's own
teardown -- nodes, executor, context -- is done by then).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from flight_fdi.cli.analyze import (add_analysis_options, analysis_config, exit_status,
                                    format_result, input_spec)
from flight_fdi.cli.errors import CliError

#: the run's bounds a user can set: option -> (keyword of run_pipeline / run_pipeline3d, least,
#: most); their defaults are the pipeline's (TIMEOUT_S, STALL_TIMEOUT_S,
#: runner.TEARDOWN_TIMEOUT_S: 600 s, 60 s, 10 s)
BOUNDS = {"--timeout": ("timeout_s", 1.0, 86400.0),
          "--stall-timeout": ("stall_timeout_s", 1.0, 3600.0),
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
    p.add_argument("--timeout", metavar="S", default=None,
                   help="end the run with an error when its work (replay, recording, analysis) "
                   "is not done after S seconds (1 to 86400; default 600): raise it for a long "
                   "flight on a slow or loaded machine")
    p.add_argument("--stall-timeout", metavar="S", default=None,
                   help="end the run with an error naming the stage when a stage with work "
                   "waiting makes no progress for S seconds (1 to 3600; default 60)")
    p.add_argument("--teardown-timeout", metavar="S", default=None,
                   help="bound on the middleware teardown after the run's work (1 to 600 s; "
                   "default 10): past it the result is still printed and the report written, "
                   "and the process exits without the teardown (docs/hardening.md section 5)")
    add_analysis_options(p)
    # on the command line: no cyclic GC, and the process ends once the output is flushed
    # (cli.main.exit_now), without the interpreter's teardown -- 0.3-0.7 s of CPU after a run
    # (numba, llvmlite, rclpy, matplotlib), for a command whose work is all done and written
    p.set_defaults(func=run, short_lived=True)


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
    from flight_fdi.nodes.pipeline import PipelineError, run_pipeline_detailed

    bounds = pipeline_bounds(args)
    if ins3d.is_ins3d(args):  # the 3-D model
        return run3d(args, bounds)
    bag, out = bag_and_folder(args)
    config = analysis_config(args)
    spec = input_spec(args)
    try:
        run = run_pipeline_detailed(
            bag, out, config=config, model=args.model, storage=args.storage, overwrite=True,
            spec=spec, progress=None if args.no_progress else sys.stderr,
            on_teardown_timeout=after_blocked_teardown(out, args, complete),
            with_truth=not args.no_report, **bounds)
    except (PipelineError, ParameterError) as exc:
        raise CliError(str(exc)) from None
    return complete(run, out, args)


def bag_and_folder(args: argparse.Namespace) -> tuple[Path, Path]:
    """The run's input bag (it must exist) and its output folder (``--out``, default
    out/<bag name>; checked by ``report_folder``: one line when it names a file)."""
    from flight_fdi.cli.report import report_folder

    bag = Path(args.bag)
    if not bag.exists():
        raise CliError(f"bag {str(bag)!r} does not exist")
    return bag, report_folder(args.out or Path("out") / bag.resolve().name, "output folder")


def run3d(args: argparse.Namespace, bounds: dict[str, float]) -> int:
    """``flight-fdi run BAG --model ins3d``: the node pipeline of the 3-D model
    (nodes/ins3d_pipeline.py), with the options of ``analyze --model ins3d`` (cli/ins3d.py)
    and the run's ``bounds`` (:func:`pipeline_bounds`)."""
    from flight_fdi.bagio.ins3d_input import description_options, sim_description, topic_names
    from flight_fdi.cli.ins3d import (error_model_block, recorded_model, settings, source,
                                      topics)
    from flight_fdi.nodes.errors import ParameterError
    from flight_fdi.nodes.ins3d_pipeline import run_pipeline3d
    from flight_fdi.nodes.pipeline import PipelineError

    bag, out = bag_and_folder(args)
    s = settings(args)
    block = error_model_block(args)
    names = topic_names(topics(args))  # checked with the bag's messages by run_pipeline3d
    # the model options as ``analyze`` takes them, as filter_node parameters (ins3d_vertical,
    # ...; a baro loop is the node's own, the simulator's default loop)
    options = description_options(sim_description(bag), block, f"bag '{bag}'")
    options.pop("loop", None)     # (with a height topic filter_node adds the height's Markov
    #                               noise to the velocity reference's: HeightSpec.ref_markov)
    try:
        run = run_pipeline3d(bag, out, topics=names, grade=s["grade"], rows=s["rows"],
                             gate=s["gate"], storage=args.storage, overwrite=True,
                             source=source(names, s, recorded_model(options, block)),
                             options=options,
                             progress=None if args.no_progress else sys.stderr,
                             on_teardown_timeout=after_blocked_teardown(out, args, complete3d),
                             with_truth=not args.no_report, height=s["height"], **bounds)
    except (PipelineError, ParameterError) as exc:
        raise CliError(str(exc)) from None
    return complete3d(run, out, args)


def after_blocked_teardown(out: Path, args: argparse.Namespace, then):
    """The pipeline's ``on_teardown_timeout``: ``then(run, out, args)`` (:func:`complete`
    or :func:`complete3d`; ``run`` the PipelineRun), in the watchdog's thread, with the
    one-line error of ``main`` for a user error (status 1)."""
    def finish(run: Any) -> int:
        from flight_fdi.cli.main import EXIT_ERROR, _user_errors

        try:
            return then(run, out, args)
        except _user_errors() as exc:
            print(f"flight-fdi run: error: {exc}", file=sys.stderr, flush=True)
            return EXIT_ERROR

    return finish


def complete3d(run: Any, out: Path, args: argparse.Namespace) -> int:
    """:func:`complete` of the 3-D model: the report (unless --no-report,
    ``cli.ins3d_report.report_of_run``) of the smoother's analysis of the recording and the
    truth read with the inputs (``run``, the PipelineRun: nothing read or analysed again), the
    result printed; the exit status."""
    from flight_fdi.cli.ins3d import emit
    from flight_fdi.cli.ins3d_report import report_of_run

    extra = ["", f"recording and result.json in {out}/"]
    if not args.no_report:
        index = report_of_run(out, out / "report", run.result, (*run.smoother.ins3d, run.read))
        extra.append(f"report (figures and verdict): {index}")
    return emit(run.result, args, extra)


def complete(run: Any, out: Path, args: argparse.Namespace) -> int:
    """What ``run`` does with the pipeline's run (PipelineRun): the report (unless
    --no-report) of the smoother's analysis and the input read before the replay (nothing
    read or analysed again), the result printed; the exit status."""
    res = run.result
    index = None
    if not args.no_report:
        from flight_fdi.cli.report import of_run
        from flight_fdi.report import write_report

        analysis, truth, model, notes = of_run(run.smoother.analysis, run.smoother.recording,
                                               run.read, res)
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
