"""Pure estimation core: numpy/scipy only, no rclpy. Usable from a notebook::

    from flight_fdi.core import ins_channel, run_analysis
"""
from .errors import CoreError
from .models import LinearModel, attitude_axis, get_model, ins_channel, load_model
from .align import StreamingAligner, align_to_reference
from .kalman import ForwardResult, GateConfig, KalmanFilter, UpdateResult, run_forward
from .references import RedundantFilter, ReferenceConfig, ReferenceMonitor
from .smoother import BackwardResult, run_backward
from .diagnosis import (DiagnosisConfig, Localization, SeedDiagnosis, diagnose, fisher,
                        fisher_threshold, localize, udu)
from .glr import GlrConfig, GlrResult, isolate
from .analysis import (AnalysisConfig, AnalysisResult, analyze_flight, analyze_forward,
                       run_analysis)

__all__ = [
    "CoreError", "LinearModel", "attitude_axis", "get_model", "ins_channel", "load_model",
    "StreamingAligner", "align_to_reference",
    "ForwardResult", "GateConfig", "KalmanFilter", "UpdateResult", "run_forward",
    "RedundantFilter", "ReferenceConfig", "ReferenceMonitor",
    "BackwardResult", "run_backward",
    "DiagnosisConfig", "Localization", "SeedDiagnosis", "diagnose", "fisher", "fisher_threshold",
    "localize", "udu",
    "GlrConfig", "GlrResult", "isolate",
    "AnalysisConfig", "AnalysisResult", "analyze_flight", "analyze_forward", "run_analysis",
]
