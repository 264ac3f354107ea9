"""``main()`` of a node executable: init, build the node, spin, shut down.

An invalid parameter (``ParameterError`` from the node's constructor) is logged as FATAL and the
process exits 1 without spinning; Ctrl-C and an external shutdown end the spin normally.
"""
from __future__ import annotations

from typing import Any, Callable

import rclpy
from rclpy.executors import ExternalShutdownException

from .errors import ParameterError


def run_node(factory: Callable[[], Any], name: str, args: list[str] | None = None,
             exit_status: Callable[[Any], int] = lambda node: 0) -> int:
    """Run the node ``factory()`` until shutdown; ``exit_status(node)`` is the return code."""
    rclpy.init(args=args)
    try:
        node = factory()
    except ParameterError as exc:
        rclpy.logging.get_logger(name).fatal(str(exc))
        rclpy.try_shutdown()
        return 1
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        node.destroy_node()
        rclpy.try_shutdown()
    return exit_status(node)
