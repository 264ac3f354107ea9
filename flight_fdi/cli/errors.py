"""The one error type of the command line layer, and the parser class whose command-line errors
are one line."""
from __future__ import annotations

import argparse
from typing import NoReturn

#: exit status of a malformed command line (argparse's usage status; a bad value that parses is
#: a CliError, exit 1)
EXIT_USAGE = 2


class CliError(RuntimeError):
    """A command cannot do what was asked; the message is shown to the user as one line."""


class OneLineParser(argparse.ArgumentParser):
    """The parser of ``flight-fdi`` and of every subcommand (``cli.main.build_parser``; a
    subparser takes its parent's class): a malformed command line (``--latency=yes``, ``--rows
    4``, an option without its value, an unknown option, a missing argument) is one line on
    stderr, ``flight-fdi CMD: error: <argparse's message>``, and exit 2 (``EXIT_USAGE``) -- the
    usage text left out: ``--help`` has it. Unknown options are refused by the subcommand's own
    parser: argparse would hand them to the top-level parser, whose error names no
    subcommand."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_USAGE, f"{self.prog}: error: {message}\n")

    def parse_known_args(self, args=None, namespace=None):  # type: ignore[override]
        ns, extra = super().parse_known_args(args, namespace)
        if extra:
            self.error(f"unrecognized arguments: {' '.join(extra)}")
        return ns, extra
