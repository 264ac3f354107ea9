"""Triple-redundant IMU voting with calibrated dynamic thresholds (seed 002, SPEC section 4).

Three co-mounted IMUs measure the same quantity j (gyro x/y/z, accel x/y/z) as P1, P2, P3.

* **Pairwise differences** ``x1 = P1 - P2``, ``x2 = P2 - P3``, ``x3 = P1 - P3``
  (:func:`pair_differences`).
* **Statistic**: the mean of the last N differences (:func:`window_means`). Before N samples
  have been seen the mean is over all samples so far (a growing window), so a vote is possible
  from the first sample; its spread is larger there, which the thresholds reflect.
* **Calibration** (offline, :func:`flight_fdi.core.voting_calib.calibrate`): at each time step of a
  Monte Carlo over nominal flights, the window means of each pair are tested for normality with the
  Kolmogorov-Smirnov test (:func:`ks_normal`, parameters by maximum likelihood). Normal: bounds
  mu +- z_(1-alpha/2) sigma; not normal: the empirical alpha/2 and 1-alpha/2 quantiles
  (:func:`bounds_from_samples`). The bound curves are cut into segments at the points of largest
  rate of change, each segment taking its max (upper) and min (lower) (:func:`segment_curve`). The
  result is a :class:`ThresholdTable`, saved as JSON (:func:`save_table`, schema in
  :data:`TABLE_FORMAT`'s docs below) and loaded by the voter (:func:`load_table`).
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
    model         optional (tables calibrated on recordings): the real-sensor model of
                  flight_fdi.core.voter_core.VoterModel -- prefilter, offset learning, time
                  offsets, mounting; the bounds then bound the deviation of the statistic from
                  each pair's learned nominal offset
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

import numpy as np

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
    #: the real-sensor model (prefilter, offsets, alignment, mounting; see
    #: flight_fdi.core.voter_core.VoterModel); empty: the seed's plain window means
    model: Mapping[str, Any] = field(default_factory=dict)

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
            **({"model": _plain(dict(self.model))} if self.model else {}),
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
        model = data.get("model") or {}
        if not isinstance(model, Mapping):
            raise CoreError("model must be an object")
        return ThresholdTable(tuple(quantities), window, rate, alpha, dur, entries, stats,
                              dict(data.get("calibration") or {}), dict(model))
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
