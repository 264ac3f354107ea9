"""Threshold calibration of the triple-IMU voter from recorded nominal flights of real IMUs.

The seed calibrates on a Monte Carlo of one trajectory; real recordings are few, of different
lengths and trajectories, and their units disagree by offsets that change from day to day. So:

1. per recording, the time offsets of IMU2 and IMU3 are estimated over the learning phase
   (:func:`flight_fdi.core.voter_align.estimate_time_offsets`), and with them the mounting maps
   are estimated over all recordings together
   (:func:`~flight_fdi.core.voter_align.estimate_mounting`);
   With ``linear`` (>= 3 recordings) the per-pair linear model (lever arm, scale factor:
   :mod:`flight_fdi.core.voter_linear`) is fitted on the aligned, mounting-corrected recordings
   and kept for the quantities where it lowers the held-out residual;
2. every recording is run through the voter's own statistic (:class:`VoterCore`: alignment,
   prefilter, window mean, the per-unit offset learnt in the first ``learn_s`` seconds as the
   median of ``offset_blocks`` block means), which gives the deviation of each pair from its
   learnt offset at every sample after the learning;
3. the seed's procedure on those deviations: the flight time is cut into bins of ``bin_s``; the
   deviations of all recordings in a bin are the sample of that time step (the recordings play the
   part of the seed's Monte Carlo flights, the samples of a bin widen the sample); per bin and
   pair the Kolmogorov-Smirnov test decides between normal bounds mu +- z sigma and the alpha/2,
   1 - alpha/2 quantiles; the bound curves are cut into segments at their largest rates of change
   (:func:`~flight_fdi.core.voting_calib.segment_curve`); bins held by fewer than
   ``min_recordings`` recordings end the curve (the last segment then holds);
4. with ``symmetric`` each bound becomes +- the larger of the two (a set of recordings may drift
   one way; another day's may drift the other), and the bounds are multiplied by ``margin``
   (>= 1; recordings of other days spread more than the calibration set: a margin chosen on
   held-out days, docs/voter_real.md).

5. with ``sequential`` ({quantity: drift nu}) the same pass runs the CUSUM of each pair
   (:mod:`flight_fdi.core.voter_sequential`) without alarms; its thresholds are
   ``sequential_margin`` x the largest statistic of the recordings.

The result is a :class:`~flight_fdi.core.voting.ThresholdTable` with a ``model`` section
(:class:`~flight_fdi.core.voter_core.VoterModel`) that ``flight-fdi vote`` and ``voter_node`` use.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .errors import CoreError
from . import voter_linear, voter_sequential
from .voter_align import align_times, correct_mounting, estimate_mounting, \
    estimate_time_offsets, mounting_summary
from .voter_core import VoterCore, VoterModel
from .voting import PAIRS, QUANTITIES, ThresholdTable
from .voting_calib import bounds_from_samples, segment_curve

_WIDE = 1e6


def open_table(quantities: Sequence[str], window: int, rate_hz: float, model: VoterModel
               ) -> ThresholdTable:
    """A table whose bounds never trip (for computing deviations)."""
    e = (np.zeros(1), np.full(1, -_WIDE), np.full(1, _WIDE))
    entries = {q: {p: e for p in PAIRS} for q in quantities}
    return ThresholdTable(tuple(quantities), int(window), float(rate_hz), 0.5, 1.0, entries,
                          model=model.to_dict())


def deviations(stamp_ns: Any, P: Any, model: VoterModel, window: int, rate_hz: float,
               quantities: Sequence[str] = QUANTITIES) -> tuple[np.ndarray, np.ndarray,
                                                              VoterCore]:
    """(t (m,), deviation (m, Q, 3), the core) of one recording: the voted statistic after the
    learning phase."""
    core = VoterCore(open_table(quantities, window, rate_hz, model), model=model)
    parts = [core.push(stamp_ns, P), core.finish()]
    t = np.concatenate([d.t_flight for d in parts])
    dev = np.concatenate([d.deviation for d in parts])
    return t, dev, core


def calibrate_recordings(recordings: Sequence[tuple[Any, Any]], alpha: float, rate_hz: float,
                         window: int = 600, prefilter: int = 12, learn_s: float = 5.0,
                         track_tau_s: float = 0.0, max_lag_s: float = 0.2,
                         estimate_mount: bool = True, bin_s: float = 1.0, margin: float = 1.0,
                         ks_alpha: float = 0.05, method: str = "auto", n_segments: int = 8,
                         min_segment_s: float = 2.0, min_recordings: int = 5,
                         quantities: Sequence[str] = QUANTITIES, names: Sequence[str] = (),
                         symmetric: bool = True, baseline: str = "learn",
                         linear: bool = True, offset_blocks: int = 5,
                         sequential: dict[str, float] | None = None,
                         sequential_margin: float = 1.5) -> tuple[ThresholdTable, dict[str, Any]]:
    """Threshold table from nominal recordings ``[(stamp_ns (T,), P (T, 6, 3)), ...]``."""
    if len(recordings) < 2:
        raise CoreError(f"calibration needs at least 2 recordings, got {len(recordings)}")
    if not margin >= 1.0:
        raise CoreError(f"margin must be >= 1, got {margin!r}")
    if learn_s <= 0:
        raise CoreError("calibration from recordings needs a learning phase (learn_s > 0)")
    names = list(names) or [f"recording {i + 1}" for i in range(len(recordings))]
    taus, aligned = _aligned(recordings, names, rate_hz, learn_s, max_lag_s, prefilter)
    mounting = estimate_mounting(aligned, rate_hz) if estimate_mount else None
    lin, lin_report = None, {}
    if linear and len(recordings) < 3:
        lin_report = {"skipped": "fewer than 3 recordings"}
    elif linear:
        lin, lin_report = voter_linear.fit([correct_mounting(A, mounting) for A in aligned],
                                           rate_hz, quantities)
    model = VoterModel.from_dict({"prefilter": prefilter, "learn_s": learn_s,
                                  "track_tau_s": track_tau_s, "time_offsets_s": None,
                                  "max_lag_s": max_lag_s, "mounting": mounting,
                                  "baseline": baseline, "linear": lin,
                                  "offset_blocks": offset_blocks,
                                  "sequential": voter_sequential.open_section(sequential)
                                  if sequential else None}, "calibration")
    series, offsets, peaks = [], [], []
    for ns, P in recordings:
        t, dev, core = deviations(ns, P, model, window, rate_hz, quantities)
        series.append((t, dev))
        offsets.append(core.offset)
        if core.cusum is not None:
            peaks.append(core.cusum.peak.reshape(len(quantities), 3))
    if sequential:     # the CUSUM thresholds from the same nominal recordings
        hours = sum(float(t[-1] - t[0]) for t, _ in series if t.size) / 3600.0
        model = VoterModel.from_dict({**model.to_dict(), "sequential": voter_sequential.thresholds(
            peaks, quantities, sequential, sequential_margin, hours)}, "calibration")
    t_bins, lo, up, normal, pval = _binned_bounds(series, alpha, learn_s, bin_s, ks_alpha,
                                                  method, min_recordings)
    entries: dict[str, dict[str, tuple]] = {}
    stats: dict[str, dict[str, dict[str, float]]] = {}
    for iq, q in enumerate(quantities):
        entries[q], stats[q] = {}, {}
        for ip, pair in enumerate(PAIRS):
            ts, l, u = segment_curve(t_bins, lo[:, iq, ip], up[:, iq, ip], n_segments,
                                     min_segment_s, 0.0, (learn_s,))
            if symmetric:   # other days' deviations are not skewed like this set's
                u = np.maximum(np.abs(l), np.abs(u))
                l = -u
            entries[q][pair] = (ts, margin * np.minimum(l, 0.0), margin * np.maximum(u, 0.0))
            stats[q][pair] = {"normal_fraction": float(normal[1:, iq, ip].mean()),
                              "ks_pvalue_median": float(np.median(pval[1:, iq, ip]))}
    off = np.array(offsets)
    meta = {"source": "recordings", "recordings": names, "margin": margin, "bin_s": bin_s,
            "ks_alpha": ks_alpha, "method": method, "n_segments": n_segments,
            "min_recordings": min_recordings,
            "time_offsets_s": {n: np.round(tau, 5).tolist() for n, tau in zip(names, taus)},
            "mounting": mounting_summary(mounting), "linear": lin_report,
            "sequential": model.sequential,
            "offsets": {"mean": off.mean(axis=0), "min": off.min(axis=0),
                        "max": off.max(axis=0)}}
    table = ThresholdTable(tuple(quantities), int(window), float(rate_hz), float(alpha),
                           float(t_bins[-1] + bin_s), entries, stats, meta, model.to_dict())
    return table, meta


def _aligned(recordings, names, rate_hz, learn_s, max_lag_s, prefilter):
    """Per recording: the time offsets estimated over the learning phase, and the recording
    moved onto IMU1's time with them."""
    taus, aligned = [], []
    for (ns, P), name in zip(recordings, names):
        P = np.asarray(P, dtype=float)
        t = (np.asarray(ns) - ns[0]) * 1e-9
        n = int(np.searchsorted(t, learn_s))
        try:
            tau, _ = estimate_time_offsets(P[:n], rate_hz, max_lag_s, prefilter)
        except CoreError as exc:
            raise CoreError(f"{name}: {exc}") from None
        taus.append(tau)
        aligned.append(align_times(P, tau, rate_hz))
    return taus, aligned


