"""nodes/runner.py: the shared ``main()`` of the node executables, in process.

SIGINT / SIGTERM can arrive at any moment after ``rclpy.init``; these tests deliver them (and
KeyboardInterrupt) at each stage -- inside the node's constructor, between construction and the
first spin, while spinning -- and check that the node is destroyed, the default context shut down
and the return code is the node's exit status: never an escaping KeyboardInterrupt (which kills
the process with SIGINT) nor a teardown racing rclpy's signal thread.
"""
from __future__ import annotations

import os
import signal

import harness  # noqa: F401  (private domain, localhost discovery)
import pytest
import rclpy
from rclpy.node import Node
from rclpy.task import Future

from flight_fdi.nodes import runner
from flight_fdi.nodes.errors import ParameterError


class _Probe(Node):
    """A node that records whether it was destroyed; optionally completes ``done`` from a timer."""

    instances: list["_Probe"] = []

    def __init__(self, finish_after: int | None = None, interrupt_in_spin: bool = False) -> None:
        super().__init__("runner_probe")
        self.destroyed = False
        self.ticks = 0
        self.done = Future()
        self._finish_after = finish_after
        self._interrupt = interrupt_in_spin
        self.create_timer(0.001, self._tick)
        _Probe.instances.append(self)

    def _tick(self) -> None:
        self.ticks += 1
        if self._interrupt:
            raise KeyboardInterrupt
        if self._finish_after is not None and self.ticks >= self._finish_after:
            self.done.set_result(self.ticks)

    def destroy_node(self) -> None:
        self.destroyed = True
        super().destroy_node()


@pytest.fixture(autouse=True)
def _clean():
    _Probe.instances.clear()
    yield
    rclpy.try_shutdown()  # a failing test must not leave the default context up


def _run(factory, **kwargs) -> int:
    return runner.run_node(factory, "runner_probe", ["prog"], **kwargs)


def test_ctrl_c_between_construction_and_the_first_spin_exits_with_the_node_status(monkeypatch):
    real = runner.make_executor

    def interrupted_on_add(kind, context=None):
        executor = real(kind, context)

        def add_node(node):
            raise KeyboardInterrupt

        executor.add_node = add_node
        return executor

    monkeypatch.setattr(runner, "make_executor", interrupted_on_add)
    assert _run(_Probe, exit_status=lambda node: 7) == 7
    (node,) = _Probe.instances
    assert node.destroyed and not rclpy.ok()


def test_a_signal_while_the_node_is_built_stops_it_before_the_first_spin():
    def signalled_half_way():
        node = _Probe()
        os.kill(os.getpid(), signal.SIGINT)  # the handler runs here, in this (main) thread
        return node

    before = signal.getsignal(signal.SIGINT)
    assert _run(signalled_half_way, exit_status=lambda node: 10 + node.ticks) == 10
    (node,) = _Probe.instances
    assert node.destroyed and not rclpy.ok()
    assert signal.getsignal(signal.SIGINT) is before  # the caller's handler is back


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM])
def test_a_signal_while_spinning_ends_after_the_callback_in_progress(signum):
    class Signalling(_Probe):
        def _tick(self):
            super()._tick()
            if self.ticks == 3:
                os.kill(os.getpid(), signum)

    assert _run(Signalling, exit_status=lambda node: node.ticks) == 3
    (node,) = _Probe.instances
    assert node.destroyed and not rclpy.ok()


def test_a_second_signal_gets_the_default_action():
    before = signal.getsignal(signal.SIGTERM)
    with runner.StopSignals() as signals:
        assert not signals.stop
        os.kill(os.getpid(), signal.SIGTERM)
        assert signals.signum == signal.SIGTERM
        assert signal.getsignal(signal.SIGTERM) == signal.SIG_DFL
    assert signal.getsignal(signal.SIGTERM) is before


def test_sigusr1_prints_every_threads_stack_and_the_node_goes_on(capfd):
    """A node that hangs (e.g. in its shutdown) can say where: SIGUSR1 dumps the stacks."""
    class Dumping(_Probe):
        def _tick(self):
            super()._tick()
            if self.ticks == 2:
                os.kill(os.getpid(), signal.SIGUSR1)
            if self.ticks == 4:
                self.done.set_result(self.ticks)

    assert _run(Dumping, until=lambda node: node.done, exit_status=lambda node: node.ticks) == 4
    err = capfd.readouterr().err
    assert "most recent call first" in err and "_tick" in err


