"""The measurement update with numpy, for any number of rows m (redundant references, the
attitude axis's angle and rate): the same equations as the one-row update of
:mod:`flight_fdi.core.filter_kernel`, and the updates with failed rows (KF2 / AF, seed 001).
Scaled coordinates (see :mod:`flight_fdi.core.scaled`)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from .errors import CoreError
from .gate import GateConfig
from .redundancy import af_gain, anomaly_matrix, kf2_gain


def update_rows(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, Hs: np.ndarray,
            HsT: np.ndarray, I: np.ndarray, threshold: float, reject: bool):
    """The update with numpy, for any m (used for m > 1 rows): the same equations as the
    kernel's one-row update. x (n,), P (n, n), Hs = H T (m, n) scaled; z (m,), R (m, m), nu, S
    in measurement units. Returns (x+, P+, nu, S, K, beta2, exceeded, fused); K (n, m) is the
    gain applied (zeros when the sample was not fused)."""
    PHt = P.dot(HsT)
    S = Hs.dot(PHt) + R
    S = 0.5 * (S + S.T)
    try:
        L = np.linalg.cholesky(S)
    except np.linalg.LinAlgError:
        raise CoreError("innovation covariance S is not positive definite") from None
    Linv = np.linalg.inv(L)
    Sinv = Linv.T.dot(Linv)
    nu = z - Hs.dot(x)
    w = Linv.dot(nu)
    with np.errstate(over="ignore"):  # an overflow is refused by the caller's finiteness check
        beta2 = float(w.dot(w))
    exceeded = beta2 > threshold
    K = PHt.dot(Sinv)
    if exceeded and reject:
        return x, P, nu, S, K * 0.0, beta2, True, False
    x = x + K.dot(nu)
    A = I - K.dot(Hs)
    P = A.dot(P).dot(A.T) + K.dot(R).dot(K.T)
    P = (P + P.T) * 0.5
    return x, P, nu, S, K, beta2, exceeded, True


def update_failed_rows(x: np.ndarray, P: np.ndarray, z: np.ndarray, R: np.ndarray, Hs: np.ndarray,
                   I: np.ndarray, failed: tuple[int, ...], mode: str, G: np.ndarray | None,
                   gate: GateConfig, reject: bool):
    """The update with failed rows (numpy, scaled coordinates): KF2 (``known_anomaly``) or AF
    (``exclude``) with the gains of :mod:`.redundancy`. Returns x+, P+, nu, S (nominal, all
    rows), beta2, threshold, exceeded, fused (over the rows used), the rows used and the R used."""
    m = Hs.shape[0]
    nu = z - Hs.dot(x)
    if mode == "known_anomaly":
        C = anomaly_matrix(m, failed)
        R_used = R + C.dot(G).dot(C.T)
        K, S_used = kf2_gain(P, Hs, R, failed, G)
        S = Hs.dot(P).dot(Hs.T) + R  # the nominal S, reported (row_beta2) for every row
        S = 0.5 * (S + S.T)
        used = tuple(range(m))
        nu_used = nu
    else:
        R_used = R
        K, S = af_gain(P, Hs, R, failed)
        used = tuple(i for i in range(m) if i not in failed)
        S_used = S[np.ix_(used, used)]
        nu_used = nu[list(used)]
    if not used:
        return x, P, nu, S, 0.0, math.nan, False, False, used, R_used
    try:
        L = np.linalg.cholesky(S_used)
    except np.linalg.LinAlgError:
        raise CoreError("innovation covariance S of the rows used is not positive definite") \
            from None
    w = np.linalg.solve(L, nu_used)
    beta2 = float(w.dot(w))
    thr = gate.threshold(len(used))
    exceeded = beta2 > thr
    if exceeded and reject:
        return x, P, nu, S, beta2, thr, True, False, used, R_used
    x = x + K.dot(nu)
    A = I - K.dot(Hs)
    P = A.dot(P).dot(A.T) + K.dot(R_used).dot(K.T)
    P = (P + P.T) * 0.5
    return x, P, nu, S, beta2, thr, exceeded, True, used, R_used


def check_finite(x: np.ndarray, P: np.ndarray, beta2: float, nu: Any,
                         S: Any) -> None:
    """CoreError when an update overflowed float64: a finite measurement so far from the
    prediction (e.g. 1e200 m/s) that beta2 = nu^T S^-1 nu, a row's nu_k^2 / S_kk or the
    corrected state is Inf or NaN. The caller then leaves the filter unchanged."""
    ok = math.isfinite(beta2) and bool(np.isfinite(x).all()) and bool(np.isfinite(P).all())
    if ok and np.size(nu) > 1:
        with np.errstate(over="ignore", invalid="ignore"):
            ok = bool(np.all(np.isfinite(np.square(nu) / np.diag(S))))
    if not ok:
        raise overflow_error(nu, beta2)


def overflow_error(nu: Any, beta2: float) -> CoreError:
    return CoreError(f"the update overflows float64 (innovation {np.ravel(nu).tolist()}, "
                     f"beta2 {beta2!r}): the measurement is not a plausible value")
