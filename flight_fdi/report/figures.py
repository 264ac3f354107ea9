"""PNG figures of one analysed flight (matplotlib, Agg canvas; no pyplot, no global backend).

* :func:`element_figure` -- per state element, like figures 7.2 / 7.3 of seed 000: the true error
  (when known), the filtered estimate x(i/i) and the smoothed estimate x(i/N); the chi-square term
  J(i/k) of the element with its bound gamma_k^2; the Fisher statistic F_k with eta^2.
* :func:`gate_figure` -- the innovation with +-3 sqrt(S), beta^2 with the gate and the alarms.
* :func:`chi2_figure` -- the total J with gamma^2 and the violation episode.
* :func:`glr_figure` -- the GLR statistic over the onset time per hypothesis, with its threshold.

Every function takes the core's :class:`~flight_fdi.core.analysis.AnalysisResult` and writes one
PNG; times on the x axes are seconds from the analysis' ``t0``.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from flight_fdi.core.models import (ATTITUDE_STATES, ATTITUDE_UNITS, DEG_PER_HOUR, INS_STATES,
                                    INS_UNITS)
from flight_fdi.eval.errors import EvalError

from .canvas import canvas, maxpool, save, stride

FLOOR = 1e-3  # lower limit of the logarithmic statistic axes

#: display unit per (state element, SI unit): (label, factor from SI); others are shown in SI
DISPLAY_UNITS = {("gyro_drift", "rad/s"): ("deg/h", 1.0 / DEG_PER_HOUR),
                 ("tilt", "rad"): ("mrad", 1e3)}
#: SI units of the built-in models' states, for results that do not carry their model
KNOWN_UNITS = dict(zip(INS_STATES, INS_UNITS)) | dict(zip(ATTITUDE_STATES, ATTITUDE_UNITS))


@dataclass
class Truth:
    """The true error state of a simulated flight, in the time base of the analysis (the same
    seconds as ``AnalysisResult.fwd.t``)."""

    t: np.ndarray                 # (K,)
    x: np.ndarray                 # (K, n)
    state_names: tuple[str, ...]

    def __post_init__(self) -> None:
        self.t = np.asarray(self.t, dtype=float).reshape(-1)
        self.x = np.asarray(self.x, dtype=float)
        if self.x.ndim != 2 or self.x.shape[0] != self.t.size:
            raise EvalError(f"truth: x must be ({self.t.size}, n), got {self.x.shape}")
        self.state_names = tuple(self.state_names)
        if len(self.state_names) != self.x.shape[1]:
            raise EvalError(f"truth: {self.x.shape[1]} states but {len(self.state_names)} names")

    def series(self, name: str) -> np.ndarray | None:
        if name not in self.state_names:
            return None
        return self.x[:, self.state_names.index(name)]


def _log_positive(y: np.ndarray) -> np.ndarray:
    y = np.asarray(y, dtype=float)
    return np.where(np.isfinite(y), np.maximum(y, FLOOR), np.nan)


#: colours: thresholds are red, onsets black; hypotheses by sensor (never the thresholds' red)
THRESHOLD_COLOR, ONSET_COLOR = "tab:red", "black"
SENSOR_COLORS = {"accelerometer": "tab:blue", "gyro": "tab:green", "reference": "tab:purple"}
KIND_STYLES = {"step": "-", "ramp": "--", "jump": "-", "outliers": ":"}
FALLBACK_COLORS = ("tab:brown", "tab:pink", "tab:olive", "tab:cyan", "tab:gray")
#: an alarm span is drawn at least this fraction of the time axis wide (0.2 s at flight scale
#: would be invisible), with a marker at its start
MIN_SPAN_FRACTION = 0.004


def _onset_line(ax: Any, onset_s: float | None, label: str | None = None) -> None:
    if onset_s is not None:
        ax.axvline(onset_s, color=ONSET_COLOR, ls="--", lw=1, label=label)


def exceed_intervals(t: np.ndarray, over: np.ndarray) -> list[tuple[float, float]]:
    """(first, last) time of every run of consecutive True in ``over``."""
    over = np.asarray(over, dtype=bool)
    if not over.any():
        return []
    edges = np.diff(np.concatenate([[0], over.astype(np.int8), [0]]))
    starts, ends = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1
    return [(float(t[a]), float(t[b])) for a, b in zip(starts, ends)]


def _exceed_spans(ax: Any, t: np.ndarray, y: np.ndarray, bound: np.ndarray, label: str) -> None:
    """Shade exactly the times where y > bound (no shading elsewhere)."""
    over = np.isfinite(y) & np.isfinite(bound) & (y > bound)
    _spans(ax, exceed_intervals(t, over), float(t[-1] - t[0]) if t.size else 1.0, label,
           markers=False)


def _spans(ax: Any, spans: list[tuple[float, float]], t_range: float, label: str,
           markers: bool = True) -> None:
    """Spans, each at least MIN_SPAN_FRACTION of the axis wide, a marker at each start."""
    width = MIN_SPAN_FRACTION * max(t_range, 1e-9)
    for i, (a, b) in enumerate(spans):
        mid, half = 0.5 * (a + b), max(0.5 * (b - a), 0.5 * width)
        ax.axvspan(mid - half, mid + half, color="tab:orange", alpha=0.45, lw=0,
                   label=label if i == 0 else None)
    if spans and markers:
        ax.plot([a for a, _ in spans], [1.0] * len(spans), "v", color="tab:orange", ms=7,
                transform=ax.get_xaxis_transform(), clip_on=False,
                label=f"alarm start ({len(spans)})")


def hypothesis_style(name: str, index: int = 0) -> dict:
    """Colour and line style of a GLR hypothesis: by sensor, dashed for ramps."""
    from flight_fdi.core.glr import kind_of, sensor_of

    color = SENSOR_COLORS.get(sensor_of(name) or "",
                              FALLBACK_COLORS[index % len(FALLBACK_COLORS)])
    if name in ("reference_outlier",) or name.startswith("outlier:"):
        color = "tab:brown"
    return {"color": color, "ls": KIND_STYLES.get(kind_of(name) or "step", "-")}


def _unit(name: str, unit: str) -> tuple[str, float]:
    return DISPLAY_UNITS.get((name, unit), (unit, 1.0))


def state_names(result: Any) -> list[str]:
    """The state element names of an analysis result."""
    return [e.name for e in result.seed.elements]


def state_units(result: Any, model: Any = None) -> list[str]:
    """SI units of the states: the model's when given, else those of the built-in models."""
    if model is not None:
        return list(model.state_units)
    return [KNOWN_UNITS.get(nm, "") for nm in state_names(result)]


