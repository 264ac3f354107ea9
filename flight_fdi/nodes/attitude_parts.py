"""The parameters and per-axis state of filter_node's attitude mode (``attitude_mode``): the
attitude model and actuator monitor configuration built from the node parameters, the protocol
of what the mode needs of the node, one axis channel, one waiting angle sample."""
from __future__ import annotations

from typing import Any, Protocol

import numpy as np

from ..core.actuator import (DISTURBANCE, ActuatorConfig, ActuatorEvent, ActuatorMonitor,
                             attitude_model, require_observable)
from ..core.errors import CoreError
from ..core.kalman import GateConfig, KalmanFilter
from ..core.models import LinearModel
from . import convert
from . import diagnostics as diag
from .errors import ParameterError
from .params import fail

# Small quantities are parameters in micro-units (like the INS mode's sigma_w_deg_h): rclpy's
# Python params-file loader reads a double written as 1e-05 back as a string.
_MICRO = 1e6
#: node parameter -> (keyword of the built-in ``attitude_axis`` model, divisor to its SI unit)
MODEL_KEYS = {"attitude_m_c": ("m_c", 1.0),
              "attitude_sigma_md_walk_urad_s2": ("sigma_md_walk", _MICRO),
              "attitude_sigma_angle_urad": ("sigma_angle", _MICRO),
              "attitude_sigma_rate_urad_s": ("sigma_rate", _MICRO)}
#: node parameter -> (ActuatorConfig field, divisor to its SI unit)
MONITOR_KEYS = {"actuator_window_s": ("window_s", 1.0),
                "actuator_threshold_urad_s2": ("threshold", _MICRO),
                "actuator_zero_tolerance": ("zero_tol", 1.0),
                "actuator_settle_s": ("settle_s", 1.0), "actuator_k_sigma": ("k_sigma", 1.0)}
#: parameters that mean something only in the attitude mode
ATTITUDE_ONLY = ("attitude_measure", *MODEL_KEYS, "angle_topic", "rate_topic", "control_topic",
                 "attitude_wait_s", "rate_sync_tolerance_s", *MONITOR_KEYS)
_ROWS = {"angle": 1, "angle+rate": 2, "rate": 1}


def is_attitude_model(name: str) -> bool:
    """True when ``model`` names the built-in attitude model (a model file selects the attitude
    mode by having a control input B)."""
    return name == "attitude_axis"


def build_attitude_model(values: dict[str, Any], defaults: dict[str, Any],
                         file_model: LinearModel | None = None) -> LinearModel:
    """The attitude model from the node parameters, checked for observability (ParameterError
    naming the parameter otherwise). ``file_model``: a model loaded from a YAML file with B."""
    measure = values["attitude_measure"]
    if file_model is None:
        key = "attitude_sigma_rate_urad_s"
        if measure == "angle" and values[key] != defaults[key]:
            fail(key, values[key], f"its default ({defaults[key]!r}): the rate is not measured "
                 "(attitude_measure angle)")
        params = {core: values[k] / div for k, (core, div) in MODEL_KEYS.items()}
        try:
            model = attitude_model(measure, **params)
        except CoreError as exc:  # the table's ranges should make this unreachable
            raise ParameterError(f"invalid attitude model parameters: {exc}") from None
        key = "attitude_measure"
    else:
        model = file_model
        key = "model"
        for k in MODEL_KEYS:
            if values[k] != defaults[k]:
                fail(k, values[k], f"its default ({defaults[k]!r}): attitude model parameters "
                     "apply only to the built-in attitude_axis (a model file carries its own)")
        if model.B.shape[1] != 1:
            fail("model", values["model"], "an attitude model with one control input per axis; "
                 f"{model.name} has {model.B.shape[1]}")
        if DISTURBANCE not in model.state_names:
            fail("model", values["model"], f"an attitude model with a state named "
                 f"{DISTURBANCE!r} (the actuator monitor's); {model.name} has "
                 f"{', '.join(model.state_names)}")
        if model.m != _ROWS[measure]:
            fail("attitude_measure", measure, f"the rows of the model file: {model.name} has "
                 f"{model.m} measurement row(s) (angle: 1 row from angle_topic; angle+rate: "
                 "2 rows, angle_topic then rate_topic)")
    try:
        require_observable(model, values["actuator_window_s"])
    except CoreError as exc:
        fail(key, values[key], f"an observable configuration ({exc})")
    if measure == "rate":  # observable only for an exotic model file
        fail("attitude_measure", measure, "angle or angle+rate (the attitude mode steps at each "
             "angle sample)")
    return model