def test_an_error_while_the_context_is_up_is_not_swallowed():
    def broken():
        raise RuntimeError("bug in the constructor")

    with pytest.raises(RuntimeError, match="bug in the constructor"):
        _run(broken)
    assert not rclpy.ok()


def test_ctrl_c_while_spinning_destroys_the_node_and_exits_with_its_status():
    assert _run(lambda: _Probe(interrupt_in_spin=True), exit_status=lambda node: node.ticks) == 1
    (node,) = _Probe.instances
    assert node.destroyed and not rclpy.ok()


def test_ctrl_c_inside_the_constructor_exits_0():
    def interrupted():
        raise KeyboardInterrupt

    assert _run(interrupted, exit_status=lambda node: 5) == 0
    assert not rclpy.ok()


def test_an_invalid_parameter_exits_1_without_spinning():
    def invalid():
        raise ParameterError("rate must be > 0")

    assert _run(invalid) == 1
    assert not rclpy.ok()


@pytest.mark.parametrize("kind", runner.EXECUTORS)
def test_spins_until_the_nodes_future_completes(kind):
    status = runner.run_node(lambda: _Probe(finish_after=3), "runner_probe",
                             ["prog", "--executor", kind], until=lambda node: node.done,
                             exit_status=lambda node: 40 + node.done.result())
    assert status == 43
    (node,) = _Probe.instances
    assert node.destroyed and not rclpy.ok()


def test_executor_option_reads_only_the_non_ros_arguments():
    assert runner.executor_option(["prog"], "p") == "single"
    assert runner.executor_option(["prog"], "p", default="events") == "events"
    assert runner.executor_option(["prog", "--executor", "single"], "p", "events") == "single"
    assert runner.executor_option(["prog", "--executor", "events", "--ros-args", "-p",
                                   "a:=1"], "p") == "events"
    assert runner.executor_option(["prog", "--ros-args", "-p", "executor:=events"], "p") == "single"
    with pytest.raises(ParameterError, match="invalid executor 'threads'"):
        runner.make_executor("threads")


# ------------------------------------------------------------------ a teardown that blocks
# (a recorder's blocked for good inside rcl_node_fini, Fast DDS deleting its participant, while
# its peers shut down at the same moment: 1 stop in 776 under CPU load)

_HANGING_TEARDOWN = """
import ctypes, sys, threading
from rclpy.node import Node
from rclpy.task import Future
from flight_fdi.nodes import runner

class Hanging(Node):
    def __init__(self):
        super().__init__("hanging_teardown")
        self.done = Future()
        self.create_timer(0.01, lambda: self.done.set_result(True))

    def finish_work(self):
        print("work complete", flush=True)

    def destroy_node(self):
        super().destroy_node()
        if sys.argv[1] == "gil":       # blocked in C with the GIL held (PyDLL keeps it)
            ctypes.PyDLL(None).pause()
        threading.Event().wait()       # blocked, GIL released (as in rcl_node_fini)

sys.exit(runner.run_node(Hanging, "hanging_teardown", ["prog"], until=lambda n: n.done,
                         exit_status=lambda n: 3, teardown_timeout=float(sys.argv[2])))
"""


def _run_hanging(how: str, timeout_s: float):
    import subprocess
    import sys

    proc = subprocess.run([sys.executable, "-c", _HANGING_TEARDOWN, how, str(timeout_s)],
                          capture_output=True, text=True, timeout=60)  # (a failure bound)
    return proc.returncode, proc.stdout, proc.stderr


def test_a_blocked_middleware_teardown_ends_with_the_nodes_status_after_its_work():
    rc, out, err = _run_hanging("released", 0.5)
    assert rc == 3, err                           # the node's status, not a hang
    assert out == "work complete\n"               # the work was completed before the teardown
    assert "did not end within 0.5 s" in err and "exiting with status 3" in err
    assert "in destroy_node" in err               # the stack says where it blocked


def test_a_teardown_blocked_with_the_gil_held_still_ends_with_the_stacks():
    rc, out, err = _run_hanging("gil", 0.5)
    assert rc == 1, err                           # faulthandler's watchdog: no status to give
    assert out == "work complete\n"
    assert "Timeout (0:00:01)!" in err and "in destroy_node" in err


def test_the_teardown_watchdog_stands_down_when_the_teardown_ends():
    with runner.TeardownWatchdog("quick", 5, 30.0) as watchdog:
        assert watchdog.thread.is_alive()
    watchdog.thread.join(timeout=10)  # (a failure bound: it returns at once)
    assert not watchdog.thread.is_alive()
