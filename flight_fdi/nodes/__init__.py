"""ROS 2 nodes of flight_fdi (rclpy). Nodes stay thin: they convert messages
(:mod:`.convert`), declare and validate parameters (:mod:`.params`), publish diagnostics
(:mod:`.diagnostics`) and call the pure estimation core (:mod:`flight_fdi.core`).

Importing this package does not import rclpy; the node modules do. It sets the processes' BLAS
threading before numpy loads (:mod:`flight_fdi.blas_env`: one OpenBLAS thread unless the user
set OPENBLAS_NUM_THREADS), so every node executable gets it.
"""
from ..blas_env import one_blas_thread

one_blas_thread()

from .errors import ParameterError  # noqa: E402

__all__ = ["ParameterError"]
