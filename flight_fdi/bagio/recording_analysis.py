"""A recording of ``filter_node`` read and analysed, no rclpy: what ``smoother_node`` runs.

    smoother_run(bag, channel="x", state_topic="/fdi/state", model_topic="/fdi/model", *,
                 config=None, flight_start_s=None, **analysis_fields) -> SmootherRun
        channel x / y: :func:`flight_fdi.bagio.recording.read_recording` then the core's
        :func:`flight_fdi.core.recording.analyze_recording` (``config``: the core's
        AnalysisConfig; None: its defaults with the recorded gate and ``analysis_fields``, e.g.
        ``fisher_window``); channel ins3d: :func:`analyze_recording3d` (``config``'s gate, else
        the recorded one). Never raises for a bag that cannot be analysed: the SmootherRun then
        holds a schema-valid ``insufficient_data`` result and the one-line ``error``.
    analyze_recording3d(path, state_topic, model_topic, bag_label=None, gate=None)
        -> (result dict, Ins3dAnalysis, the recording's dict of ``read_recording3d``)
        the analysis of ``flight-fdi analyze --model ins3d`` on the recorded inputs (raises
        BagError / CoreError).

A notebook gets the smoother's result of a recording with ``smoother_run("run/recording")``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

from .errors import BagError
from .recording3d import read_recording3d


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


def smoother_run(bag: str | Path, channel: str = "x", state_topic: str = "/fdi/state",
                 model_topic: str = "/fdi/model", *, config: Any = None,
                 flight_start_s: float | None = None, **analysis_fields: Any) -> Any:
    """The SmootherRun of ``channel`` of the recording ``bag`` (module docstring)."""
    from flight_fdi.core.errors import CoreError
    from flight_fdi.core.recording import SmootherRun, error_result

    bag = str(bag) if bag else ""
    if channel == "ins3d":
        try:
            if not bag:
                raise BagError("no bag given (set the 'bag' parameter)")
            result, analysis, rec = analyze_recording3d(
                bag, state_topic, model_topic, bag_label=bag,
                gate=config.gate if config is not None else None)
            return SmootherRun(result=result, ins3d=(analysis, rec))
        except (BagError, CoreError, ValueError) as exc:
            return SmootherRun(result={**error_result(bag, "en", str(exc)), "model": "ins3d"},
                               error=str(exc))
    from flight_fdi.core.recording import analysis_config, analyze_recording

    from .recording import read_recording

    try:
        if not bag:
            raise BagError("no bag given (set the 'bag' parameter)")
        rec = read_recording(bag, channel, state_topic, model_topic)
        config = config or analysis_config(gate=rec.gate, **analysis_fields)
        return analyze_recording(rec, config, flight_start_s or None, bag_label=bag)
    except (BagError, CoreError) as exc:
        return SmootherRun(result=error_result(bag, channel, str(exc)), error=str(exc))


__all__ = ["analyze_recording3d", "smoother_run"]
