"""Triple-redundant IMU voting with calibrated dynamic thresholds (seed 002, SPEC section 4).

Three co-mounted IMUs measure the same quantity j (gyro x/y/z, accel x/y/z) as P1, P2, P3.

* **Pairwise differences** ``x1 = P1 - P2``, ``x2 = P2 - P3``, ``x3 = P1 - P3``
  (:func:`pair_differences`).
* **Statistic**: the mean of the last N differences (:func:`window_means`). Before N samples
  have been seen the mean is over all samples so far (a growing window), so a vote is possible
  from the first sample; its spread is larger there, which the thresholds reflect.
* **Calibration** (offline, :func:`calibrate`): at each time step of a Monte Carlo over nominal
  flights, the window means of each pair are tested for normality with the Kolmogorov-Smirnov
  test (:func:`ks_normal`, parameters by maximum likelihood). Normal: bounds mu +- z_(1-alpha/2)
  sigma; not normal: the empirical alpha/2 and 1-alpha/2 quantiles (:func:`bounds_from_samples`).
  The bound curves are cut into segments at the points of largest rate of change, each segment
  taking its max (upper) and min (lower) (:func:`segment_curve`). The result is a
  :class:`ThresholdTable`, saved as JSON (:func:`save_table`, schema in :data:`TABLE_FORMAT`'s
  docs below) and loaded by the voter (:func:`load_table`).
* **Voting** (:func:`vote`): eps_k = 1 when x_k is inside its bounds.

  ======= ============================== ============ ===============
  sum     verdict                        faulty IMU   IMU to use
  ======= ============================== ============ ===============
  3       healthy                        none         IMU1
  2       healthy, marginal (warn)       none         IMU1
  1       single fault (majority):
            eps1 = 1                     IMU3         IMU1
            eps2 = 1                     IMU1         IMU2
            eps3 = 1                     IMU2         IMU1
  0       multiple fault                 unknown      (keep the last)
  ======= ============================== ============ ===============

Threshold table file (JSON, ``format: flight_fdi.voter_thresholds/1``)::

    format        "flight_fdi.voter_thresholds/1"
    quantities    ["gyro_x", ..., "accel_z"]       the quantities with thresholds
    pairs         ["x1", "x2", "x3"]              x1 = P1-P2, x2 = P2-P3, x3 = P1-P3
    units         {"gyro": "rad/s", "accel": "m/s^2"}   of the pair means and bounds
    window        N, samples of the window mean
    rate_hz       the IMU sample rate the table was calibrated for
    alpha         the confidence level 1 - alpha of the bounds
    duration_s    the calibrated flight time; later times use the last segment
    time_origin   "first matched sample": t = 0 at the first sample of the flight
    entries       {quantity: {pair: {"t_start": [...], "lower": [...], "upper": [...],
                                     "normal_fraction": f, "ks_pvalue_median": p}}}
                  segment i holds from t_start[i] to t_start[i+1] (the last to the end);
                  t_start[0] = 0
    calibration   free-form metadata (flights, seed, IMU parameters, profile ...)
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.stats import kstwo, kstwobign, norm

from .errors import CoreError

QUANTITIES = ("gyro_x", "gyro_y", "gyro_z", "accel_x", "accel_y", "accel_z")
PAIRS = ("x1", "x2", "x3")
#: (minuend, subtrahend) IMU index (0-based) of each pair
PAIR_IMUS = ((0, 1), (1, 2), (0, 2))
UNITS = {"gyro": "rad/s", "accel": "m/s^2"}
TABLE_FORMAT = "flight_fdi.voter_thresholds/1"
#: a flight time within this of a segment start counts as inside the segment (stamps are
#: integer nanoseconds; the table's times are float seconds)
TIME_TOL_S = 1e-6
#: bounds are inclusive and widened by this fraction of their magnitude: window means of pulse
#: outputs and quantile bounds both lie on the pulse lattice, so a mean equal to a bound must
#: not flip with the rounding of how it was summed (running sum vs cumulative sum)
BOUND_RTOL = 1e-9

# statuses, as in msg_defs/msg/VoteStatus.msg
HEALTHY = 0
MARGINAL = 1
SINGLE_FAULT = 2
MULTIPLE_FAULT = 3
STATUS_NAMES = {HEALTHY: "healthy", MARGINAL: "marginal", SINGLE_FAULT: "single fault",
                MULTIPLE_FAULT: "multiple fault"}


# --------------------------------------------------------------------------- statistics

def pair_differences(p: Any) -> np.ndarray:
    """x1 = P1 - P2, x2 = P2 - P3, x3 = P1 - P3 from ``p`` of shape (..., 3) (last axis: IMU)."""
    p = np.asarray(p, dtype=float)
    if p.shape[-1:] != (3,):
        raise CoreError(f"pair_differences: the last axis must hold the 3 IMUs, got shape "
                        f"{p.shape}")
    return np.stack([p[..., 0] - p[..., 1], p[..., 1] - p[..., 2], p[..., 0] - p[..., 2]],
                    axis=-1)


def window_means(x: Any, window: int, axis: int = 0) -> np.ndarray:
    """Mean of the last ``window`` samples along ``axis`` at every sample.

    Sample k averages x[max(0, k - window + 1) .. k] (a growing window until ``window`` samples
    exist). Computed from a cumulative sum, vectorised over all other axes.
    """
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window < 1:
        raise CoreError(f"window_means: the window must be an integer >= 1, got {window!r}")
    x = np.moveaxis(np.asarray(x, dtype=float), axis, 0)
    T = x.shape[0]
    c = np.cumsum(x, axis=0)
    out = np.empty_like(c)
    w = int(window)
    head = min(w, T)
    count = np.arange(1, head + 1, dtype=float).reshape((-1,) + (1,) * (x.ndim - 1))
    out[:head] = c[:head] / count
    if T > w:
        out[w:] = (c[w:] - c[:-w]) / w
    return np.moveaxis(out, 0, axis)


# --------------------------------------------------------------------------- voting

@dataclass(frozen=True)
class Vote:
    """The truth-table verdict for one quantity (see the module docstring)."""

    epsilon: tuple[int, int, int]
    total: int
    status: int
    faulty_imu: int     # 0 none / unknown, else 1..3
    use_imu: int        # 1..3, or 0 = keep the current selection (multiple fault)

    @property
    def status_name(self) -> str:
        return STATUS_NAMES[self.status]


def vote(eps1: int | bool, eps2: int | bool, eps3: int | bool) -> Vote:
    """The seed's truth table for one quantity (eps_k = 1: pair k inside its bounds)."""
    e = tuple(int(bool(v)) for v in (eps1, eps2, eps3))
    total = sum(e)
    if total == 3:
        return Vote(e, 3, HEALTHY, 0, 1)  # type: ignore[arg-type]
    if total == 2:
        return Vote(e, 2, MARGINAL, 0, 1)  # type: ignore[arg-type]
    if total == 1:
        if e[0]:       # only P1-P2 agree: IMU3 is faulty
            return Vote(e, 1, SINGLE_FAULT, 3, 1)  # type: ignore[arg-type]
        if e[1]:       # only P2-P3 agree: IMU1 is faulty
            return Vote(e, 1, SINGLE_FAULT, 1, 2)  # type: ignore[arg-type]
        return Vote(e, 1, SINGLE_FAULT, 2, 1)      # only P1-P3 agree: IMU2 is faulty
    return Vote(e, 0, MULTIPLE_FAULT, 0, 0)  # type: ignore[arg-type]