def actuator_config(values: dict[str, Any]) -> ActuatorConfig:
    """ActuatorConfig from the ``actuator_*`` parameters."""
    try:
        return ActuatorConfig(**{f: values[k] / div for k, (f, div) in MONITOR_KEYS.items()})
    except CoreError as exc:  # the table's ranges should make this unreachable
        raise ParameterError(f"invalid actuator monitor parameters: {exc}") from None


class FilterHost(Protocol):
    """What the attitude mode needs of the filter node beyond rclpy's Node (publishers,
    subscriptions, timers, logger, ``p``, ``counters``, ``diagnostics``, ``channels``,
    ``inputs``): the node's shared input checks and outputs. The mode never touches a filter's
    state except through KalmanFilter's public calls (``step``/``predict``/``update`` in one
    ``transaction``)."""

    def _now(self) -> float:
        """The node's clock in seconds."""

    def _resolve(self, key: str, topic: str) -> str:
        """The fully qualified name of ``topic`` (ParameterError naming ``key``)."""

    def _create_outputs(self, n_channels: int) -> None:
        """fdi/innovation, fdi/state and fdi/model publishers (``pub_*``)."""

    def _bad_stamp(self, what: str, t: float, sec: int, nanosec: int) -> bool:
        """True (and counted) when a stamp cannot be carried by an output stamp."""

    def _drop(self, reason: str, detail: str, channel: Any = None, n: int = 1) -> None:
        """Count a dropped sample (``dropped_<reason>``) and warn (throttled)."""

    def _dt(self, ch: Any, t: float) -> tuple[float, bool]:
        """(dt, reset) of the next step of channel ``ch`` at ``t``."""


class AxisChannel:
    """One axis: its filter, its actuator monitor, the latched event, counts."""

    def __init__(self, name: str, model: LinearModel, gate: GateConfig,
                 config: ActuatorConfig) -> None:
        self.name = name
        self.axis = convert.AXIS_INDEX[name]
        self.model = model
        self.config = config
        self.kf = KalmanFilter(model, gate)
        self.event: ActuatorEvent | None = None
        self.windows_closed = 0
        self.windows_evaluated = 0
        self.last_t: float | None = None
        self.last_step_clock: float | None = None
        self.last_u: float | None = None
        self.result = None
        self.alarm_since: float | None = None
        self.counters = diag.Counters(("fused", "gated", "rejected", "alarms_raised", "resets"))
        self._new_monitor(check_observable=True)

    def _new_monitor(self, check_observable: bool = False) -> None:
        self.monitor = ActuatorMonitor(self.model, self.config, self.name, keep_windows=False,
                                       check_observable=check_observable)
        self.monitor.latched = self.event is not None  # the switch has been made
        self._window = None

    def reset(self) -> None:
        """Restart the filter from the prior, and the monitor (its time line and open window;
        a latched event stays latched)."""
        self.kf.reset()
        self.last_t = None
        self.alarm_since = None
        self._new_monitor()

    def window_closed(self) -> bool:
        """Count a window the monitor closed at the last update; True when one did."""
        w = self.monitor.last_window
        if w is None or w is self._window:
            return False
        self._window = w
        self.windows_closed += 1
        self.windows_evaluated += bool(w.evaluated)
        return True


class Sample:
    """An angle sample waiting for its command (and rate): stamp, values per axis, arrival time
    on the node clock."""

    __slots__ = ("t", "angle", "rate", "arrived")

    def __init__(self, t: float, angle: np.ndarray, arrived: float) -> None:
        self.t = t
        self.angle = angle
        self.rate: np.ndarray | None = None
        self.arrived = arrived
