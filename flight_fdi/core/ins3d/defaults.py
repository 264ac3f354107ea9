"""The 3-D core's defaults that a light module needs without importing the core.

``nodes/ins3d_params.py`` declares the ins3d mode's node parameters in every mode of filter_node,
which imports the 3-D core (numpy, scipy, the compiled kernels) only when ``model: ins3d`` is
selected; so this module imports nothing (``flight_fdi/core/ins3d/__init__.py`` imports nothing
either). ``model.VERTICAL`` and ``analysis.analyze_ins3d``'s model-option defaults are these.
"""
from __future__ import annotations

#: the error model's vertical channels (``model.Ins3dModel.vertical``)
VERTICAL = ("damped", "free", "loop")
#: the defaults of ``analysis.analyze_ins3d``'s model options
ANALYZE_DEFAULTS = {"vertical": "loop", "latency": True, "ref_markov": (0.02, 0.03, 30.0),
                    "aligned_prior": True}

__all__ = ["ANALYZE_DEFAULTS", "VERTICAL"]
