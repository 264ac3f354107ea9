"""The top-level ``flight-fdi`` parser: each subcommand is built on its own (only its module is
imported, so ``analyze`` does not pay for SciPy's statistics), and the whole list for help."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from flight_fdi.cli.main import SUBCOMMANDS, build_parser, main


@pytest.mark.parametrize("name", sorted(SUBCOMMANDS))
def test_each_subcommand_registers_under_its_own_name(name):
    parser = build_parser(only=name)
    sub = next(a for a in parser._actions if a.dest == "command")
    assert list(sub.choices) == [name]


def test_full_parser_lists_every_subcommand(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    for name in SUBCOMMANDS:
        assert name in out


def test_unknown_subcommand_is_an_argparse_error(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["no-such-command"])
    assert exc.value.code == 2
    assert "invalid choice" in capsys.readouterr().err


def test_analyze_does_not_import_the_voter_statistics():
    code = ("import sys\nfrom flight_fdi.cli.main import build_parser\n"
            "build_parser('analyze').parse_args(['analyze', 'x'])\n"
            "print('scipy.stats' in sys.modules, 'flight_fdi.core.voting' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.split() == ["False", "False"]


def _blas_threads_seen_by_the_command(env: dict) -> str:
    code = ("import flight_fdi.cli.main, os, numpy; "
            "print(os.environ.get('OPENBLAS_NUM_THREADS'))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                         check=True, timeout=120)
    return out.stdout.strip()


def test_the_command_runs_openblas_on_one_thread_unless_the_user_says_otherwise():
    env = {k: v for k, v in os.environ.items() if k != "OPENBLAS_NUM_THREADS"}
    assert _blas_threads_seen_by_the_command(env) == "1"
    assert _blas_threads_seen_by_the_command(env | {"OPENBLAS_NUM_THREADS": "2"}) == "2"