def element_figure(result: Any, k: int, path: Path, truth: Truth | None = None,
                   model: Any = None) -> Path:
    """Figure of state element ``k`` (seed 000, figures 7.2 / 7.3)."""
    name = state_names(result)[k]
    unit, factor = _unit(name, state_units(result, model)[k])
    t0 = result.t0
    fwd, bwd, seed = result.fwd, result.bwd, result.seed
    t = np.asarray(fwd.t) - t0
    onset = result.summary["post_flight"]["onset_s"]
    fig, (ax1, ax2, ax3) = canvas(3, f"{name}: error, filtered and smoothed estimates; "
                                      "chi-square and Fisher tests")
    ts, xf, xs, sf = stride(t, fwd.x[:, k] * factor, bwd.x_s[:, k] * factor,
                             np.sqrt(np.maximum(fwd.P[:, k, k], 0.0)) * factor)
    if truth is not None and truth.series(name) is not None:
        tt, xt = stride(truth.t - t0, truth.series(name) * factor)
        ax1.plot(tt, xt, color="black", lw=1.5, label="true error")
    ax1.plot(ts, xf, color="tab:blue", lw=1, label="filtered x(i/i)")
    ax1.fill_between(ts, xf - sf, xf + sf, color="tab:blue", alpha=0.15, lw=0,
                     label="filtered +-1 sigma")
    ax1.plot(ts, xs, color="tab:orange", lw=1.2, label="smoothed x(i/N)")
    _onset_line(ax1, onset, label="isolated onset")
    ax1.set_ylabel(f"{name} [{unit}]")
    ax1.legend(loc="best", fontsize=8)
    ax1.grid(True, alpha=0.3)

    valid = np.asarray(seed.valid, dtype=bool)
    term = np.where(valid, seed.terms[:, k], np.nan)
    tj, jk = maxpool(t, term)
    _, gk = stride(t, np.where(valid, seed.gammas[:, k], np.nan))
    ax2.plot(tj, _log_positive(jk), color="tab:green", lw=1, label=f"J(i/{k + 1}) (chi-square)")
    ax2.plot(stride(t)[0], gk, color=THRESHOLD_COLOR, lw=1,
             label=f"gamma_{k + 1}^2 = k + 3 sqrt(2k) (effective dof)")
    _onset_line(ax2, onset, label="isolated onset")
    ax2.set_yscale("log")
    ax2.set_ylabel("chi-square term [-]")
    ax2.legend(loc="best", fontsize=8)
    ax2.grid(True, which="both", alpha=0.3)

    F = np.where(valid, seed.F[:, k], np.nan)
    tf, fk = maxpool(t, F)
    ax3.plot(tf, _log_positive(fk), color="tab:purple", lw=1,
             label=f"F_{k + 1} (Fisher, window {seed.config.fisher_window})")
    ax3.axhline(seed.eta2, color=THRESHOLD_COLOR, lw=1, label=f"eta^2 = {seed.eta2:.3g}")
    _onset_line(ax3, onset, label="isolated onset")
    if not np.any(np.isfinite(F)):
        ax3.text(0.5, 0.6, "F not defined: the backward filter has no information on this "
                 "element", transform=ax3.transAxes, ha="center", color="tab:gray")
    ax3.set_yscale("log")
    ax3.set_ylabel("variance ratio F [-]")
    ax3.set_xlabel("time [s]")
    ax3.legend(loc="best", fontsize=8)
    ax3.grid(True, which="both", alpha=0.3)
    return save(fig, path)


