"""Alignment of three co-mounted real IMUs before voting: time offsets and mounting.

Real units are not hardware-synchronised and not perfectly co-aligned (the Xsens DOT recordings of
``../shared/data/mimu_quadrotor``: 0-100 ms between units, ~1-2 deg between their axes). On a
maneuvering vehicle both turn the rates into pair differences far larger than a sensor fault: a
delay tau gives tau * (rate change over the window) / W in the window mean, a tilt theta gives
theta * (mean cross-axis rate).

Layout: ``P`` is (T, 6, 3): samples x quantities (gyro x/y/z [rad/s], accel x/y/z [m/s^2], the
order of :data:`flight_fdi.core.voting.QUANTITIES`) x IMUs (IMU1..IMU3), one row per matched
triple at the sample rate.

* :func:`estimate_time_offsets`: cross-correlation of the smoothed gyro vectors of IMU1 and IMU k
  over lags +- ``max_lag_s`` on a 0.01-sample grid (band-limited interpolation of the
  correlation through its spectrum, exact for whole-sample shifts). tau_k > 0: IMU k's
  sample of an instant comes tau_k after IMU1's.
* :func:`delay`: IMU k's value at sample index n + tau_k (linear interpolation; clamped at the
  ends), i.e. IMU k moved onto IMU1's time.
* :func:`estimate_mounting`: per IMU k and sensor group (gyro, accel) the 3x3 map M_k with
  p_k ~ M_k p_1 + b_k, least squares on 1-s window means of the centred signals of one or more
  recordings (window means, not samples: the vibration of the samples would bias a regression on
  noisy regressors towards zero). :func:`correct_mounting` applies M_k^-1 to IMU k;
  :func:`mounting_summary` reports the small rotation angles and scale-factor differences.
"""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .errors import CoreError
from .voting import window_means

GROUPS = {"gyro": slice(0, 3), "accel": slice(3, 6)}


def _check_p(P: Any) -> np.ndarray:
    P = np.asarray(P, dtype=float)
    if P.ndim != 3 or P.shape[1:] != (6, 3):
        raise CoreError(f"IMU triples must have shape (T, 6 quantities, 3 IMUs), got {P.shape}")
    return P


