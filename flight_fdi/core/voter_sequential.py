"""The voter's sequential detector: a CUSUM per quantity and pair on the residual after the
offset (and linear) model -- an option of the voter core (``model.sequential``).

A bias step of a real unit is persistent; the units' nominal disagreement is partly
high-frequency (vibration, bias wander on seconds). The seed's statistic compares one window
mean with a bound; Page's two-sided CUSUM accumulates the residual

    e_t = (prefiltered pair difference - linear model)_t - b      (b: the learnt offset)

as g+_t = max(0, g+_(t-1) + (e_t - nu) dt) (and g- for -e_t), in the residual's unit x s, so a
step delta > nu raises g by (delta - nu) per second until g > h, while zero-mean noise and
wander below nu are forgotten (:func:`flight_fdi.core.voter_kernel.cusum`). A pair whose g+ or
g- exceeds h is "outside" in the vote, in addition to the window bounds; the seed's truth table
and the persistence then name the IMU.

Parameters per quantity: the drift nu (half the smallest step of interest, the textbook
choice; given to the calibration) and per quantity and pair the threshold h, calibrated on the
nominal recordings (:func:`thresholds`): h = margin x the largest g of the calibration
recordings after the learning. The calibration set's duration is stored with it: no alarm in
those hours at h / margin, i.e. an empirical false-alarm rate below one per that many hours
(docs/voter_real.md measures it on held-out days).

Table section: ``{"drift": {quantity: nu}, "threshold": {quantity: [h_x1, h_x2, h_x3]},
"margin": m, "calibration_hours": H}``.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .errors import CoreError
from .voter_kernel import cusum

#: threshold of the calibration pass (no alarm): larger than any real g
OPEN = 1e30


def check(section: Any, source: str) -> dict[str, Any] | None:
    """Validate a ``sequential`` section; CoreError naming what is wrong."""
    if section is None:
        return None
    if not isinstance(section, Mapping) or not isinstance(section.get("drift"), Mapping):
        raise CoreError(f"{source}: sequential must hold drift {{quantity: value}} and "
                        "threshold {quantity: [3 values]}")
    drift, thr = section["drift"], section.get("threshold") or {}
    if not isinstance(thr, Mapping):
        raise CoreError(f"{source}: sequential threshold must map quantities to 3 values")
    out_d, out_h = {}, {}
    for q, v in drift.items():
        if isinstance(v, bool) or not isinstance(v, (int, float)) or not (
                math.isfinite(v) and v >= 0):
            raise CoreError(f"{source}: sequential drift of {q} must be a number >= 0")
        out_d[str(q)] = float(v)
    for q, h in thr.items():
        try:
            h = np.asarray(h, dtype=float)
        except (TypeError, ValueError):
            raise CoreError(f"{source}: sequential threshold of {q} holds non-numbers") from None
        if h.shape != (3,) or not np.all(h > 0) or np.any(np.isnan(h)):
            raise CoreError(f"{source}: sequential threshold of {q} must be 3 values > 0")
        if str(q) not in out_d:
            raise CoreError(f"{source}: sequential threshold of {q} has no drift")
        out_h[str(q)] = h.tolist()
    rest = {k: v for k, v in section.items() if k not in ("drift", "threshold")}
    return {"drift": out_d, "threshold": out_h, **rest}


class Cusum:
    """The CUSUM state of one flight for the quantities of a table (columns quantity x pair);
    quantities without a drift are never flagged."""

    def __init__(self, section: Mapping[str, Any], quantities: Sequence[str], rate_hz: float
                 ) -> None:
        Q = len(quantities)
        self.dt = 1.0 / float(rate_hz)
        self.drift = np.zeros(Q * 3)
        self.h = np.full(Q * 3, np.inf)
        for i, q in enumerate(quantities):
            if q in section["drift"]:
                self.drift[3 * i:3 * i + 3] = section["drift"][q]
                self.h[3 * i:3 * i + 3] = section["threshold"].get(q, [OPEN] * 3)
        self.g_pos, self.g_neg = np.zeros(Q * 3), np.zeros(Q * 3)
        self.peak = np.zeros(Q * 3)
        self.shape = (Q, 3)

    def step(self, e: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Residuals (m, Q, 3) -> (signed g (m, Q, 3), inside (m, Q, 3))."""
        m = e.shape[0]
        g, inside = cusum(np.ascontiguousarray(e.reshape(m, -1), dtype=float), self.drift,
                          self.h, self.dt, self.g_pos, self.g_neg, self.peak)
        return g.reshape((m,) + self.shape), inside.reshape((m,) + self.shape)


def open_section(drift: Mapping[str, float]) -> dict[str, Any]:
    """The section of the calibration pass: the drifts, no alarm."""
    return {"drift": {q: float(v) for q, v in drift.items()},
            "threshold": {q: [OPEN] * 3 for q in drift}}


def thresholds(peaks: Sequence[np.ndarray], quantities: Sequence[str],
               drift: Mapping[str, float], margin: float, hours: float) -> dict[str, Any]:
    """The section from the largest g per recording (each (Q, 3)): h = margin x the largest
    over the recordings (and at least a tiny positive value)."""
    if not margin >= 1.0:
        raise CoreError(f"sequential margin must be >= 1, got {margin!r}")
    top = np.max(np.stack([np.asarray(p, dtype=float) for p in peaks]), axis=0)
    thr = {q: np.maximum(margin * top[i], 1e-12).tolist()
           for i, q in enumerate(quantities) if q in drift}
    return {"drift": {q: float(drift[q]) for q in thr}, "threshold": thr,
            "margin": float(margin), "calibration_hours": round(float(hours), 4)}
