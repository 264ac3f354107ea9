"""Quaternions live in :mod:`flight_fdi.core.rotation` (the simulator and the ins3d error model
share them); this module keeps the simulator's names."""
from ..core.rotation import (attitude_error_array, dcm_array, euler_from_quat_array, qdcm, qexp,
                             qexp_array, qlog, qmul, qmul_array, qrot, quat_from_euler_array)

__all__ = ["attitude_error_array", "dcm_array", "euler_from_quat_array", "qdcm", "qexp",
           "qexp_array", "qlog", "qmul", "qmul_array", "qrot", "quat_from_euler_array"]