def estimate_time_offsets(P: Any, rate_hz: float, max_lag_s: float = 0.2,
                          smooth: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """(tau (3,) in seconds, tau[0] = 0; peak correlation (3,)) of IMU2 and IMU3 against IMU1.

    The gyro vectors are smoothed with a ``smooth``-sample moving average (vibration near the
    Nyquist frequency is not common to the units), centred, and correlated at lags within
    +- ``max_lag_s`` on a 0.01-sample grid (the correlation of IMU1's interior -- all but
    max_lag_s at each end -- with IMU k, evaluated from the cross-spectrum of the zero-padded
    signals, so a whole-sample shift of IMU k moves the estimate by exactly that shift). Needs at
    least 4 max lags of data."""
    P = _check_p(P)
    L = max(1, int(round(max_lag_s * rate_hz)))
    T = P.shape[0]
    if T < 4 * L + 2:
        raise CoreError(f"time offset estimate: {T} samples are too few for lags of +-{L} "
                        f"samples (need {4 * L + 2})")
    g = window_means(P[:, 0:3, :], max(1, int(smooth)), axis=0)
    g = g - g.mean(axis=0)
    tau = np.zeros(3)
    peak = np.ones(3)
    a = np.zeros_like(g[:, :, 0])
    a[L:T - L] = g[L:T - L, :, 0]    # IMU1's interior: every lag sees whole IMU k data
    nfft = 2 * g.shape[0]
    X = np.fft.rfft(a, n=nfft, axis=0)
    k = np.arange(X.shape[0])
    w = np.full(k.size, 2.0)
    w[0] = w[-1] = 1.0               # nfft even: the zero and Nyquist bins once
    e1 = np.sum(a ** 2)
    for j in (1, 2):
        S = w * np.sum(np.conj(X) * np.fft.rfft(g[:, :, j], n=nfft, axis=0), axis=1)
        coarse = np.fft.irfft(S / w, n=nfft)                # integer lags
        ints = np.r_[coarse[:L + 1], coarse[-L:]]
        il = np.r_[np.arange(L + 1), np.arange(-L, 0)]
        l0 = il[int(np.argmax(ints))]
        lags = l0 + np.arange(-1.0, 1.0 + 1e-9, 0.01)   # refined on a 0.01-sample grid
        c = (np.exp(2j * np.pi * np.outer(lags, k) / nfft) @ S).real / nfft
        i = int(np.argmax(c))
        tau[j] = float(np.clip(lags[i], -L, L)) / rate_hz
        ej = np.sum(g[L:T - L, :, j] ** 2)
        peak[j] = float(c[i] / np.sqrt(e1 * ej)) if e1 > 0 and ej > 0 else 0.0
    return tau, peak


def delay(values: Any, shift_samples: float, index: Any = None) -> np.ndarray:
    """``values`` (T, ...) at sample positions ``index + shift_samples`` (default index 0..T-1),
    by linear interpolation between samples, clamped to the first / last sample."""
    v = np.asarray(values, dtype=float)
    n = np.arange(v.shape[0], dtype=float)
    at = (n if index is None else np.asarray(index, dtype=float)) + float(shift_samples)
    if shift_samples == 0 and index is None:
        return v.copy()
    flat = v.reshape(v.shape[0], -1)
    out = np.empty((at.size, flat.shape[1]))
    for j in range(flat.shape[1]):
        out[:, j] = np.interp(at, n, flat[:, j])
    return out.reshape((at.size,) + v.shape[1:])


def align_times(P: Any, tau_s: Sequence[float], rate_hz: float) -> np.ndarray:
    """IMU2 and IMU3 of ``P`` moved onto IMU1's time (see :func:`delay`)."""
    P = _check_p(P)
    out = P.copy()
    for k in (1, 2):
        if tau_s[k]:
            out[:, :, k] = delay(P[:, :, k], tau_s[k] * rate_hz)
    return out


def estimate_mounting(recordings: Sequence[Any], rate_hz: float, window_s: float = 1.0
                      ) -> dict[str, list[list[list[float]]]]:
    """The 3x3 maps M_k (p_k ~ M_k p_1 + b_k) of IMU2 and IMU3, per group (gyro, accel), by least
    squares over the time-aligned ``recordings`` (each (T, 6, 3)); each recording's own means
    are removed (its offsets b_k). Returns {"gyro": [M_2, M_3], "accel": [M_2, M_3]}."""
    w = max(1, int(round(window_s * rate_hz)))
    step = max(1, w // 4)
    xs: dict[str, list] = {g: [] for g in GROUPS}
    ys: dict[str, dict[int, list]] = {g: {1: [], 2: []} for g in GROUPS}
    for P in recordings:
        P = _check_p(P)
        if P.shape[0] < 2 * w:
            continue
        m = window_means(P, w, axis=0)[w - 1::step]
        m = m - m.mean(axis=0)
        for g, sl in GROUPS.items():
            xs[g].append(m[:, sl, 0])
            for k in (1, 2):
                ys[g][k].append(m[:, sl, k])
    if not xs["gyro"]:
        raise CoreError(f"mounting estimate: no recording is longer than {2 * w} samples")
    out: dict[str, list] = {}
    for g in GROUPS:
        X = np.vstack(xs[g])
        maps = []
        for k in (1, 2):
            Y = np.vstack(ys[g][k])
            B, *_ = np.linalg.lstsq(X, Y, rcond=None)
            maps.append(B.T.tolist())
        out[g] = maps
    return out


def correct_mounting(P: Any, mounting: dict[str, Any] | None) -> np.ndarray:
    """IMU2 and IMU3 of ``P`` mapped into IMU1's axes: p_k' = M_k^-1 p_k (per group)."""
    P = np.asarray(P, dtype=float)
    if not mounting:
        return P
    out = P.copy()
    for g, sl in GROUPS.items():
        maps = mounting.get(g)
        if maps is None:
            continue
        for k in (1, 2):
            Minv = np.linalg.inv(np.asarray(maps[k - 1], dtype=float))
            out[..., sl, k] = P[..., sl, k] @ Minv.T
    return out


def check_mounting(mounting: Any, source: str) -> dict[str, Any] | None:
    """Validate a mounting document ({group: [M_2, M_3]}, 3x3, invertible); CoreError if not."""
    if mounting is None:
        return None
    if not isinstance(mounting, dict) or set(mounting) - set(GROUPS):
        raise CoreError(f"{source}: mounting must map gyro / accel to two 3x3 matrices")
    for g, maps in mounting.items():
        try:
            arr = np.asarray(maps, dtype=float)
        except (TypeError, ValueError):
            raise CoreError(f"{source}: mounting {g} holds non-numbers") from None
        if arr.shape != (2, 3, 3) or not np.all(np.isfinite(arr)):
            raise CoreError(f"{source}: mounting {g} must be two finite 3x3 matrices")
        if np.any(np.abs(np.linalg.det(arr)) < 0.5):
            raise CoreError(f"{source}: mounting {g} is not close to a rotation (det < 0.5)")
    return {g: np.asarray(m, dtype=float).tolist() for g, m in mounting.items()}


def mounting_summary(mounting: dict[str, Any] | None) -> dict[str, Any]:
    """Per IMU k and group: small rotation angles (deg, about x/y/z, from the antisymmetric part
    of M_k) and scale-factor differences (%, diagonal of M_k - I)."""
    out: dict[str, Any] = {}
    for g, maps in (mounting or {}).items():
        for k, M in zip((2, 3), maps):
            A = np.asarray(M, dtype=float) - np.eye(3)
            ang = 0.5 * np.array([A[2, 1] - A[1, 2], A[0, 2] - A[2, 0], A[1, 0] - A[0, 1]])
            out[f"imu{k}_{g}"] = {"rotation_deg": np.degrees(ang).round(3).tolist(),
                                  "scale_pct": (100 * np.diag(A)).round(3).tolist()}
    return out
