"""The exit path of ``flight-fdi analyze`` on the command line (``cli.main.exit_now``): the
process ends once its output is flushed, without the interpreter's teardown, with the same output
and exit status as the in-process call; it runs without the cyclic GC; library calls of
``main(argv)`` keep both."""
from __future__ import annotations

import json
import subprocess
import sys

import pytest

from flight_fdi.cli.main import main

#: a command line whose atexit handler (which the interpreter's teardown runs) reports itself,
#: and which reports whether the cyclic GC runs during the analysis
_COMMAND_LINE = """
import atexit, gc, sys
atexit.register(lambda: sys.stderr.write("teardown ran\\n"))
import flight_fdi.cli.analyze as analyze
from flight_fdi.cli.main import main
run = analyze.run
def reporting_run(args):
    sys.stderr.write(f"gc enabled: {gc.isenabled()}\\n")
    return run(args)
analyze.run = reporting_run
argv = sys.argv[2:]
if sys.argv[1] == "command-line":
    sys.argv = ["flight-fdi", *argv]
    sys.exit(main())
sys.exit(main(argv))
"""


def _run(mode: str, *argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", _COMMAND_LINE, mode, *argv],
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("options, status", [(("--json",), 0), (("--fail-on-fault",), 3)])
def test_command_line_analyze_leaves_at_once_with_the_same_output_and_status(
        capsys, repo_root, options, status):
    bag = str(repo_root / "bags" / "accel_fault_500s")
    argv = ["analyze", bag, "--jobs", "1", *options]
    assert main(argv) == status
    expected = capsys.readouterr().out
    proc = _run("command-line", *argv)
    assert proc.returncode == status, proc.stderr
    assert proc.stdout == expected
    assert proc.stderr.splitlines() == ["gc enabled: False"]  # no "teardown ran"


def test_library_call_keeps_the_gc_and_the_teardown(repo_root):
    proc = _run("library", "analyze", str(repo_root / "bags" / "nominal"), "--json",
                "--jobs", "1")
    assert proc.returncode == 0, proc.stderr
    assert json.loads(proc.stdout)["post_flight"]["verdict"] == "no_fault"
    assert proc.stderr.splitlines() == ["gc enabled: True", "teardown ran"]


def test_command_line_error_keeps_its_message_and_status(tmp_path):
    proc = _run("command-line", "analyze", str(tmp_path / "missing"))
    assert proc.returncode == 1
    lines = proc.stderr.splitlines()
    assert lines[0] == "gc enabled: False" and len(lines) == 3, proc.stderr
    assert lines[1].startswith("flight-fdi analyze: error:") and "does not exist" in lines[1]
    assert lines[2] == "teardown ran"  # (an error returns the normal way)


def test_a_failing_flush_exits_the_normal_way():
    """stdout that cannot be flushed (a closed pipe): ``exit_now`` returns, and the interpreter
    exits as it did before (its own flush error reported, status 120)."""
    code = ("import atexit, sys\n"
            "from flight_fdi.cli.main import exit_now\n"
            "atexit.register(lambda: sys.stderr.write('teardown ran\\n'))\n"
            "class Closed:\n"
            "    def write(self, s): return len(s)\n"
            "    def flush(self): raise BrokenPipeError(32, 'Broken pipe')\n"
            "sys.stdout = Closed()\n"
            "exit_now(0)\n"
            "sys.stderr.write('returned\\n')\n")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                          timeout=60)
    assert proc.stderr.splitlines()[:2] == ["returned", "teardown ran"]
    assert proc.returncode == 120  # what the interpreter does when stdout fails at exit