# status, faulty IMU and IMU to use for every eps pattern, indexed by 4 eps1 + 2 eps2 + eps3
_TABLE = np.array([[v.status, v.faulty_imu, v.use_imu]
                   for v in (vote(k >> 2 & 1, k >> 1 & 1, k & 1) for k in range(8))],
                  dtype=np.int8)


def vote_array(eps: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The truth table over arrays: ``eps`` (..., 3) bool -> (status, faulty_imu, use_imu),
    each of shape (...)."""
    e = np.asarray(eps, dtype=bool)
    if e.shape[-1:] != (3,):
        raise CoreError(f"vote_array: the last axis must hold eps1..eps3, got shape {e.shape}")
    code = 4 * e[..., 0] + 2 * e[..., 1] + e[..., 2]
    row = _TABLE[code]
    return row[..., 0], row[..., 1], row[..., 2]


def inside(x: Any, lower: Any, upper: Any) -> np.ndarray:
    """eps: x within [lower, upper] (NaN is outside)."""
    x = np.asarray(x, dtype=float)
    return (x >= lower) & (x <= upper)


# --------------------------------------------------------------------------- calibration

def ks_critical(ks_alpha: float, n: int) -> float:
    """The exact critical value of the KS statistic D_n at significance ``ks_alpha``."""
    return float(kstwo.isf(ks_alpha, n))


def ks_normal(samples: Any, axis: int = 0, exact_p: bool = False
              ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Kolmogorov-Smirnov test of normality along ``axis``, vectorised over the other axes.

    The normal's parameters are the maximum-likelihood estimates (mean, std with 1/n); with
    estimated parameters the test is conservative (Lilliefors). Returns (D statistic, p-value,
    mu, sigma). The p-value is exact (``scipy.stats.kstwo``, slow for many samples) when
    ``exact_p``, else Stephens' approximation Q_KS((sqrt(n) + 0.12 + 0.11 / sqrt(n)) D).
    Decisions should compare D with :func:`ks_critical` (exact). A sample with sigma = 0 gets
    D = 1, p = 0 (a point mass is not normal).
    """
    x = np.moveaxis(np.asarray(samples, dtype=float), axis, 0)
    n = x.shape[0]
    if n < 2:
        raise CoreError(f"ks_normal: need at least 2 samples, got {n}")
    if not np.all(np.isfinite(x)):
        raise CoreError("ks_normal: samples contain NaN or Inf")
    mu = x.mean(axis=0)
    sigma = x.std(axis=0)  # MLE (ddof = 0)
    degenerate = sigma <= 1e-300 + 1e-12 * np.abs(mu)
    safe = np.where(degenerate, 1.0, sigma)
    z = np.sort((x - mu) / safe, axis=0)
    F = norm.cdf(z)
    i = np.arange(1, n + 1, dtype=float).reshape((-1,) + (1,) * (x.ndim - 1))
    D = np.maximum((i / n - F).max(axis=0), (F - (i - 1) / n).max(axis=0))
    D = np.where(degenerate, 1.0, D)
    if exact_p:
        p = kstwo.sf(D, n)
    else:
        sn = math.sqrt(n)
        p = kstwobign.sf((sn + 0.12 + 0.11 / sn) * D)
    p = np.where(degenerate, 0.0, p)
    return D, p, mu, sigma


def bounds_from_samples(samples: Any, alpha: float, ks_alpha: float = 0.05, axis: int = 0,
                        method: str = "auto") -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                       np.ndarray]:
    """Confidence bounds of level 1 - alpha for the distribution of ``samples`` along ``axis``.

    ``method``: ``auto`` -- KS test; normal (D <= the exact critical value at ``ks_alpha``)
    -> mu +- z_(1-alpha/2) sigma (MLE),
    else the empirical alpha/2 and 1 - alpha/2 quantiles; ``normal`` or ``quantile`` force one.
    Returns (lower, upper, is_normal (bool), KS p-value (approximate, see :func:`ks_normal`)).
    """
    if not (isinstance(alpha, (int, float)) and 0.0 < alpha < 1.0):
        raise CoreError(f"alpha must be in (0, 1), got {alpha!r}")
    if not (isinstance(ks_alpha, (int, float)) and 0.0 < ks_alpha < 1.0):
        raise CoreError(f"ks_alpha must be in (0, 1), got {ks_alpha!r}")
    if method not in ("auto", "normal", "quantile"):
        raise CoreError(f"bounds method must be auto, normal or quantile, got {method!r}")
    x = np.moveaxis(np.asarray(samples, dtype=float), axis, 0)
    D, p, mu, sigma = ks_normal(x, axis=0)
    if method == "auto":
        is_normal = D <= ks_critical(ks_alpha, x.shape[0])
    else:
        is_normal = np.full(p.shape, method == "normal")
    z = norm.isf(alpha / 2.0)
    lo_n, up_n = mu - z * sigma, mu + z * sigma
    q = np.quantile(x, [alpha / 2.0, 1.0 - alpha / 2.0], axis=0)
    lower = np.where(is_normal, lo_n, q[0])
    upper = np.where(is_normal, up_n, q[1])
    return lower, upper, is_normal, p


