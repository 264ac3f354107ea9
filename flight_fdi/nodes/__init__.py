"""ROS 2 nodes of flight_fdi (rclpy). Nodes stay thin: they convert messages
(:mod:`.convert`), declare and validate parameters (:mod:`.params`), publish diagnostics
(:mod:`.diagnostics`) and call the pure estimation core (:mod:`flight_fdi.core`).

Importing this package does not import rclpy; the node modules do.
"""
from .errors import ParameterError

__all__ = ["ParameterError"]
