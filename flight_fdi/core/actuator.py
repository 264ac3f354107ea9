"""Actuator fault monitor of the spacecraft attitude axis (seed 003; SPEC section 7).

Per axis j the filter estimates x = (angle, rate, disturbance) of::

    angle' = rate,   rate' = m_c u + m_d,   m_d' = small noise,   z = angle (+ rate)

where m_c u is the commanded control torque per unit inertia and m_d the disturbance torque per
unit inertia. The decision rule of the seed: *if the mean of the estimated disturbance over a
time base where the control is zero exceeds the admissible threshold, the actuator has failed;
switch to the reserve.* While the actuators are commanded off, the only torque acting is the
environment's (gravity gradient, solar pressure: small and nearly constant); a thruster whose
valve leaks (or is stuck partly open) keeps producing a torque although commanded off, and the
filter -- which knows u = 0 -- can only explain it as disturbance. Windows with control are left
out on purpose: there an efficiency error of the actuator (m_c wrong) also leaks into the
disturbance estimate and would be confused with the environment.

This module gives

* :func:`attitude_model` -- the seed-003 model measuring the angle, the angle and rate, or (to be
  refused) the rate only;
* :func:`require_observable` -- the Kalman rank test rank [H^T A^T H^T (A^T)^2 H^T] = n; an
  unobservable configuration is refused with a message naming the states that cannot be
  estimated;
* :class:`ActuatorMonitor` -- the streaming rule, one filter step at a time
  (``update(t, u, x_hat, P)`` returns an :class:`ActuatorEvent`, "switch to reserve", or None);
* :func:`monitor_record` -- the same monitor over a recorded forward pass;
* :func:`run_attitude` -- observability check, forward filter with the control input, monitor.

Windows (the "time base")
-------------------------
Step i belongs to a zero-control window when the control applied over the interval ending at
t_i is zero (|u_i| <= ``zero_tol`` for every input). A window opens at the first such step
(``settle_s`` after the last non-zero control), collects the disturbance estimates and their
variances, and closes once it spans ``window_s``; the next window opens at the next step. A step
with control discards the open window. A closed window is *evaluated* when the estimate is
precise enough for the threshold to be meaningful -- the root mean square of the estimate's
standard deviation over the window is at most ``threshold / k_sigma`` (right after start-up the
prior is far wider than the threshold); an evaluated window whose |mean| exceeds ``threshold``
raises the event. After an event the monitor is latched (the actuator set has been switched);
:meth:`ActuatorMonitor.reset` re-arms it.
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from .errors import CoreError
from .kalman import ForwardResult, GateConfig, run_forward
from .models import LinearModel, ObservabilityReport, attitude_axis

MEASUREMENTS = ("angle", "angle+rate", "rate")
#: tolerance of the window and settle-time comparisons: sample times such as k * 0.1 carry
#: rounding errors, and 5.0 - 3.0000000000000004 must count as 2 s
TIME_EPS = 1e-6
DISTURBANCE = "disturbance"


def attitude_model(measure: str = "angle", **params: float) -> LinearModel:
    """The attitude axis of seed 003 (:func:`~flight_fdi.core.models.attitude_axis`) measuring
    ``"angle"``, ``"angle+rate"`` (``sigma_rate`` default 1e-5 rad/s) or ``"rate"`` only.

    The rate-only configuration is built so that :func:`require_observable` can refuse it: with
    z = rate the angle never enters a measurement.
    """
    if measure not in MEASUREMENTS:
        raise CoreError(f"attitude measurement must be one of {', '.join(MEASUREMENTS)}, "
                        f"got {measure!r}")
    if measure == "angle":
        params.pop("sigma_rate", None)
        return attitude_axis(**params)
    params.setdefault("sigma_rate", 1e-5)
    both = attitude_axis(**params)
    if measure == "angle+rate":
        return both
    return LinearModel(both.name, both.state_names, both.state_units, both.A, both.Qc,
                       both.H[1:2], both.R[1:2, 1:2], both.P0, both.B, both.scale,
                       measurement_names=("rate",), params=dict(both.params))


def unobservable_states(model: LinearModel) -> list[str]:
    """States with a component in the null space of the observability matrix."""
    n = model.n
    O = np.vstack([model.H @ np.linalg.matrix_power(model.A, k) for k in range(n)])
    T = np.diag(model.scale)
    _, s, Vt = np.linalg.svd(O @ T)
    tol = max(O.shape) * np.finfo(float).eps * (s[0] if s.size else 0.0)
    null = Vt[int(np.sum(s > tol)):]
    if null.size == 0:
        return []
    weight = np.sum(null**2, axis=0)
    return [nm for nm, w in zip(model.state_names, weight) if w > 1e-6]


def require_observable(model: LinearModel, span_s: float) -> ObservabilityReport:
    """The Kalman rank test rank [H^T A^T H^T ... (A^T)^(n-1) H^T] = n (seed 003, SPEC section 7).

    Returns the observability report when the model is observable; raises CoreError naming the
    states that cannot be estimated otherwise.
    """
    if not isinstance(model, LinearModel):
        raise CoreError(f"expected a LinearModel, got {type(model).__name__}")
    rep = model.observability(span_s)
    if not rep.observable:
        lost = unobservable_states(model)
        raise CoreError(
            f"model {model.name!r} measuring {', '.join(model.measurement_names)} is not "
            f"observable: rank [H^T A^T H^T (A^T)^2 H^T] = {rep.rank} < n = {rep.n}; "
            f"{', '.join(lost) or 'some states'} cannot be estimated from these measurements "
            "(measure the angle: z = angle, or angle and rate). Refusing to run.")
    return rep


# --------------------------------------------------------------------------- the monitor

def _number(name: str, value: Any, positive: bool = True) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)) \
            or not math.isfinite(float(value)) or (value <= 0 if positive else value < 0):
        raise CoreError(f"ActuatorConfig.{name} must be a number {'> 0' if positive else '>= 0'}"
                        f", got {value!r}")
    return float(value)


@dataclass(frozen=True)
class ActuatorConfig:
    """The decision rule (see the module docstring).

    window_s: the time base, seconds of zero control per window.
    threshold: admissible |mean disturbance| per unit inertia, rad/s^2.
    zero_tol: |u| at or below this counts as zero control.
    settle_s: seconds after the last non-zero control before a window may open.
    k_sigma: a window is evaluated only when the rms standard deviation of the estimate over it
        is at most threshold / k_sigma.
    disturbance_state: name of the disturbance state in the model.
    """

    window_s: float = 5.0
    threshold: float = 1e-5
    zero_tol: float = 0.0
    settle_s: float = 0.0
    k_sigma: float = 3.0
    disturbance_state: str = DISTURBANCE

    def __post_init__(self) -> None:
        object.__setattr__(self, "window_s", _number("window_s", self.window_s))
        object.__setattr__(self, "threshold", _number("threshold", self.threshold))
        object.__setattr__(self, "zero_tol", _number("zero_tol", self.zero_tol, positive=False))
        object.__setattr__(self, "settle_s", _number("settle_s", self.settle_s, positive=False))
        object.__setattr__(self, "k_sigma", _number("k_sigma", self.k_sigma))
        if not isinstance(self.disturbance_state, str) or not self.disturbance_state:
            raise CoreError("ActuatorConfig.disturbance_state must be a state name")


@dataclass(frozen=True)
class WindowResult:
    """One closed zero-control window."""

    start_t: float
    end_t: float
    samples: int
    mean: float           # mean disturbance estimate over the window, rad/s^2
    std: float            # rms standard deviation of the estimate over the window
    evaluated: bool       # std <= threshold / k_sigma
    exceeded: bool        # evaluated and |mean| > threshold


@dataclass(frozen=True)
class ActuatorEvent:
    """An actuator fault: switch the axis to the reserve actuator set."""

    t: float              # time of the decision (end of the window)
    axis: str
    window_start_t: float
    window_end_t: float
    mean: float
    threshold: float
    std: float
    samples: int
    action: str = "switch_to_reserve"

    def as_dict(self) -> dict:
        return asdict(self)

    def message(self) -> str:
        return (f"actuator fault on axis {self.axis}: mean disturbance {self.mean:.3g} rad/s^2 "
                f"over {self.window_end_t - self.window_start_t:.1f} s of zero control "
                f"exceeds {self.threshold:.3g} -> switch to reserve")


class ActuatorMonitor:
    """The streaming decision rule for one axis (module docstring).

    ``update(t, u, x_hat, P)`` after each filter step: t the step's time (s, increasing), u the
    control applied over the interval ending at t (scalar or the model's p inputs), x_hat and P
    the filter's posterior. Returns an :class:`ActuatorEvent` once, at the window that decides
    the fault, else None. ``keep_windows=False`` keeps only the last closed window
    (``last_window``), for long-running nodes.
    """

    def __init__(self, model: LinearModel, config: ActuatorConfig = ActuatorConfig(),
                 axis: str = "x", keep_windows: bool = True, check_observable: bool = True
                 ) -> None:
        if not isinstance(config, ActuatorConfig):
            raise CoreError(f"config must be an ActuatorConfig, got {type(config).__name__}")
        if not isinstance(model, LinearModel):
            raise CoreError(f"model must be a LinearModel, got {type(model).__name__}")
        if model.B is None:
            raise CoreError(f"model {model.name!r} has no control input (B); the actuator monitor "
                            "needs a model with B")
        if check_observable:
            require_observable(model, config.window_s)
        self.model = model
        self.config = config
        self.axis = str(axis)
        self.index = model.index(config.disturbance_state)
        self.p = model.B.shape[1]
        self.keep_windows = bool(keep_windows)
        self.windows: list[WindowResult] = []
        self.last_window: WindowResult | None = None
        self.events: list[ActuatorEvent] = []
        self._last_t: float | None = None
        self.reset()

    def reset(self) -> None:
        """Re-arm the monitor (after the switch to the reserve) and drop the open window."""
        self.latched = False
        self._open = False
        self._start = 0.0
        self._sum = 0.0
        self._sum_var = 0.0
        self._count = 0
        self._control_t: float | None = None  # last time control was non-zero

    def _control_is_zero(self, u: Any) -> bool:
        if u is None:
            return True
        arr = np.asarray(u, dtype=float).reshape(-1)
        if arr.size != self.p or not np.all(np.isfinite(arr)):
            raise CoreError(f"actuator monitor: u must be {self.p} finite value(s), got {u!r}")
        return bool(np.all(np.abs(arr) <= self.config.zero_tol))

    def update(self, t: float, u: Any, x_hat: Any, P: Any) -> ActuatorEvent | None:
        t = float(t)
        if not math.isfinite(t):
            raise CoreError(f"actuator monitor: time must be finite, got {t!r}")
        if self._last_t is not None and t <= self._last_t:
            raise CoreError(f"actuator monitor: time must increase; {t!r} follows {self._last_t!r}")
        n, k = self.model.n, self.index
        x = np.asarray(x_hat, dtype=float).reshape(-1)
        Pm = np.asarray(P, dtype=float)
        if x.size != n or Pm.shape != (n, n):
            raise CoreError(f"actuator monitor: x_hat must have {n} values and P be {n} x {n}")
        d, var = float(x[k]), float(Pm[k, k])
        if not (math.isfinite(d) and math.isfinite(var) and var >= 0):
            raise CoreError(f"actuator monitor: the disturbance estimate or its variance at "
                            f"t = {t} is not finite / not >= 0")
        self._last_t = t
        cfg = self.config
        if not self._control_is_zero(u):
            self._control_t = t
            self._open = False
            return None
        if self._control_t is not None and t - self._control_t < cfg.settle_s - TIME_EPS:
            return None
        if not self._open:
            self._open, self._start, self._sum, self._sum_var, self._count = True, t, 0.0, 0.0, 0
        self._sum += d
        self._sum_var += var
        self._count += 1
        if t - self._start < cfg.window_s - TIME_EPS:
            return None
        mean = self._sum / self._count
        std = math.sqrt(self._sum_var / self._count)
        evaluated = std <= cfg.threshold / cfg.k_sigma
        exceeded = evaluated and abs(mean) > cfg.threshold
        win = WindowResult(self._start, t, self._count, mean, std, evaluated, exceeded)
        self._open = False
        self.last_window = win
        if self.keep_windows:
            self.windows.append(win)
        if exceeded and not self.latched:
            self.latched = True
            event = ActuatorEvent(t=t, axis=self.axis, window_start_t=win.start_t,
                                  window_end_t=t, mean=mean, threshold=cfg.threshold, std=std,
                                  samples=win.samples)
            self.events.append(event)
            return event
        return None


@dataclass
class MonitorResult:
    """The monitor over a record: its events (at most one: the monitor latches) and windows."""

    axis: str
    config: ActuatorConfig
    events: list[ActuatorEvent] = field(default_factory=list)
    windows: list[WindowResult] = field(default_factory=list)

    @property
    def fault(self) -> bool:
        return bool(self.events)

    def summary(self) -> dict:
        evaluated = [w for w in self.windows if w.evaluated]
        return {
            "axis": self.axis,
            "actuator_fault": self.fault,
            "events": [e.as_dict() for e in self.events],
            "windows": len(self.windows),
            "windows_evaluated": len(evaluated),
            "windows_exceeded": sum(w.exceeded for w in self.windows),
            "max_abs_mean": max((abs(w.mean) for w in evaluated), default=None),
            "config": asdict(self.config),
        }


def monitor_record(model: LinearModel, t: Any, u: Any, x: Any, P: Any,
                   config: ActuatorConfig = ActuatorConfig(), axis: str = "x") -> MonitorResult:
    """Run :class:`ActuatorMonitor` over a record: t (N,), u (N, p) or None (no control),
    x (N, n) posteriors, P (N, n, n)."""
    tt = np.asarray(t, dtype=float).reshape(-1)
    N = tt.size
    xa = np.asarray(x, dtype=float)
    Pa = np.asarray(P, dtype=float)
    n = model.n
    if xa.shape != (N, n) or Pa.shape != (N, n, n):
        raise CoreError(f"monitor_record: x must be ({N}, {n}) and P ({N}, {n}, {n})")
    ua = None
    if u is not None:
        ua = np.asarray(u, dtype=float).reshape(N, -1)
    mon = ActuatorMonitor(model, config, axis)
    for i in range(N):
        mon.update(tt[i], None if ua is None else ua[i], xa[i], Pa[i])
    return MonitorResult(axis=mon.axis, config=config, events=list(mon.events),
                         windows=list(mon.windows))


def run_attitude(model: LinearModel, t: Any, z: Any, u: Any, R: Any = None,
                 config: ActuatorConfig = ActuatorConfig(), axis: str = "x",
                 gate: GateConfig = GateConfig()) -> tuple[ForwardResult, MonitorResult]:
    """Observability check, the forward filter with the control input (u[k] = the control
    applied over the interval ending at t[k]), and the actuator monitor on its estimates."""
    tt = np.asarray(t, dtype=float).reshape(-1)
    span = float(tt[-1] - tt[0]) if tt.size > 1 else config.window_s
    require_observable(model, max(span, config.window_s))
    fwd = run_forward(model, tt, z, R, u=u, gate=gate)
    return fwd, monitor_record(model, fwd.t, fwd.u, fwd.x, fwd.P, config, axis)