def segment_curve(t: Any, lower: Any, upper: Any, n_segments: int,
                  min_segment_s: float = 0.0, smooth_s: float = 0.0,
                  forced_cuts: Sequence[float] = ()) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cut a threshold curve into at most ``n_segments`` pieces at its largest rates of change.

    The rate between grid points k and k+1 is max(|upper'|, |lower'|) (first differences over
    dt) of the curves after a centred moving average over ``smooth_s`` seconds (0: none). The
    smoothing keeps single-step flips of a quantized curve (window means of pulse outputs sit on
    a lattice, so the per-step quantiles jump by one lattice step back and forth) from taking
    the cuts that belong to sustained changes (the growing first window, maneuvers). The cut
    points are the largest rates, taken greedily so that no segment is shorter than
    ``min_segment_s``; a cut between k and k+1 starts a segment at t[k+1]. Each segment's bounds
    are the max of ``upper`` and the min of ``lower`` over its grid points (unsmoothed).
    ``forced_cuts``: times where a segment always starts (at the first grid point at or after
    each; they count towards ``n_segments``), e.g. the end of the first window, where the
    statistic changes from a growing to a sliding mean.
    Returns (t_start, lower, upper) per segment; t_start[0] = t[0].
    """
    t = np.asarray(t, dtype=float).reshape(-1)
    lo = np.asarray(lower, dtype=float).reshape(-1)
    up = np.asarray(upper, dtype=float).reshape(-1)
    if not (t.size == lo.size == up.size) or t.size == 0:
        raise CoreError("segment_curve: t, lower and upper must be non-empty and of equal size")
    if np.any(np.diff(t) <= 0):
        raise CoreError("segment_curve: t must increase")
    if isinstance(n_segments, bool) or not isinstance(n_segments, (int, np.integer)) \
            or n_segments < 1:
        raise CoreError(f"segment_curve: n_segments must be an integer >= 1, got {n_segments!r}")
    cuts: list[int] = []  # index of the first grid point of a new segment
    if not math.isfinite(smooth_s) or smooth_s < 0:
        raise CoreError(f"segment_curve: smooth_s must be >= 0, got {smooth_s!r}")
    for tc in sorted(float(v) for v in forced_cuts):
        k = int(np.searchsorted(t, tc, side="left"))
        if 0 < k < t.size and k not in cuts and len(cuts) < n_segments - 1:
            cuts.append(k)
    if t.size > 1 and n_segments > 1:
        dt = np.diff(t)
        width = int(round(smooth_s / float(np.median(dt)))) if smooth_s > 0 else 1
        su, sl = (_moving_average(c, width) for c in (up, lo))
        rate = np.maximum(np.abs(np.diff(su)), np.abs(np.diff(sl))) / dt
        order = np.argsort(-rate, kind="stable")
        edges = [t[0], t[-1] + (t[-1] - t[-2])] + [t[c] for c in cuts]  # boundaries in time
        for k in order:
            if len(cuts) == n_segments - 1 or rate[k] <= 0:
                break
            start = t[k + 1]
            if min(abs(start - e) for e in edges) < min_segment_s:
                continue
            cuts.append(int(k + 1))
            edges.append(start)
    bounds = [0] + sorted(cuts) + [t.size]
    t_start = t[bounds[:-1]]
    seg_lo = np.array([lo[a:b].min() for a, b in zip(bounds[:-1], bounds[1:])])
    seg_up = np.array([up[a:b].max() for a, b in zip(bounds[:-1], bounds[1:])])
    return t_start, seg_lo, seg_up


def _moving_average(x: np.ndarray, width: int) -> np.ndarray:
    """Centred moving average over ``width`` points (shorter at the ends)."""
    if width <= 1 or x.size < 2:
        return x
    c = np.concatenate([[0.0], np.cumsum(x)])
    k = np.arange(x.size)
    lo = np.clip(k - width // 2, 0, x.size)
    hi = np.clip(k - width // 2 + width, 0, x.size)
    return (c[hi] - c[lo]) / (hi - lo)


# --------------------------------------------------------------------------- the table

@dataclass(frozen=True, eq=False)
class ThresholdTable:
    """Piecewise-constant bounds per quantity x pair over flight time (see the module doc)."""

    quantities: tuple[str, ...]
    window: int
    rate_hz: float
    alpha: float
    duration_s: float
    #: entries[q][pair] = (t_start (k,), lower (k,), upper (k,))
    entries: Mapping[str, Mapping[str, tuple[np.ndarray, np.ndarray, np.ndarray]]]
    #: per quantity and pair: normal_fraction, ks_pvalue_median
    stats: Mapping[str, Mapping[str, Mapping[str, float]]] = field(default_factory=dict)
    calibration: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not self.quantities:
            raise CoreError("threshold table: no quantities")
        for q in self.quantities:
            if q not in QUANTITIES:
                raise CoreError(f"threshold table: unknown quantity {q!r}; quantities are "
                                f"{', '.join(QUANTITIES)}")
        if len(set(self.quantities)) != len(self.quantities):
            raise CoreError("threshold table: a quantity is listed twice")
        if isinstance(self.window, bool) or not isinstance(self.window, (int, np.integer)) \
                or self.window < 1:
            raise CoreError(f"threshold table: window must be an integer >= 1, got "
                            f"{self.window!r}")
        for nm in ("rate_hz", "duration_s"):
            v = getattr(self, nm)
            if not isinstance(v, (int, float)) or not math.isfinite(v) or v <= 0:
                raise CoreError(f"threshold table: {nm} must be a positive number, got {v!r}")
        if not isinstance(self.alpha, (int, float)) or not 0 < self.alpha < 1:
            raise CoreError(f"threshold table: alpha must be in (0, 1), got {self.alpha!r}")
        grid: set[float] = set()
        for q in self.quantities:
            if q not in self.entries:
                raise CoreError(f"threshold table: no entry for {q}")
            for pair in PAIRS:
                if pair not in self.entries[q]:
                    raise CoreError(f"threshold table: no entry for {q} {pair}")
                ts, lo, up = (np.asarray(a, dtype=float).reshape(-1)
                              for a in self.entries[q][pair])
                what = f"threshold table {q} {pair}"
                if ts.size == 0 or not (ts.size == lo.size == up.size):
                    raise CoreError(f"{what}: t_start, lower and upper must be non-empty lists "
                                    "of equal length")
                if not (np.all(np.isfinite(ts)) and np.all(np.isfinite(lo))
                        and np.all(np.isfinite(up))):
                    raise CoreError(f"{what}: contains NaN or Inf")
                if ts[0] != 0.0 or np.any(np.diff(ts) <= 0):
                    raise CoreError(f"{what}: t_start must start at 0 and increase")
                if np.any(lo > up):
                    raise CoreError(f"{what}: a lower bound exceeds its upper bound")
                grid.update(ts.tolist())
        # one merged grid for fast lookup: bounds (K, Q, 3) valid from grid[k], widened by
        # BOUND_RTOL
        g = np.array(sorted(grid))
        Q = len(self.quantities)
        L = np.empty((g.size, Q, 3))
        U = np.empty((g.size, Q, 3))
        for iq, q in enumerate(self.quantities):
            for ip, pair in enumerate(PAIRS):
                ts, lo, up = (np.asarray(a, dtype=float) for a in self.entries[q][pair])
                idx = np.searchsorted(ts, g, side="right") - 1
                L[:, iq, ip] = lo[idx]
                U[:, iq, ip] = up[idx]
        tol = BOUND_RTOL * 0.5 * (np.abs(L) + np.abs(U)) + 1e-300
        L, U = L - tol, U + tol
        for a in (g, L, U):
            a.setflags(write=False)
        object.__setattr__(self, "grid", g)
        object.__setattr__(self, "lower_grid", L)
        object.__setattr__(self, "upper_grid", U)

    grid: np.ndarray = field(init=False, repr=False)
    lower_grid: np.ndarray = field(init=False, repr=False)
    upper_grid: np.ndarray = field(init=False, repr=False)

    def segment_index(self, t: Any) -> np.ndarray:
        """Index into ``grid`` of the segment holding at flight time ``t`` (t < 0: the first;
        a time within TIME_TOL_S before a segment start counts as in that segment)."""
        idx = np.searchsorted(self.grid, np.asarray(t, dtype=float) + TIME_TOL_S,
                              side="right") - 1
        return np.clip(idx, 0, self.grid.size - 1)

    def bounds(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper), each (quantities, 3 pairs), at flight time ``t`` (widened by
        BOUND_RTOL: compare ``lower <= mean <= upper``)."""
        k = int(self.segment_index(t))
        return self.lower_grid[k], self.upper_grid[k]

    def bounds_at(self, t: Any) -> tuple[np.ndarray, np.ndarray]:
        """(lower, upper), each (T, quantities, 3), at the flight times ``t`` (T,)."""
        k = self.segment_index(np.asarray(t, dtype=float).reshape(-1))
        return self.lower_grid[k], self.upper_grid[k]

    def to_dict(self) -> dict[str, Any]:
        entries = {}
        for q in self.quantities:
            entries[q] = {}
            for pair in PAIRS:
                ts, lo, up = self.entries[q][pair]
                e = {"t_start": [float(v) for v in ts], "lower": [float(v) for v in lo],
                     "upper": [float(v) for v in up]}
                e.update({k: float(v) for k, v in self.stats.get(q, {}).get(pair, {}).items()})
                entries[q][pair] = e
        return {
            "format": TABLE_FORMAT,
            "quantities": list(self.quantities),
            "pairs": list(PAIRS),
            "pair_definition": {"x1": "P1 - P2", "x2": "P2 - P3", "x3": "P1 - P3"},
            "units": dict(UNITS),
            "window": int(self.window),
            "rate_hz": float(self.rate_hz),
            "alpha": float(self.alpha),
            "duration_s": float(self.duration_s),
            "time_origin": "first matched sample",
            "entries": entries,
            "calibration": _plain(dict(self.calibration)),
        }


