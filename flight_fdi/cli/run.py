"""``flight-fdi run BAG``: the node pipeline on a bag, in one process.

bag_player -> filter_node -> recorder_node -> smoother_node on one executor: the player replays the
flight as fast as possible without losing messages, the filter runs the gated Kalman filter, the
recorder stores its outputs in a bag (OUT/recording), and the smoother replays that recording
backwards and localizes the fault. Prints the in-flight alarms and the localized-fault result (the
same numbers as ``flight-fdi analyze`` on the same bag: both go through one core).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from flight_fdi.cli.analyze import (add_analysis_options, analysis_config, exit_status,
                                    format_result, input_spec)
from flight_fdi.cli.errors import CliError


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
    add_analysis_options(p)
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from flight_fdi.cli import ins3d
    from flight_fdi.nodes.errors import ParameterError
    from flight_fdi.nodes.pipeline import PipelineError, run_pipeline

    if ins3d.is_ins3d(args):  # the 3-D model (cli/ins3d.py)
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
                           progress=None if args.no_progress else sys.stderr)
    except (PipelineError, ParameterError) as exc:
        raise CliError(str(exc)) from None
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
