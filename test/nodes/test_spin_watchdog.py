"""A node callback that never returns cannot hold ``flight-fdi run`` past its bound
(``runner.SpinWatchdog`` in ``pipeline_graph.Graph``): the spin loop checks the deadline only
between callbacks, so before the watchdog such a run hung until killed (and a first Ctrl-C only
set a flag nobody read). Run in a subprocess: the watchdog ends the process."""
from __future__ import annotations

import subprocess
import sys
import time

import harness  # noqa: F401  (private ROS domain, inherited by the subprocess)

SCRIPT = r"""
import sys, threading
from rclpy.node import Node
from flight_fdi.nodes import pipeline_graph
from flight_fdi.nodes.pipeline_graph import Graph, PipelineError

pipeline_graph.SPIN_GRACE_S = 1.0
MODE = sys.argv[1]


class Blocker(Node):
    def __init__(self, **kw):
        super().__init__("blocker", **kw)
        self.create_timer(0.1, self._cb)

    def _cb(self):
        print("callback entered", flush=True)
        if MODE == "forever":
            threading.Event().wait()              # never returns


try:
    with Graph(timeout_s=2.0, stall_timeout_s=60.0, teardown_timeout=5.0) as g:
        g.build(Blocker, {})
        g.spin_until(lambda: False, "waiting for the blocker")
except PipelineError as exc:
    print(f"PipelineError: {exc}", flush=True)
    sys.exit(1)
"""


def _run(mode: str) -> tuple[subprocess.CompletedProcess, float]:
    t0 = time.monotonic()
    done = subprocess.run([sys.executable, "-c", SCRIPT, mode], capture_output=True, text=True,
                          timeout=120)
    return done, time.monotonic() - t0


def test_a_callback_that_never_returns_ends_the_run_at_its_bound():
    done, took = _run("forever")
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert "callback entered" in done.stdout
    line = next(ln for ln in done.stderr.splitlines() if "[ERROR]" in ln)
    assert "timed out while waiting for the blocker: a node callback has not returned " \
           "within 3 s; exiting with status 1" in line
    assert "_cb" in done.stderr                      # the stacks name the blocked callback
    assert took < 60.0                               # (it hung until killed before)


def test_callbacks_that_return_leave_the_usual_timeout():
    """Callbacks that return: the spin loop's own PipelineError at the deadline, the watchdog
    silent (stopped before the teardown)."""
    done, _ = _run("returns")
    assert done.returncode == 1, (done.stdout, done.stderr)
    assert "PipelineError: pipeline timed out while waiting for the blocker" in done.stdout
    assert "[ERROR]" not in done.stderr
