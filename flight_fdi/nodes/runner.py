"""``main()`` of a node executable: init, build the node, spin, shut down.

    ros2 run flight_fdi filter_node [--executor {single,events}] [--ros-args ...]

``--executor`` (before ``--ros-args``) picks rclpy's executor: ``single`` (what ``rclpy.spin``
uses) or ``events`` (rclpy's C++ EventsExecutor, still ``rclpy.experimental`` in Jazzy: twice the
throughput and half the latency, docs/performance.md). The in-flight monitors (filter_node,
voter_node) default to ``events``: with ``single`` the filter's input -> innovation latency misses
its p99 <= 2 ms target at 10x real time. The other nodes default to ``single``.

``-h`` / ``--help`` prints the node's parameters (its ``*_PARAMS`` table) and exits 0 without
starting anything. Before ``rclpy.init`` the values of the node's own parameters in ``-p`` and
``--params-file`` are typed by its table (``param_args``: ``-p channel:=y`` is the string "y",
the output of ``ros2 param dump`` loads back).

An invalid parameter (``ParameterError`` from the node's constructor), or a node with guard
conditions on the EventsExecutor (which does not support them: bag_player's fast replay without
``ack_topic``), is logged as FATAL and the process exits 1 without spinning; an invalid
``--executor`` is an argparse error (exit 2);
SIGINT / SIGTERM (at any point after ``rclpy.init``) and an external shutdown end the process
normally; a second SIGINT / SIGTERM gets the default action. SIGUSR1 prints the Python stack of
every thread to stderr and the node goes on (``faulthandler``: a node that hangs, e.g. in its
shutdown, can say where; the graph tests send it before they kill a node that did not stop).

Shutdown: the node first completes its own work (``finish_work()`` when it has one: a recorder
closes its bag), then the middleware is torn down (executor, node, context; with Fast DDS the
last node's destruction deletes the DDS participant). That teardown is bounded
(:class:`TeardownWatchdog`, ``teardown_timeout``): under CPU load a recorder's was seen to block
for good inside ``rcl_node_fini`` while its peers shut down at the same moment (1 stop in
776); after the bound the process says so, prints every thread's stack and exits with the
node's own status.
"""
from __future__ import annotations

import argparse
import faulthandler
import os
import signal
import sys
import textwrap
import threading
from typing import Any, Callable

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.signals import SignalHandlerOptions

from .errors import ParameterError

EXECUTORS = ("single", "events")
TEARDOWN_TIMEOUT_S = 10.0  # bound on the middleware teardown once the node's work is complete
ON_TIMEOUT_BOUND_S = 300.0  # bound on what a process still does after its teardown timed out


def make_executor(kind: str, context: Any = None) -> Any:
    """rclpy's SingleThreadedExecutor (``"single"``) or EventsExecutor (``"events"``; the
    Python executor when this rclpy has none); ParameterError for another name."""
    from rclpy.executors import SingleThreadedExecutor

    if kind == "events":
        try:
            from rclpy.experimental import EventsExecutor
        except ImportError:  # an rclpy without it: the Python executor works, slower
            return SingleThreadedExecutor(context=context)
        return EventsExecutor(context=context)
    if kind == "single":
        return SingleThreadedExecutor(context=context)
    raise ParameterError(f"invalid executor {kind!r}; allowed: {', '.join(EXECUTORS)}")


def executor_option(argv: list[str], prog: str, default: str = "single") -> str:
    """The ``--executor`` value among the non-ROS arguments of ``argv`` (argv[0]: program),
    ``default`` when it is not given."""
    return _options(argv, prog, default).executor


def _options(argv: list[str], prog: str, default: str) -> argparse.Namespace:
    from rclpy.utilities import remove_ros_args

    parser = argparse.ArgumentParser(prog=prog, add_help=False)
    parser.add_argument("--executor", choices=EXECUTORS, default=default)
    parser.add_argument("-h", "--help", action="store_true")
    known, _ = parser.parse_known_args(remove_ros_args(args=argv)[1:])
    return known


def node_table(factory: Callable[[], Any]) -> tuple:
    """The ``*_PARAMS`` table of the module that defines ``factory`` (empty when none)."""
    from .params import find_table

    try:
        return find_table(sys.modules[factory.__module__])
    except (KeyError, AttributeError, ValueError):
        return ()


def help_text(name: str, specs: tuple, default_executor: str) -> str:
    """``<node> --help``: usage and every parameter of the table (type, default, allowed
    values, meaning), as documented in config/<node>.yaml."""
    from .params import format_yaml_value

    lines = [f"usage: ros2 run flight_fdi {name} [--executor {{single,events}}] "
             f"[--ros-args -p NAME:=VALUE ... --params-file FILE ...]", "",
             f"  --executor   rclpy executor (default: {default_executor})",
             "  -h, --help   print this help and exit", "", "parameters:"]
    for s in specs:
        unit = f" [{s.unit}]" if s.unit else ""
        lines.append(f"  {s.name} ({s.type}, default {format_yaml_value(s.default)}){unit}")
        lines += ["      " + ln for ln in textwrap.wrap(
            f"{s.description}. Allowed: {s.allowed()}." +
            ("" if s.read_only else " Can be changed at run time."), width=88)]
    return "\n".join(lines) + "\n"


