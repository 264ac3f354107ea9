"""``flight-fdi``: simulate flights, analyse bags, run the node pipeline.

Every error a user can cause (missing or corrupt bag, bad parameter, bad model file) ends as one
line on stderr and a non-zero exit status, never a traceback.
"""
from __future__ import annotations

import argparse
import gc
import importlib
import os
import sys

from flight_fdi.blas_env import one_blas_thread

one_blas_thread()  # (before numpy loads; a user's own OPENBLAS_NUM_THREADS wins)

from flight_fdi import __version__  # noqa: E402

#: subcommand name -> its module; each module has ``register(subparsers)`` that adds the parser
#: of that name with ``func=run``
SUBCOMMANDS = {
    "info": "flight_fdi.cli.info",
    "simulate": "flight_fdi.cli.simulate",
    "analyze": "flight_fdi.cli.analyze",
    "run": "flight_fdi.cli.run",
    "report": "flight_fdi.cli.report",
    "montecarlo": "flight_fdi.cli.montecarlo",
    "attitude": "flight_fdi.cli.attitude",
    "criticality": "flight_fdi.cli.criticality",
    "imu-simulate": "flight_fdi.cli.imu_simulate",
    "voter-calibrate": "flight_fdi.cli.voter_calibrate",
    "voter-experiment": "flight_fdi.cli.voter_experiment",
    "vote": "flight_fdi.cli.vote",
    "imu-csv": "flight_fdi.cli.imu_csv",
    "batch": "flight_fdi.cli.batch",
    "calibrate": "flight_fdi.cli.calibrate",
}

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


def _user_errors() -> tuple[type[BaseException], ...]:
    """Error types whose message is meant for the user (one per subpackage)."""
    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.errors import CoreError

    errors: list[type[BaseException]] = [CliError, CoreError]
    for mod, name in (("flight_fdi.bagio.errors", "BagError"),
                      ("flight_fdi.sim.errors", "SimError")):
        try:
            errors.append(getattr(importlib.import_module(mod), name))
        except (ImportError, AttributeError):
            pass
    return tuple(errors)


def _command_of(argv: list[str]) -> str | None:
    """The subcommand named by ``argv`` when it is the first argument (the top-level parser has
    only --help and --version), else None."""
    return argv[0] if argv and argv[0] in SUBCOMMANDS else None


def build_parser(only: str | None = None) -> argparse.ArgumentParser:
    """The parser with every subcommand, or with ``only`` that one: importing a subcommand's
    module can be slow (SciPy's statistics for the IMU voter), and ``analyze`` is timed. Every
    parser in it is a ``cli.errors.OneLineParser``: a malformed command line is one line, exit
    2."""
    from flight_fdi.cli.errors import OneLineParser

    parser = OneLineParser(  # (its subcommands' parsers take its class: one-line errors)
        prog="flight-fdi",
        description="INS fault detection in flight and fault isolation after the flight.",
    )
    parser.add_argument("--version", action="version", version=f"flight-fdi {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name, module in SUBCOMMANDS.items():
        if only is None or name == only:
            importlib.import_module(module).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    """Run the command ``argv`` (default: this process's command line) and return its exit
    status. On the command line (``argv`` not given) a short-lived subcommand (``analyze``: its
    parser's ``short_lived``) runs without the cyclic garbage collector and ends the process as
    soon as its output is flushed (:func:`exit_now`)."""
    command_line = argv is None
    if argv is None:
        argv = sys.argv[1:]
    parser = build_parser(_command_of(argv))
    args = parser.parse_args(argv)
    short_lived = command_line and getattr(args, "short_lived", False)
    if short_lived:
        # its start-up (numpy, numba, the compiled kernels) allocates ~180 000 objects, which the
        # collector would scan over and over (~0.1 s CPU) to free no cycle worth it; the peak
        # memory of a 3-hour flight's analysis is the same without it
        gc.disable()
    try:
        code = int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("flight-fdi: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except _user_errors() as exc:
        print(f"flight-fdi {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:
        return 0
    if short_lived:
        exit_now(code)
    return code


def exit_now(code: int) -> None:
    """End the process with status ``code`` once stdout and stderr are flushed, without the
    interpreter's teardown: after an ``analyze`` that is numba's and llvmlite's finalisation and
    the collection of every module, 0.2-0.4 s of wall time (docs/performance.md), for a command
    whose whole output is already written. Only for the command line (never in library code).
    Returns instead, and the process exits the normal way with the same status, when a flush
    fails (e.g. a closed pipe: reported as before) or coverage is measuring the process (it
    saves its data at exit; numba imports coverage without measuring anything: that does not
    count)."""
    if _coverage_measuring() or os.environ.get("COVERAGE_PROCESS_START"):
        return
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        return
    os._exit(code)


def _coverage_measuring() -> bool:
    """Whether coverage is measuring this process (a started ``coverage.Coverage``)."""
    cov = sys.modules.get("coverage")
    current = getattr(getattr(cov, "Coverage", None), "current", None)
    if cov is None:
        return False
    return current is None or current() is not None  # (an old coverage: assume it measures)


if __name__ == "__main__":
    sys.exit(main())
