"""The ins3d mode's parameters (``model: ins3d``), apart from the mode itself.

``filter_node`` declares these at start-up in every mode (one parameter set, one
``config/filter.yaml``), but imports the mode (``nodes/ins3d_mode.py``: the 3-D core, its compiled
kernels, scipy) only when ``model: ins3d`` is selected, so this module imports of
``flight_fdi.core.ins3d`` only ``defaults`` (which imports nothing): the core's own defaults
(``analyze_ins3d``'s model options, ``model.VERTICAL``) are taken from there.
"""
from __future__ import annotations

from typing import Any

from ..core.ins3d.defaults import (ANALYZE_DEFAULTS, DATUMS, HEIGHT_DEFAULTS, HEIGHT_TYPES,
                                   VERTICAL)
from .params import ParamSpec, fail

MODEL = "ins3d"

INS3D_PARAMS = (
    ParamSpec("imu_topic", "string", "/ins/imu",
              "ins3d mode: INS attitude and mean IMU rate / specific force (sensor_msgs/Imu)",
              non_empty=True),
    ParamSpec("fix_topic", "string", "/ins/fix",
              "ins3d mode: INS latitude and height (sensor_msgs/NavSatFix)", non_empty=True),
    ParamSpec("ins3d_grade", "string", "navigation",
              "ins3d mode: IMU grade of the bias models, a preset (navigation, tactical, mems) "
              "or the path of a YAML grade file (docs/ins3d.md, 'IMU grade from a file')",
              non_empty=True),
    ParamSpec("ins3d_rows", "int", 3,
              "ins3d mode: reference rows, 2 (east, north) or 3 (with up)", "rows",
              min=2, max=3),
    ParamSpec("ins3d_vertical", "string", ANALYZE_DEFAULTS["vertical"],
              "ins3d mode: the error model's vertical channel -- loop (the INS's baro height "
              "loop), damped (an unknown height loop: dv_U a Markov state of its own) or free "
              "(a free-inertial INS on a short flight); a bag's description says which "
              "(docs/ins3d.md, 'The contract description')", choices=VERTICAL),
    ParamSpec("ins3d_latency", "bool", ANALYZE_DEFAULTS["latency"],
              "ins3d mode: estimate the reference's latency (a state)"),
    ParamSpec("ins3d_reference_markov", "double_array", list(ANALYZE_DEFAULTS["ref_markov"]),
              "ins3d mode: the reference's Markov noise states, [sigma_h m/s, sigma_v m/s, tau "
              "s] (all > 0), or [0, 0, 0]: none (white reference noise)", min=0.0),
    ParamSpec("ins3d_aligned_prior", "bool", ANALYZE_DEFAULTS["aligned_prior"],
              "ins3d mode: the initial covariance of an INS levelled on its own accelerometers "
              "(the tilt cancels the horizontal accelerometer bias); false: independent states "
              "(its attitude came from elsewhere)"),
    ParamSpec("ins3d_height_topic", "string", "",
              "ins3d mode: a height reference as the third reference row (a barometer or an "
              "altitude, ins3d_height_type; docs/ins3d.md, 'A height reference'); empty: none"),
    ParamSpec("ins3d_height_type", "string", HEIGHT_TYPES[1],
              "ins3d mode: the height topic's message type", choices=HEIGHT_TYPES),
    ParamSpec("ins3d_height_sigma", "double", HEIGHT_DEFAULTS["sigma"],
              "ins3d mode: white sigma of a height message without a known variance", "m",
              min=0.0, min_exclusive=True),
    ParamSpec("ins3d_height_markov", "double_array", list(HEIGHT_DEFAULTS["markov"]),
              "ins3d mode: the height's Markov error [sigma m, tau s] (both > 0; the third "
              "row's own, beside ins3d_reference_markov's), or [0, 0]: none", min=0.0),
    ParamSpec("ins3d_height_datum", "string", HEIGHT_DEFAULTS["datum"],
              "ins3d mode: first -- the height offset to the INS height at its first sample; "
              "absolute -- as published", choices=DATUMS),
    ParamSpec("ins3d_v0_sigma_up", "double", HEIGHT_DEFAULTS["v0_sigma_up"],
              "ins3d mode, with a height topic: the initial vertical velocity error's sigma",
              "m/s", min=0.0, min_exclusive=True),
    ParamSpec("ins3d_wait_s", "double", 1.0,
              "ins3d mode: longest wait (in IMU stamps) of a step for the reference stream to "
              "pass it; after that a late reference sample is dropped", "s",
              min=0.0, max=60.0, min_exclusive=True),
    ParamSpec("ins3d_end_idle_s", "double", 2.0,
              "ins3d mode: end of input -- after this long without a message on any of the "
              "inputs (steady clock) the waiting steps and reference rows are flushed and the "
              "record ends; the next message starts a new record (0: never)", "s",
              min=0.0, max=3600.0),
)
INS3D_ONLY = tuple(s.name for s in INS3D_PARAMS)
#: filter_node parameters the ins3d mode uses besides its own
USED = INS3D_ONLY + (
    "model", "ins_topic", "reference_topic", "input_qos", "input_queue_depth", "gate_rule",
    "gate_probability", "alarm_m", "alarm_n", "gate_action", "frame_id",
    "diagnostics_period_s", "stale_after_s", "rate_window_s")


def refuse_in_other_modes(values: dict[str, Any], defaults: dict[str, Any]) -> None:
    """A changed ins3d-only parameter with another model would be ignored: refuse it."""
    for k in INS3D_ONLY:
        if values[k] != defaults[k]:
            fail(k, values[k], f"its default ({defaults[k]!r}): it applies only to model ins3d")


__all__ = ["ANALYZE_DEFAULTS", "INS3D_ONLY", "INS3D_PARAMS", "MODEL", "USED", "VERTICAL",
           "refuse_in_other_modes"]