def gate_figure(result: Any, path: Path, unit: str = "m/s") -> Path:
    """The innovation (in ``unit``, the measurement's) with +-3 sqrt(S) and beta^2 with the
    gate and the alarm episodes (drawn at least MIN_SPAN_FRACTION wide)."""
    fwd = result.fwd
    t = np.asarray(fwd.t) - result.t0
    fig, (ax1, ax2) = canvas(2, "in flight: innovation and the beta^2 gate")
    nu = fwd.nu[:, 0]
    s3 = 3.0 * np.sqrt(np.maximum(fwd.S[:, 0, 0], 0.0))
    ts, nus, s3s = stride(t, nu, s3)
    ax1.plot(ts, nus, color="tab:blue", lw=0.6, label="innovation nu")
    # both bounds as one labelled line (a NaN between them breaks it)
    ax1.plot(np.concatenate([ts, [np.nan], ts]), np.concatenate([s3s, [np.nan], -s3s]),
             color=THRESHOLD_COLOR, lw=1, label="+-3 sqrt(S)")
    ax1.set_ylabel(f"innovation nu [{unit}]")
    ax1.legend(loc="best", fontsize=8)
    ax1.grid(True, alpha=0.3)

    tb, b2 = maxpool(t, np.asarray(fwd.beta2, dtype=float))
    ax2.plot(tb, _log_positive(b2), color="tab:blue", lw=0.6, label="beta^2 = nu^2 / S")
    ax2.axhline(float(fwd.threshold[0]), color=THRESHOLD_COLOR, lw=1,
                label=f"gate {float(fwd.threshold[0]):.3g}")
    spans = [(a["start_s"] - result.t0, a["end_s"] - result.t0) for a in fwd.alarms()]
    _spans(ax2, spans, float(t[-1] - t[0]) if t.size else 1.0, "alarm (M of N)")
    ax2.set_yscale("log")
    ax2.set_ylabel("beta^2 [-]")
    ax2.set_xlabel("time [s]")
    ax2.legend(loc="best", fontsize=8)
    ax2.grid(True, which="both", alpha=0.3)
    return save(fig, path)


def chi2_figure(result: Any, path: Path) -> Path:
    """The total two-filter statistic J with gamma^2 (7.12-7.14); shaded exactly where J
    exceeds gamma^2, the seed method's onset (J peak of its episode) as a labelled line."""
    seed = result.seed
    t = np.asarray(seed.t) - result.t0
    valid = np.asarray(seed.valid, dtype=bool)
    fig, (ax,) = canvas(1, "post flight: chi-square statistic J of the two-filter residual")
    tj, J = maxpool(t, np.where(valid, seed.J, np.nan))
    ax.plot(tj, _log_positive(J), color="tab:green", lw=1, label="J(i)")
    ts, g = stride(t, np.where(valid, seed.gamma2, np.nan))
    ax.plot(ts, g, color=THRESHOLD_COLOR, lw=1, label="gamma^2 = n + 3 sqrt(2n)")
    _exceed_spans(ax, t, np.where(valid, seed.J, np.nan), np.where(valid, seed.gamma2, np.nan),
                  "J > gamma^2 (before a step too: the backward filter carries it)")
    _onset_line(ax, None if seed.onset_t is None else seed.onset_t - result.t0,
                label=f"seed onset: J peak ({seed.verdict}, {seed.element})")
    glr = result.glr
    if glr.detected and glr.onset_t is not None:
        ax.axvline(glr.onset_t - result.t0, color="tab:gray", ls=":", lw=1.5,
                   label=f"GLR onset ({glr.hypothesis}, {glr.isolation})")
    ax.set_yscale("log")
    ax.set_ylabel("J [-] (chi-square)")
    ax.set_xlabel("time [s]")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return save(fig, path)


def glr_figure(result: Any, path: Path) -> Path:
    """The GLR statistic l(theta, h) over the onset theta for every hypothesis h."""
    glr = result.glr
    fig, (ax,) = canvas(1, "post flight: GLR statistic over the onset time")
    for i, (h, (tc, lc)) in enumerate(glr.curves.items()):
        tc = np.asarray(tc, dtype=float) - result.t0
        ax.plot(tc, _log_positive(lc), lw=1, label=h, **hypothesis_style(h, i))
    ax.axhline(glr.threshold, color=THRESHOLD_COLOR, lw=1, ls="-.",
               label=f"threshold {glr.threshold:.3g}")
    if glr.detected and glr.onset_t is not None:
        ax.plot([glr.onset_t - result.t0], [glr.statistic], "kv", ms=8,
                label=f"best: {glr.hypothesis} ({glr.isolation})")
    ax.set_yscale("log")
    ax.set_ylabel("l(theta) [-] (2 log-likelihood ratio)")
    ax.set_xlabel("onset time theta [s]")
    ax.legend(loc="best", fontsize=8)
    ax.grid(True, which="both", alpha=0.3)
    return save(fig, path)

