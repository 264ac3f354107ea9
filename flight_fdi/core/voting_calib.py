"""Threshold calibration of the triple-IMU voter (seed 002, SPEC section 4).

Kolmogorov-Smirnov test of normality of the window means (:func:`ks_normal`), normal or quantile
bounds (:func:`bounds_from_samples`), the seed's dynamic piecewise thresholds
(:func:`segment_curve`) and the Monte Carlo calibration (:func:`calibrate`) that gives a
:class:`~flight_fdi.core.voting.ThresholdTable`. Calibration from recorded flights is in
:mod:`flight_fdi.core.voter_real`.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.stats import kstwo, kstwobign, norm

from .errors import CoreError
from .voting import PAIRS, QUANTITIES, ThresholdTable


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