def _plain(value: Any) -> Any:
    """JSON-compatible plain data."""
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, (np.integer,)):
        return int(value)
    if isinstance(value, (np.floating,)):
        return float(value)
    return value


def table_from_dict(data: Any, source: str = "threshold table") -> ThresholdTable:
    """Validate a parsed threshold-table document (see the module docstring)."""
    if not isinstance(data, Mapping):
        raise CoreError(f"{source}: not a threshold table (expected a JSON object)")
    if data.get("format") != TABLE_FORMAT:
        raise CoreError(f"{source}: not a threshold table (format {data.get('format')!r}, "
                        f"expected {TABLE_FORMAT!r}; write one with flight-fdi voter-calibrate)")
    for key in ("quantities", "window", "rate_hz", "alpha", "duration_s", "entries"):
        if key not in data:
            raise CoreError(f"{source}: missing key {key!r}")
    quantities = data["quantities"]
    if not isinstance(quantities, list) or not all(isinstance(q, str) for q in quantities):
        raise CoreError(f"{source}: 'quantities' must be a list of names")
    entries_in = data["entries"]
    if not isinstance(entries_in, Mapping):
        raise CoreError(f"{source}: 'entries' must be an object")
    entries: dict[str, dict[str, tuple]] = {}
    stats: dict[str, dict[str, dict[str, float]]] = {}
    for q in quantities:
        eq = entries_in.get(q)
        if not isinstance(eq, Mapping):
            raise CoreError(f"{source}: no entry for {q}")
        entries[q], stats[q] = {}, {}
        for pair in PAIRS:
            e = eq.get(pair)
            if not isinstance(e, Mapping) or not all(k in e for k in ("t_start", "lower",
                                                                         "upper")):
                raise CoreError(f"{source}: entry {q} {pair} needs t_start, lower and upper")
            try:
                arrs = tuple(np.array(e[k], dtype=float).reshape(-1)
                             for k in ("t_start", "lower", "upper"))
            except (TypeError, ValueError):
                raise CoreError(f"{source}: entry {q} {pair} holds non-numbers") from None
            entries[q][pair] = arrs
            stats[q][pair] = {k: float(v) for k, v in e.items()
                              if k not in ("t_start", "lower", "upper")
                              and isinstance(v, (int, float))}
    window = data["window"]
    if isinstance(window, float) and window.is_integer():
        window = int(window)
    try:
        rate, alpha, dur = float(data["rate_hz"]), float(data["alpha"]), float(data["duration_s"])
    except (TypeError, ValueError):
        raise CoreError(f"{source}: rate_hz, alpha and duration_s must be numbers") from None
    try:
        return ThresholdTable(tuple(quantities), window, rate, alpha, dur, entries, stats,
                              dict(data.get("calibration") or {}))
    except CoreError as exc:
        raise CoreError(f"{source}: {str(exc).removeprefix('threshold table: ')}") from None