def _binned_bounds(series, alpha, learn_s, bin_s, ks_alpha, method, min_recordings):
    """Per flight-time bin: pooled deviations -> bounds (the seed's per-step statistics)."""
    t_end = sorted((t[-1] for t, _ in series if t.size), reverse=True)
    if len(t_end) < min_recordings:
        raise CoreError(f"calibration: {len(t_end)} recordings last beyond the learning phase; "
                        f"need at least {min_recordings}")
    horizon = t_end[min_recordings - 1]
    starts = np.arange(learn_s, max(horizon, learn_s + bin_s), bin_s)
    rows = []
    for b0 in starts:
        pooled = np.concatenate([dev[(t >= b0 - 1e-9) & (t < b0 + bin_s - 1e-9)]
                                 for t, dev in series])
        if pooled.shape[0] < 10:
            break
        rows.append(bounds_from_samples(pooled, alpha, ks_alpha, axis=0, method=method))
    if not rows:
        raise CoreError("calibration: no flight-time bin holds 10 samples after the learning")
    lo, up, normal, p = (np.array([r[i] for r in rows]) for i in range(4))
    t_bins = np.concatenate([[0.0], starts[:len(rows)]])
    # the learning phase (no decisions) takes the first bin's bounds
    lo, up, normal, p = (np.concatenate([a[:1], a]) for a in (lo, up, normal, p))
    return t_bins, lo, up, normal, p
