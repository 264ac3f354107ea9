"""A malformed command line of any ``flight-fdi`` subcommand is one line on stderr and exit 2
(``cli.errors.OneLineParser``; before: argparse's whole usage text for every subcommand but
``analyze``, ``run`` and ``report``), while ``--help`` still prints the full help and exits 0.

Every command (each subcommand, and ``attitude``'s actions) is found by walking the parser, and
given a minimal command line that parses (each positional and required option "x"): then an
unknown option, a value of the wrong type and a missing argument each get one line naming the
command. In-process (``main``), one parser build per command."""
from __future__ import annotations

import argparse

import pytest

from flight_fdi.cli.errors import EXIT_USAGE, OneLineParser
from flight_fdi.cli.main import SUBCOMMANDS, build_parser, main


def _commands(parser: argparse.ArgumentParser, path: tuple[str, ...] = ()):
    """(path, parser, minimal argv) of every command under ``parser`` (leaves of the tree)."""
    sub = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if sub:
        for name, child in sub[0].choices.items():
            yield from _commands(child, (*path, name))
        return
    argv: list[str] = []
    for a in parser._actions:
        if not a.option_strings:
            argv.append("x")
        elif a.required:
            argv += [a.option_strings[0], "x"]
    yield path, parser, argv


def _all_commands():
    out = []
    for name in SUBCOMMANDS:
        out += list(_commands(build_parser(only=name)))
    return out


COMMANDS = _all_commands()
IDS = [" ".join(path) for path, _, _ in COMMANDS]


def _one_line(capsys, prog: str) -> str:
    captured = capsys.readouterr()
    lines = captured.err.splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"{prog}: error: "), captured.err
    assert captured.out == "" and "usage:" not in captured.err
    return lines[0]


def _exits(argv: list[str]) -> int:
    with pytest.raises(SystemExit) as exc:
        main(argv)
    return exc.value.code


def test_every_command_is_walked_and_every_parser_is_one_line():
    assert {path[0] for path, _, _ in COMMANDS} == set(SUBCOMMANDS)
    assert {"attitude simulate", "attitude analyze", "attitude study"} <= set(IDS)
    assert all(isinstance(p, OneLineParser) for _, p, _ in COMMANDS)


@pytest.mark.parametrize("path, parser, argv", COMMANDS, ids=IDS)
def test_an_unknown_option_is_one_line(path, parser, argv, capsys):
    assert _exits([*path, *argv, "--no-such-option", "7"]) == EXIT_USAGE
    assert _one_line(capsys, parser.prog).endswith(
        ": error: unrecognized arguments: --no-such-option 7")


@pytest.mark.parametrize("path, parser, argv", COMMANDS, ids=IDS)
def test_a_value_of_the_wrong_type_is_one_line(path, parser, argv, capsys):
    typed = [a for a in parser._actions if a.option_strings and a.type in (int, float)
             and a.nargs is None]
    if not typed:
        pytest.skip("no option with a number type")
    flag = typed[0].option_strings[-1]
    assert _exits([*path, *argv, flag, "lots"]) == EXIT_USAGE
    line = _one_line(capsys, parser.prog)
    assert f"argument {'/'.join(typed[0].option_strings)}: invalid" in line and "'lots'" in line


@pytest.mark.parametrize("path, parser, argv", COMMANDS, ids=IDS)
def test_a_missing_argument_is_one_line(path, parser, argv, capsys):
    if not argv:
        pytest.skip("nothing required")
    assert _exits(list(path)) == EXIT_USAGE
    assert "the following arguments are required: " in _one_line(capsys, parser.prog)


@pytest.mark.parametrize("path, parser, argv", COMMANDS, ids=IDS)
def test_help_still_prints_the_full_help(path, parser, argv, capsys):
    assert _exits([*path, "--help"]) == 0
    captured = capsys.readouterr()
    assert captured.err == ""
    assert captured.out.startswith(f"usage: {parser.prog}")
    assert "-h, --help" in captured.out and captured.out.count("\n") > 3


@pytest.mark.parametrize("argv, needle", [
    ([], "the following arguments are required: COMMAND"),
    (["no-such-command"], "argument COMMAND: invalid choice: 'no-such-command'"),
    (["--no-such-option", "info"], "unrecognized arguments: --no-such-option"),
    (["attitude"], "the following arguments are required: ACTION"),
])
def test_the_top_level_and_the_action_errors_are_one_line(argv, needle, capsys):
    assert _exits(argv) == EXIT_USAGE
    prog = "flight-fdi attitude" if argv == ["attitude"] else "flight-fdi"
    assert needle in _one_line(capsys, prog)


def test_the_full_help_and_the_version_still_exit_0(capsys):
    assert _exits(["--help"]) == 0
    assert capsys.readouterr().out.startswith("usage: flight-fdi")
    assert _exits(["--version"]) == 0
    assert capsys.readouterr().out.startswith("flight-fdi ")
