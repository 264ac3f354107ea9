"""The ins3d recording in the nodes: ``smoother_node`` (``channel: ins3d``) reads a recording
of ``filter_node`` (``model: ins3d``) back into the core's NavSteps / RefRows and runs the same
analysis as ``flight-fdi analyze --model ins3d``. The recording's layout (FilterState /
ModelInfo) and its reader, which need no rclpy, are :mod:`flight_fdi.bagio.recording3d`
(re-exported here).
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from flight_fdi.bagio.errors import BagError
from flight_fdi.bagio.recording3d import (CHANNEL, GRADE_PREFIX, OPTION_PREFIX,  # noqa: F401
                                          ROW_NAMES, STEP_U, grade_params, option_params,
                                          pack_step, read_recording3d, recorded_grade,
                                          recorded_options, state_units, t0_params)


def analyze_recording3d(path: str | Path, state_topic: str = "/fdi/state",
                        model_topic: str = "/fdi/model", bag_label: str | None = None,
                        gate: Any = None) -> tuple[dict, Any, dict]:
    """(result dict, Ins3dAnalysis, recording) of an ins3d recording: the analysis of
    ``flight-fdi analyze --model ins3d`` on the recorded inputs (``gate``: override the
    recorded one)."""
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.core.ins3d_result import ins3d_result

    rec = read_recording3d(path, state_topic, model_topic)
    analysis = analyze_ins3d(rec["steps"], rec["refs"], grade=rec["grade"], rows=rec["rows"],
                             gate=gate or rec["gate"], **rec["options"])
    return ins3d_result(analysis, bag_label or str(path)), analysis, rec


def smoother_run3d(bag: str, state_topic: str, model_topic: str, gate: Any = None):
    """What ``smoother_node`` (``channel: ins3d``) runs: a SmootherRun with the result (and in
    its ``ins3d`` the analysis and the recording read), or for a bag that cannot be analysed a
    schema-valid ``insufficient_data`` result with the error (never raises for bad input)."""
    from flight_fdi.core.errors import CoreError

    from .smoother_node import SmootherRun, error_result

    try:
        if not bag:
            raise BagError("no bag given (set the 'bag' parameter)")
        result, analysis, rec = analyze_recording3d(bag, state_topic, model_topic,
                                                    bag_label=bag, gate=gate)
        return SmootherRun(result=result, ins3d=(analysis, rec))
    except (BagError, CoreError, ValueError) as exc:
        return SmootherRun(result={**error_result(bag, "en", str(exc)), "model": "ins3d"},
                           error=str(exc))


__all__ = ["CHANNEL", "STEP_U", "analyze_recording3d", "grade_params", "option_params",
           "pack_step", "read_recording3d", "recorded_grade", "recorded_options",
           "smoother_run3d", "state_units", "t0_params"]
