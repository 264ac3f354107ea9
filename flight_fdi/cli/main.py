"""``flight-fdi``: simulate flights, analyse bags, run the node pipeline.

Every error a user can cause (missing or corrupt bag, bad parameter, bad model file) ends as one
line on stderr and a non-zero exit status, never a traceback.
"""
from __future__ import annotations

import argparse
import importlib
import sys

from flight_fdi import __version__

#: subcommand modules; each has ``register(subparsers)`` that adds a parser with ``func=run``
SUBCOMMANDS = (
    "flight_fdi.cli.info",
    "flight_fdi.cli.simulate",
    "flight_fdi.cli.analyze",
    "flight_fdi.cli.run",
    "flight_fdi.cli.report",
    "flight_fdi.cli.montecarlo",
    "flight_fdi.cli.attitude",
    "flight_fdi.cli.criticality",
    "flight_fdi.cli.imu_simulate",
    "flight_fdi.cli.voter_calibrate",
    "flight_fdi.cli.voter_experiment",
)

EXIT_ERROR = 1
EXIT_INTERRUPTED = 130


def _user_errors() -> tuple[type[BaseException], ...]:
    """Error types whose message is meant for the user (one per subpackage)."""
    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.errors import CoreError

    errors: list[type[BaseException]] = [CliError, CoreError]
    for mod, name in (("flight_fdi.bagio.errors", "BagError"), ("flight_fdi.sim.errors", "SimError")):
        try:
            errors.append(getattr(importlib.import_module(mod), name))
        except (ImportError, AttributeError):
            pass
    return tuple(errors)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="flight-fdi",
        description="INS fault detection in flight and fault isolation after the flight.",
    )
    parser.add_argument("--version", action="version", version=f"flight-fdi {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    sub.required = True
    for name in SUBCOMMANDS:
        importlib.import_module(name).register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        return int(args.func(args) or 0)
    except KeyboardInterrupt:
        print("flight-fdi: interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
    except _user_errors() as exc:
        print(f"flight-fdi {args.command}: error: {exc}", file=sys.stderr)
        return EXIT_ERROR
    except BrokenPipeError:
        return 0


if __name__ == "__main__":
    sys.exit(main())
