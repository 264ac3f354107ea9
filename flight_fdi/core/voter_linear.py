"""Per-pair linear calibration of the voter's pair differences on real units (lever arm, scale).

Co-mounted units at different points of a rotating body do not measure the same specific force:
unit k at r_k sees f + w_dot x r_k + w x (w x r_k), so a pair difference holds
w_dot x (r_j - r_k) + w x (w x (r_j - r_k)) -- linear in the six products w_i w_j and in w_dot --
and scale-factor / misalignment differences left after the mounting maps add M f. Per quantity
and pair the model is

    d ~ b + Phi B,   Phi = (wx^2, wy^2, wz^2, wx wy, wx wz, wy wz, w_dot x, y, z, f x, y, z)

with w, f the mean of the three aligned units and w_dot a backward difference. The constant b is
the voter's offset (learnt in flight); B (12 x 3 per quantity) is fitted here by ridge least
squares on 1-s window means of calibration recordings (each recording's means removed), and kept
only for the quantities where it lowers the residual of recordings it was not fitted on
(leave-one-recording-out within the calibration set): on the Xsens DOT recordings the
accelerometers x/y gain, the gyros do not (docs/voter_real.md).
"""
from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from .errors import CoreError
from .voting import QUANTITIES, window_means

FEATURES = ("wx2", "wy2", "wz2", "wxwy", "wxwz", "wywz", "dwx", "dwy", "dwz", "fx", "fy", "fz")


def features(A: np.ndarray, rate_hz: float, w_prev: np.ndarray | None = None) -> np.ndarray:
    """Phi (m, 12) of aligned triples ``A`` (m, 6, 3); ``w_prev`` (3,): the mean rate of the
    sample before ``A[0]`` (None: w_dot 0 at the first sample)."""
    w, f = A[:, 0:3, :].mean(axis=-1), A[:, 3:6, :].mean(axis=-1)
    before = w[:1] if w_prev is None else np.asarray(w_prev, dtype=float).reshape(1, 3)
    dw = np.diff(np.concatenate([before, w]), axis=0) * rate_hz
    prod = np.stack([w[:, 0] ** 2, w[:, 1] ** 2, w[:, 2] ** 2, w[:, 0] * w[:, 1],
                     w[:, 0] * w[:, 2], w[:, 1] * w[:, 2]], axis=1)
    return np.concatenate([prod, dw, f], axis=1)


def pair_diffs(A: np.ndarray) -> np.ndarray:
    """x1 = P1 - P2, x2 = P2 - P3, x3 = P1 - P3 of ``A`` (m, Q, 3)."""
    return np.stack([A[..., 0] - A[..., 1], A[..., 1] - A[..., 2], A[..., 0] - A[..., 2]],
                    axis=-1)


def apply(d: np.ndarray, Phi: np.ndarray, coef: Mapping[str, Any],
          quantities: Sequence[str]) -> np.ndarray:
    """Pair differences ``d`` (m, Q, 3) minus Phi B of the quantities that have a B."""
    out = d.copy()
    for i, q in enumerate(quantities):
        if q in coef:
            out[:, i, :] -= Phi @ np.asarray(coef[q], dtype=float)
    return out


def check(linear: Any, source: str) -> dict[str, Any] | None:
    """Validate a model's ``linear`` section ({"features": [...], "coef": {quantity: 12x3}})."""
    if linear is None:
        return None
    if not isinstance(linear, dict) or list(linear.get("features", [])) != list(FEATURES) \
            or not isinstance(linear.get("coef"), dict):
        raise CoreError(f"{source}: linear must hold features {list(FEATURES)} and coef")
    coef = {}
    for q, B in linear["coef"].items():
        try:
            B = np.asarray(B, dtype=float)
        except (TypeError, ValueError):
            raise CoreError(f"{source}: linear coef {q} holds non-numbers") from None
        if q not in QUANTITIES or B.shape != (len(FEATURES), 3) or not np.all(np.isfinite(B)):
            raise CoreError(f"{source}: linear coef {q!r} must be a finite "
                            f"{len(FEATURES)}x3 matrix of a quantity")
        coef[q] = B.tolist()
    return {"features": list(FEATURES), "coef": coef}


def _means(A: np.ndarray, rate_hz: float, w: int) -> tuple[np.ndarray, np.ndarray]:
    """1-s window means (every w/4 samples, recording means removed) of d (n, 6, 3), Phi."""
    d, Phi = pair_diffs(A), features(A, rate_hz)
    step = max(1, w // 4)
    dm = window_means(d, w, axis=0)[w - 1::step]
    Pm = window_means(Phi, w, axis=0)[w - 1::step]
    return dm - dm.mean(axis=0), Pm - Pm.mean(axis=0)


def _ridge(X: np.ndarray, Y: np.ndarray, ridge: float) -> np.ndarray:
    s = X.std(axis=0) + 1e-300                  # scale-free ridge on standardised columns
    Xs = X / s
    B = np.linalg.solve(Xs.T @ Xs + ridge * X.shape[0] * np.eye(X.shape[1]), Xs.T @ Y)
    return B / s[:, None]


def _five_s_var(r: np.ndarray, n: int) -> float:
    """Variance of the 5-s means (n consecutive 1-s means apart by w/4) of residuals r."""
    if r.shape[0] <= n:
        return float(np.sum(r.mean(axis=0) ** 2))
    m = window_means(r, n, axis=0)[n - 1:]
    return float(np.sum(np.var(m, axis=0)))


def fit(recordings: Sequence[np.ndarray], rate_hz: float, quantities: Sequence[str],
        ridge: float = 1e-3, min_gain: float = 0.1
        ) -> tuple[dict[str, Any] | None, dict[str, dict[str, float]]]:
    """(linear section or None, report) from aligned, mounting-corrected recordings (T, 6, 3).

    Per quantity: leave-one-recording-out, the variance of 5-s means of the residual with and
    without the model; B fitted on all recordings is kept when the held-out variance falls by
    at least ``min_gain`` (a fraction). The report gives both residual standard deviations."""
    w = max(2, int(round(rate_hz)))
    parts = [_means(np.asarray(A, dtype=float), rate_hz, w) for A in recordings
             if np.asarray(A).shape[0] >= 3 * w]
    if len(parts) < 3:
        raise CoreError("linear calibration needs at least 3 recordings of 3 s or more")
    coef, report = {}, {}
    for q in quantities:
        iq = QUANTITIES.index(q)
        before = after = 0.0
        for k, (dm, Pm) in enumerate(parts):
            X = np.vstack([p[1] for j, p in enumerate(parts) if j != k])
            Y = np.vstack([p[0][:, iq, :] for j, p in enumerate(parts) if j != k])
            B = _ridge(X, Y, ridge)
            before += _five_s_var(dm[:, iq, :], 20)
            after += _five_s_var(dm[:, iq, :] - Pm @ B, 20)
        report[q] = {"held_out_std_before": float(np.sqrt(before / len(parts) / 3)),
                     "held_out_std_after": float(np.sqrt(after / len(parts) / 3))}
        if after <= (1.0 - min_gain) * before:
            X = np.vstack([p[1] for p in parts])
            Y = np.vstack([p[0][:, iq, :] for p in parts])
            coef[q] = _ridge(X, Y, ridge).tolist()
    return ({"features": list(FEATURES), "coef": coef} if coef else None), report