class StopSignals:
    """SIGINT / SIGTERM as a request to stop, handled in Python between callbacks.

    rclpy's own handler (a C++ thread that shuts the context down and then triggers every
    executor's guard condition) races with the executor's teardown: the thread can trigger a
    guard condition the main thread has just destroyed, a segfault seen under load. Here a signal
    only sets :attr:`signum`; the spin loop sees it within one ``spin_once`` timeout, the callback
    in progress completes, and the node is torn down in order. A second signal of the same kind
    gets the default action (a hung shutdown can still be killed with another Ctrl-C).
    While installed, SIGUSR1 prints every thread's Python stack to stderr (``faulthandler``).
    Installed in the main thread only (elsewhere Python cannot handle signals: a no-op).
    """

    def __init__(self, signals: tuple[int, ...] = (signal.SIGINT, signal.SIGTERM)) -> None:
        self.signals = signals
        self.signum: int | None = None
        self._previous: dict[int, Any] = {}

    def __enter__(self) -> "StopSignals":
        if threading.current_thread() is threading.main_thread():
            for signum in self.signals:
                self._previous[signum] = signal.signal(signum, self._handle)
            faulthandler.register(signal.SIGUSR1, all_threads=True)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._previous:
            faulthandler.unregister(signal.SIGUSR1)
        for signum, previous in self._previous.items():
            signal.signal(signum, previous)
        self._previous.clear()

    def _handle(self, signum: int, frame: Any) -> None:
        self.signum = signum
        signal.signal(signum, signal.SIG_DFL)

    @property
    def stop(self) -> bool:
        return self.signum is not None


class TeardownWatchdog:
    """Bounds the middleware teardown that follows a node's (or the pipeline's) completed work.

    Inside ``with TeardownWatchdog(name, status, timeout):`` a daemon thread waits ``timeout``
    seconds; if the block has not ended by then it writes one line saying so -- naming
    :attr:`stage`, what the teardown was doing (the block sets it as it goes: "destroying node
    recorder_node") -- and every thread's stack to stderr and ends the process with ``status``
    (``os._exit``: what the node was responsible for is done; only the middleware's goodbye to
    its peers is lost, and they drop the participant when its lease expires). ``after`` says
    what was complete before the teardown began. Should the blocked call hold the GIL (the
    thread could not run), faulthandler's own watchdog, which needs none, dumps the stacks and
    exits with status 1 after ``2 * timeout``. ``timeout`` None: no bound.

    ``on_timeout``: what the process still has to do once its work is complete, e.g. ``flight-fdi
    run``'s printing of the result and its report. Called in the watchdog's thread after the
    line and the stacks, bounded by faulthandler's watchdog (``ON_TIMEOUT_BOUND_S``: stacks and
    status 1 when it does not return); its return value is the exit status (an exception: a line
    and ``status``); a second line says the status. Once the watchdog has fired, a teardown that
    ends after all does not let the block's thread go on: the watchdog ends the process.
    """

    def __init__(self, name: str, status: int, timeout: float | None,
                 after: str = "the node completed its work",
                 on_timeout: Callable[[], int] | None = None) -> None:
        self.name, self.status, self.timeout, self.after = name, status, timeout, after
        self.on_timeout = on_timeout
        self.stage = "executor, node, context"
        self._done = threading.Event()
        self._fired = False
        self._lock = threading.Lock()
        self.thread = threading.Thread(target=self._watch, name="teardown-watchdog", daemon=True)

    def __enter__(self) -> "TeardownWatchdog":
        if self.timeout is not None:
            self.thread.start()
            faulthandler.dump_traceback_later(2 * self.timeout, exit=True)
        return self

    def __exit__(self, *exc: Any) -> None:
        with self._lock:
            self._done.set()
            fired = self._fired
        if fired:  # too late: the watchdog is ending the process (after on_timeout)
            self.thread.join()
        if self.timeout is not None:
            faulthandler.cancel_dump_traceback_later()

    def _watch(self) -> None:
        if self._done.wait(self.timeout):
            return
        with self._lock:
            if self._done.is_set():
                return
            self._fired = True
        os.write(2, self._line().encode())
        faulthandler.dump_traceback(all_threads=True)
        status = self.status
        if self.on_timeout is not None:
            status = self._complete()
        for stream in (sys.stdout, sys.stderr):
            try:
                stream.flush()
            except (OSError, ValueError):
                pass
        os._exit(status)

    def _line(self) -> str:
        """The line said when the bound passes (the stacks follow)."""
        then = (f"exiting with status {self.status} without it" if self.on_timeout is None
                else "completing the command without it")
        return (f"[WARN] [{self.name}]: the middleware teardown did not end within "
                f"{self.timeout:g} s ({self.stage}) after {self.after}; {then}. Stacks:\n")

    def _complete(self) -> int:
        """``on_timeout()``, bounded (class docstring); the exit status."""
        faulthandler.cancel_dump_traceback_later()
        faulthandler.dump_traceback_later(ON_TIMEOUT_BOUND_S, exit=True)
        status = self.status
        try:
            status = int(self.on_timeout())
        except BaseException as exc:  # said, and the status stays
            os.write(2, f"[ERROR] [{self.name}]: {type(exc).__name__}: {exc}\n".encode())
        try:
            sys.stdout.flush()  # (the command's output before the last line)
        except (OSError, ValueError):
            pass
        os.write(2, f"[WARN] [{self.name}]: exiting with status {status} without the middleware "
                    "teardown\n".encode())
        return status


