"""The exit of ``flight-fdi run`` on the command line (``cli.main.exit_now``, as ``analyze``:
test/test_cli_exit.py): once the pipeline is torn down, the result printed and the report
written, the process ends without the interpreter's teardown (0.3-0.7 s of CPU after a run:
numba's, llvmlite's, rclpy's and matplotlib's finalisation), and it runs without the cyclic GC;
the output, files and status are those of the in-process call."""
from __future__ import annotations

import json
import subprocess
import sys

import harness  # noqa: F401  (private ROS domain, inherited by the subprocess)
import pytest
# the 20-s flight of the shutdown tests (module fixture, reused)
from nodes.test_pipeline_shutdown import _assert_closed_cleanly, small_bag  # noqa: F401

#: a command line whose atexit handler (which the interpreter's teardown runs) reports itself,
#: and which reports whether the cyclic GC runs during the run
_COMMAND_LINE = """
import atexit, gc, sys
atexit.register(lambda: sys.stderr.write("teardown ran\\n"))
import flight_fdi.cli.run as run_cli
from flight_fdi.cli.main import main
real = run_cli.run
def reporting_run(args):
    sys.stderr.write(f"gc enabled: {gc.isenabled()}\\n")
    return real(args)
run_cli.run = reporting_run
sys.argv = ["flight-fdi", *sys.argv[1:]]
sys.exit(main())
"""


@pytest.mark.timeout(300)
def test_command_line_run_leaves_at_once_with_its_output(small_bag, tmp_path):  # noqa: F811
    out = tmp_path / "out"
    proc = subprocess.run([sys.executable, "-c", _COMMAND_LINE, "run", str(small_bag), "--out",
                           str(out), "--json", "--no-progress"],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == ["gc enabled: False"]   # no "teardown ran"
    res = json.loads((out / "result.json").read_text())
    assert json.loads(proc.stdout) == res and proc.stdout.count("\n") == 1
    assert (out / "report" / "index.html").is_file()
    assert _assert_closed_cleanly(out / "recording") > 0


@pytest.mark.timeout(300)
def test_command_line_run_error_exits_the_normal_way(tmp_path):
    proc = subprocess.run([sys.executable, "-c", _COMMAND_LINE, "run", str(tmp_path / "none"),
                           "--out", str(tmp_path / "out")],
                          capture_output=True, text=True, timeout=240)
    assert proc.returncode == 1
    assert proc.stderr.splitlines() == [
        "gc enabled: False", f"flight-fdi run: error: bag {str(tmp_path / 'none')!r} does not "
        "exist", "teardown ran"]
