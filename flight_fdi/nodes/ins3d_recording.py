"""The ins3d recording's layout, under the name the nodes (``ins3d_mode``) and older callers use.

Nothing here needs rclpy, so nothing lives here: the recording's layout (FilterState /
ModelInfo) and its reader are :mod:`flight_fdi.bagio.recording3d` (re-exported here), its
analysis (``analyze_recording3d``) and what ``smoother_node`` (``channel: ins3d``) runs
(``smoother_run``) :mod:`flight_fdi.bagio.recording_analysis`.
"""
from __future__ import annotations

from flight_fdi.bagio.recording3d import (CHANNEL, GRADE_PREFIX, OPTION_PREFIX,  # noqa: F401
                                          ROW_NAMES, STEP_U, grade_params, option_params,
                                          pack_step, read_recording3d, recorded_grade,
                                          recorded_options, state_units, t0_params)

__all__ = ["CHANNEL", "GRADE_PREFIX", "OPTION_PREFIX", "ROW_NAMES", "STEP_U", "grade_params",
           "option_params", "pack_step", "read_recording3d", "recorded_grade",
           "recorded_options", "state_units", "t0_params"]
