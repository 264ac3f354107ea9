"""Input checks of the forward filter: CoreError with a message naming the bad value, so that a
caller (a node, the CLI) can refuse it and keep its state."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import CoreError
from .gate import is_int
from .models import LinearModel


def failed_rows(rows: Any, m: int) -> tuple[int, ...]:
    """Sorted unique failed row indices in 0..m-1 (CoreError otherwise)."""
    out = set()
    for r in np.asarray(rows, dtype=object).reshape(-1).tolist() if rows is not None else ():
        if not is_int(r) or not 0 <= r < m:
            raise CoreError(f"failed row {r!r} is not a row index in 0..{m - 1}")
        out.add(int(r))
    return tuple(sorted(out))


def anomaly_covariance(Gamma: Any, r: int) -> np.ndarray:
    """Gamma as an r x r matrix: a number (the same variance for every failed row), r
    variances, or an r x r covariance; variances must be > 0."""
    if Gamma is None:
        raise CoreError("known_anomaly mode: Gamma (the anomaly variance) is required")
    try:
        G = np.asarray(Gamma, dtype=float)
    except (TypeError, ValueError):
        raise CoreError(f"Gamma is not numeric: {Gamma!r}") from None
    if G.ndim == 0:
        G = np.full(r, float(G))
    if G.ndim == 1:
        if G.shape != (r,):
            raise CoreError(f"Gamma must give {r} variances (one per failed row), got {G.size}")
        G = np.diag(G)
    if G.shape != (r, r) or not np.all(np.isfinite(G)):
        raise CoreError(f"Gamma must be a finite {r} x {r} matrix, got shape {G.shape}")
    if np.any(np.diag(G) <= 0) or not np.allclose(G, G.T, rtol=1e-9, atol=0.0):
        raise CoreError("Gamma must be symmetric with positive variances")
    return G


def check_dt(dt: Any) -> float:
    try:
        dt = float(dt)
    except (TypeError, ValueError):
        raise CoreError(f"dt must be a number, got {dt!r}") from None
    if not math.isfinite(dt):
        raise CoreError(f"dt must be finite, got {dt!r}")
    if dt < 0:
        raise CoreError(f"dt must be >= 0, got {dt!r}")
    return dt


def check_z(z: Any, m: int) -> np.ndarray:
    try:
        arr = np.asarray(z, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CoreError(f"measurement z is not numeric: {z!r}") from None
    if arr.shape != (m,):
        raise CoreError(f"measurement z must have {m} values, got {arr.size}")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"measurement z contains NaN or Inf: {arr.tolist()}")
    return arr


def check_R(R: Any, m: int) -> np.ndarray:
    try:
        arr = np.asarray(R, dtype=float)
    except (TypeError, ValueError):
        raise CoreError("measurement covariance R is not numeric") from None
    if arr.size == m * m:
        arr = arr.reshape(m, m)
    if arr.shape != (m, m):
        raise CoreError(f"measurement covariance R must be {m}x{m}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CoreError("measurement covariance R contains NaN or Inf")
    if m == 1:
        if arr[0, 0] < 0:
            raise CoreError(f"measurement covariance R = {arr[0, 0]:.3g} is negative")
        return arr
    if not np.allclose(arr, arr.T, rtol=1e-9, atol=0.0):
        raise CoreError("measurement covariance R is not symmetric")
    eig = np.linalg.eigvalsh(arr)
    if eig[0] < -1e-12 * max(abs(eig[-1]), 1e-300):
        raise CoreError(f"measurement covariance R is not positive semidefinite "
                        f"(smallest eigenvalue {eig[0]:.3g})")
    return 0.5 * (arr + arr.T)


def check_R_batch(R: np.ndarray, N: int, m: int) -> np.ndarray:
    if R.shape != (N, m, m):
        raise CoreError(f"R must have shape ({N}, {m}, {m}), got {R.shape}")
    bad = ~np.all(np.isfinite(R.reshape(N, -1)), axis=1)
    if np.any(bad):
        raise CoreError(f"R contains NaN or Inf at {int(bad.sum())} steps (first at index "
                        f"{int(np.argmax(bad))})")
    if m == 1:
        neg = R[:, 0, 0] < 0
        if np.any(neg):
            raise CoreError(f"R is negative at {int(neg.sum())} steps (first at index "
                            f"{int(np.argmax(neg))})")
        return R
    asym = ~np.all(np.isclose(R, np.swapaxes(R, 1, 2), rtol=1e-9, atol=0.0).reshape(N, -1), axis=1)
    if np.any(asym):
        raise CoreError(f"R is not symmetric at index {int(np.argmax(asym))}")
    eig = np.linalg.eigvalsh(R)
    neg = eig[:, 0] < -1e-12 * np.maximum(np.abs(eig[:, -1]), 1e-300)
    if np.any(neg):
        raise CoreError(f"R is not positive semidefinite at index {int(np.argmax(neg))}")
    return 0.5 * (R + np.swapaxes(R, 1, 2))


def check_prior(model: LinearModel, x0: Any, P0: Any) -> tuple[np.ndarray, np.ndarray]:
    n = model.n
    if x0 is None:
        x = np.zeros(n)
    else:
        x = np.asarray(x0, dtype=float).reshape(-1)
        if x.shape != (n,) or not np.all(np.isfinite(x)):
            raise CoreError(f"x0 must be {n} finite numbers")
    if P0 is None:
        P = np.array(model.P0, dtype=float)
    else:
        P = np.asarray(P0, dtype=float)
        if P.shape != (n, n) or not np.all(np.isfinite(P)):
            raise CoreError(f"P0 must be a finite {n}x{n} matrix")
        if not np.allclose(P, P.T, rtol=1e-9, atol=0.0):
            raise CoreError("P0 is not symmetric")
        Ps = P / np.outer(model.scale, model.scale)
        eig = np.linalg.eigvalsh(0.5 * (Ps + Ps.T))
        if eig[0] < -1e-12 * max(abs(eig[-1]), 1e-300):
            raise CoreError(f"P0 is not positive semidefinite (smallest scaled eigenvalue "
                            f"{eig[0]:.3g})")
        P = 0.5 * (P + P.T)
    return x, P


def check_u(model: LinearModel, u: Any, what: str = "u") -> np.ndarray | None:
    if u is None:
        return None
    if model.B is None:
        raise CoreError(f"model {model.name!r} has no input matrix B; a control input {what} "
                        "was given")
    p = model.B.shape[1]
    arr = np.asarray(u, dtype=float).reshape(-1)
    if arr.shape != (p,) or not np.all(np.isfinite(arr)):
        raise CoreError(f"control input {what} must be {p} finite numbers")
    return arr


def check_u_batch(model: LinearModel, u: Any, N: int) -> np.ndarray | None:
    if u is None:
        return None
    if model.B is None:
        raise CoreError(f"model {model.name!r} has no input matrix B; a control input u was given")
    p = model.B.shape[1]
    arr = np.asarray(u, dtype=float)
    if arr.size == N * p:
        arr = arr.reshape(N, p)
    if arr.shape != (N, p) or not np.all(np.isfinite(arr)):
        raise CoreError(f"control input u must be ({N}, {p}) and finite")
    return arr


def check_times(t: Any, what: str = "t") -> np.ndarray:
    """A 1-D array of finite, strictly increasing times (CoreError otherwise)."""
    try:
        arr = np.asarray(t, dtype=float).reshape(-1)
    except (TypeError, ValueError):
        raise CoreError(f"{what} is not numeric") from None
    if arr.size == 0:
        raise CoreError(f"{what} is empty")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"{what} contains NaN or Inf")
    steps = np.diff(arr)
    if np.any(steps <= 0):
        k = int(np.argmax(steps <= 0))
        raise CoreError(f"{what} must be strictly increasing; {what}[{k + 1}] = {arr[k + 1]!r} "
                        f"follows {arr[k]!r}")
    return arr

