"""Pure estimation core: numpy/scipy only, no rclpy. Usable from a notebook::

    from flight_fdi.core import ins_channel, run_analysis

The names below are imported on first use (PEP 562), so that importing one submodule (e.g.
``flight_fdi.core.forked`` before a bag is read) does not import SciPy and every other module.
"""
from __future__ import annotations

import importlib
from typing import Any

#: public name -> the submodule that defines it
_EXPORTS = {
    "CoreError": "errors",
    "LinearModel": "models", "attitude_axis": "models", "get_model": "models",
    "ins_channel": "models", "load_model": "models",
    "StreamingAligner": "align", "align_to_reference": "align",
    "ForwardResult": "kalman", "GateConfig": "kalman", "KalmanFilter": "kalman",
    "UpdateResult": "kalman", "run_forward": "kalman",
    "RedundantFilter": "references", "ReferenceConfig": "references",
    "ReferenceMonitor": "references",
    "BackwardResult": "smoother", "run_backward": "smoother",
    "DiagnosisConfig": "diagnosis", "Localization": "diagnosis", "SeedDiagnosis": "diagnosis",
    "diagnose": "diagnosis", "fisher": "diagnosis", "fisher_threshold": "diagnosis",
    "localize": "diagnosis", "udu": "diagnosis",
    "GlrConfig": "glr", "GlrResult": "glr", "isolate": "glr",
    "AnalysisConfig": "analysis", "AnalysisResult": "analysis", "analyze_flight": "analysis",
    "analyze_forward": "analysis", "run_analysis": "analysis",
}

__all__ = list(_EXPORTS)


def __getattr__(name: str) -> Any:
    module = _EXPORTS.get(name)
    if module is None:
        raise AttributeError(f"module 'flight_fdi.core' has no attribute {name!r}")
    value = getattr(importlib.import_module(f".{module}", __name__), name)
    globals()[name] = value
    return value


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