def save_table(table: ThresholdTable, path: str | Path) -> None:
    """Write the table as JSON."""
    p = Path(path)
    try:
        p.write_text(json.dumps(table.to_dict(), indent=1) + "\n")
    except OSError as exc:
        raise CoreError(f"cannot write threshold table {p}: {exc.strerror or exc}") from None


def load_table(path: str | Path) -> ThresholdTable:
    """Read and validate a threshold table file; CoreError names the file and the problem."""
    p = Path(path)
    source = f"threshold table {p}"
    try:
        text = p.read_text()
    except FileNotFoundError:
        raise CoreError(f"{source}: file not found") from None
    except OSError as exc:
        raise CoreError(f"{source}: {exc.strerror or exc}") from None
    try:
        data = json.loads(text)
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise CoreError(f"{source}: not valid JSON ({exc})") from None
    return table_from_dict(data, source)


# --------------------------------------------------------------------------- calibration

@dataclass
class Calibration:
    """A calibration's table and its per-time-step curves (for plots and checks)."""

    table: ThresholdTable
    t: np.ndarray            # (T,) flight times of the evaluated grid
    lower: np.ndarray        # (T, Q, 3) per-step bounds before segmentation
    upper: np.ndarray
    is_normal: np.ndarray    # (T, Q, 3) KS verdict per step
    ks_pvalue: np.ndarray    # (T, Q, 3)


