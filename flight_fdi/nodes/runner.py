"""``main()`` of a node executable: init, build the node, spin, shut down.

    ros2 run flight_fdi filter_node [--executor {single,events}] [--ros-args ...]

``--executor`` (before ``--ros-args``) picks rclpy's executor: ``single`` (default, what
``rclpy.spin`` uses) or ``events`` (rclpy's C++ EventsExecutor, still ``rclpy.experimental`` in
Jazzy: several times the throughput and lower latency, docs/performance.md).

An invalid parameter (``ParameterError`` from the node's constructor) is logged as FATAL and the
process exits 1 without spinning; an invalid ``--executor`` is an argparse error (exit 2);
Ctrl-C and an external shutdown end the spin normally.
"""
from __future__ import annotations

import argparse
import sys
from typing import Any, Callable

import rclpy
from rclpy.executors import ExternalShutdownException

from .errors import ParameterError

EXECUTORS = ("single", "events")


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


def executor_option(argv: list[str], prog: str) -> str:
    """The ``--executor`` value among the non-ROS arguments of ``argv`` (argv[0]: program)."""
    from rclpy.utilities import remove_ros_args

    parser = argparse.ArgumentParser(prog=prog, add_help=False)
    parser.add_argument("--executor", choices=EXECUTORS, default="single")
    known, _ = parser.parse_known_args(remove_ros_args(args=argv)[1:])
    return known.executor


def run_node(factory: Callable[[], Any], name: str, args: list[str] | None = None,
             exit_status: Callable[[Any], int] = lambda node: 0) -> int:
    """Run the node ``factory()`` until shutdown; ``exit_status(node)`` is the return code."""
    argv = list(sys.argv if args is None else args)
    kind = executor_option(argv, name)
    rclpy.init(args=argv)
    try:
        node = factory()
    except ParameterError as exc:
        rclpy.logging.get_logger(name).fatal(str(exc))
        rclpy.try_shutdown()
        return 1
    except KeyboardInterrupt:  # Ctrl-C while the node was being built
        rclpy.try_shutdown()
        return 0
    executor = make_executor(kind)
    try:
        executor.add_node(node)
        # spin_once in a loop rather than spin(): the EventsExecutor's spin() does not return
        # when Ctrl-C shuts the context down
        while rclpy.ok():
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.try_shutdown()
    return exit_status(node)
