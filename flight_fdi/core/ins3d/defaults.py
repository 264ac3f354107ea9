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

#: a height reference as the third row (``bagio.height_input``): the message types it reads,
#: the datums, and the defaults of its model -- setting (i) of the real-data evaluation
#: (tools/ins3d_real_eval.py): white 0.05 m, a Markov error of 0.4 m over 5 s, the initial
#: vertical velocity error 1 m/s; the widest interpolation 2 s
HEIGHT_TYPES = ("sensor_msgs/msg/NavSatFix", "sensor_msgs/msg/FluidPressure",
                "geometry_msgs/msg/PointStamped")
DATUMS = ("first", "absolute")
HEIGHT_DEFAULTS = {"sigma": 0.05, "markov": (0.4, 5.0), "datum": "first", "v0_sigma_up": 1.0,
                   "max_gap_s": 2.0}

__all__ = ["ANALYZE_DEFAULTS", "DATUMS", "HEIGHT_DEFAULTS", "HEIGHT_TYPES", "VERTICAL"]
