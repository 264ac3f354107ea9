"""Pure estimation core: numpy/scipy only, no rclpy. Usable from a notebook."""
from .errors import CoreError
from .models import LinearModel, attitude_axis, get_model, ins_channel, load_model

__all__ = ["CoreError", "LinearModel", "attitude_axis", "get_model", "ins_channel", "load_model"]

# GLR isolation and time alignment
from .align import StreamingAligner, align_to_reference  # noqa: E402
from .glr import GlrConfig, GlrResult, isolate  # noqa: E402

__all__ += ["StreamingAligner", "align_to_reference", "GlrConfig", "GlrResult", "isolate"]

# forward filter, backward information filter, seed diagnosis, offline analysis
from .kalman import ForwardResult, GateConfig, KalmanFilter, UpdateResult, run_forward  # noqa: E402
from .smoother import BackwardResult, run_backward  # noqa: E402
from .diagnosis import (DiagnosisConfig, Localization, SeedDiagnosis, diagnose,  # noqa: E402
                        fisher, fisher_threshold, localize, udu)
from .analysis import AnalysisConfig, AnalysisResult, analyze_flight, run_analysis  # noqa: E402

__all__ += ["ForwardResult", "GateConfig", "KalmanFilter", "UpdateResult", "run_forward",
            "BackwardResult", "run_backward", "DiagnosisConfig", "Localization", "SeedDiagnosis",
            "diagnose", "fisher", "fisher_threshold", "localize", "udu", "AnalysisConfig",
            "AnalysisResult", "analyze_flight", "run_analysis"]