def calibrate(means: Any, t: Any, alpha: float, window: int, rate_hz: float,
              quantities: Sequence[str] = QUANTITIES, ks_alpha: float = 0.05,
              n_segments: int = 12, min_segment_s: float = 0.0, smooth_s: float = 0.0,
              cut_at_window: bool = True, method: str = "auto",
              duration_s: float | None = None,
              calibration: Mapping[str, Any] | None = None) -> Calibration:
    """Threshold table from Monte Carlo window means.

    ``means``: (flights, T, Q, 3) window means of the pair differences of nominal flights at
    the flight times ``t`` (T,) (a subsample of the IMU samples is fine); ``window`` and
    ``rate_hz`` are recorded in the table (the voter must use the same). Per time step:
    :func:`bounds_from_samples`; per quantity and pair: :func:`segment_curve` (with a forced
    cut at the end of the first window when ``cut_at_window``).
    """
    m = np.asarray(means, dtype=float)
    t = np.asarray(t, dtype=float).reshape(-1)
    quantities = tuple(quantities)
    if m.ndim != 4 or m.shape[1] != t.size or m.shape[2] != len(quantities) or m.shape[3] != 3:
        raise CoreError(f"calibrate: means must have shape (flights, {t.size}, "
                        f"{len(quantities)}, 3), got {m.shape}")
    if m.shape[0] < 10:
        raise CoreError(f"calibrate: {m.shape[0]} flights are too few (need >= 10)")
    if t[0] != 0.0:
        raise CoreError("calibrate: the time grid must start at 0 (the first sample)")
    lower, upper, is_normal, p = bounds_from_samples(m, alpha, ks_alpha, axis=0, method=method)
    forced = (window / rate_hz,) if cut_at_window else ()
    entries: dict[str, dict[str, tuple]] = {}
    stats: dict[str, dict[str, dict[str, float]]] = {}
    for iq, q in enumerate(quantities):
        entries[q], stats[q] = {}, {}
        for ip, pair in enumerate(PAIRS):
            entries[q][pair] = segment_curve(t, lower[:, iq, ip], upper[:, iq, ip], n_segments,
                                             min_segment_s, smooth_s, forced)
            stats[q][pair] = {"normal_fraction": float(is_normal[:, iq, ip].mean()),
                              "ks_pvalue_median": float(np.median(p[:, iq, ip]))}
    dur = float(duration_s) if duration_s is not None else float(t[-1] + 1.0 / rate_hz)
    meta = dict(calibration or {})
    meta.update({"flights": int(m.shape[0]), "ks_alpha": ks_alpha, "n_segments": n_segments,
                 "min_segment_s": min_segment_s, "smooth_s": smooth_s,
                 "cut_at_window": cut_at_window, "method": method,
                 "grid_step_s": float(t[1] - t[0]) if t.size > 1 else 0.0})
    table = ThresholdTable(quantities, int(window), float(rate_hz), float(alpha), dur, entries,
                           stats, meta)
    return Calibration(table, t, lower, upper, is_normal, p)