class SpinWatchdog(TeardownWatchdog):
    """Bounds a spin that a node callback blocks: the spin loop checks its deadline only between
    callbacks, so a callback that never returns would hold the process past any bound. Inside
    ``with SpinWatchdog(name, bound):`` the watchdog's thread says so in one line (naming
    :attr:`stage`: what the spin was waiting for), dumps every thread's stack and ends the
    process with status 1 once ``bound`` passes (the run's own deadline plus a grace; a callback
    that returns before that lets the spin loop report its timeout as usual). What the nodes
    had written stays (the recorder is kill-safe to its last flush)."""

    def __init__(self, name: str, bound: float) -> None:
        super().__init__(name, 1, bound)
        self.stage = "spinning"
        self.thread.name = "spin-watchdog"

    def _line(self) -> str:
        return (f"[ERROR] [{self.name}]: timed out while {self.stage}: a node callback has not "
                f"returned within {self.timeout:g} s; exiting with status 1. Stacks:\n")


def run_node(factory: Callable[[], Any], name: str, args: list[str] | None = None,
             exit_status: Callable[[Any], int] = lambda node: 0,
             until: Callable[[Any], Any] = lambda node: None,
             default_executor: str = "single",
             teardown_timeout: float | None = TEARDOWN_TIMEOUT_S) -> int:
    """Run the node ``factory()`` on the executor chosen by ``--executor`` (``default_executor``
    when not given) until SIGINT / SIGTERM or an external shutdown, or until the
    future ``until(node)`` (None: no such future) completes; ``exit_status(node)`` is then the
    return code.

    A signal at any point after ``rclpy.init`` -- while the node is being built, before the
    first spin, or while it spins -- ends the process normally (:class:`StopSignals`): the node
    is destroyed (a recorder completes its bag), the context shut down, and the return code is
    ``exit_status(node)`` (0 when no node was built).

    Then, in this order: the node's ``finish_work()`` if it has one (its work completed, e.g. a
    recorder's bag closed), ``exit_status(node)``, and the middleware teardown (executor shutdown,
    ``destroy_node``, context shutdown), bounded by ``teardown_timeout`` seconds
    (:class:`TeardownWatchdog`; None: unbounded).
    """
    from .param_args import normalize_ros_args

    specs = node_table(factory)
    # parameter values typed by the node's table (y is a string to a channel parameter ...)
    argv, temps = normalize_ros_args(list(sys.argv if args is None else args), specs)
    try:
        opts = _options(argv, name, default_executor)
        if opts.help:
            sys.stdout.write(help_text(name, specs, default_executor))
            return 0
        kind = opts.executor
        rclpy.init(args=argv, signal_handler_options=SignalHandlerOptions.NO)
    finally:  # rcl has read the params files
        for path in temps:
            os.unlink(path)
    node = executor = None
    with StopSignals() as signals:
        try:
            executor = make_executor(kind)
            try:
                node = factory()
                if kind == "events" and any(True for _ in node.guards):
                    raise ParameterError(
                        f"{name} uses a guard condition in this configuration, which rclpy's "
                        "EventsExecutor does not support: use --executor single")
            except ParameterError as exc:
                rclpy.logging.get_logger(name).fatal(str(exc))
                return 1
            executor.add_node(node)
            done = until(node)
            # spin_once in a loop rather than spin(): the stop request is seen between calls
            while not signals.stop and rclpy.ok() and not (done is not None and done.done()):
                executor.spin_once(timeout_sec=0.1)
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        finally:
            try:
                if node is not None and hasattr(node, "finish_work"):
                    node.finish_work()  # the node's work complete before anything can block
            finally:
                status = 0 if node is None else exit_status(node)
                with TeardownWatchdog(name, status, teardown_timeout) as watchdog:
                    if executor is not None:
                        watchdog.stage = "shutting down the executor"
                        executor.shutdown()
                    if node is not None:
                        watchdog.stage = f"destroying node {name}"
                        node.destroy_node()
                    watchdog.stage = "shutting down the context"
                    rclpy.try_shutdown()
    return status
