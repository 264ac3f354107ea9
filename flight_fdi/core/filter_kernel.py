"""The forward Kalman filter with the beta^2 gate, compiled (numba): one source for the streaming
:class:`~flight_fdi.core.kalman.KalmanFilter` (a node's per-message step) and the batch
:func:`~flight_fdi.core.kalman.run_forward` (a whole record). Both call :func:`step`, so they
agree to the last bit.

All arrays are in scaled coordinates x' = T^-1 x (T = diag(scale), see ``core.scaled``):
A' = T^-1 A T, Qc' = T^-1 Qc T^-1, B' = T^-1 B, h' = h T. One measurement row per step
(m = 1: h a row vector, r a variance); ``core.multirow`` handles m > 1 with numpy.

    predict:  x- = Phi x + Bd u                    Phi, Qd, Bd = van_loan(A, Qc, B, dt)
              P- = Phi P Phi^T + Qd
    update:   nu = z - h x-                        innovation
              S  = h P- h^T + r                    its variance
              beta2 = nu^2 / S                     the gate statistic, chi2(1) when healthy
              K  = P- h^T / S                      gain
              x+ = x- + K nu
              P+ = (I - K h) P- (I - K h)^T + K r K^T     (Joseph form)

A sample whose beta2 exceeds the threshold is still fused unless ``reject`` is set; a rejected
sample leaves x+ = x-, P+ = P- and K = 0.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .discretize import matmul, van_loan

#: status codes of :func:`update` and :func:`step` (0: fine)
OK = 0
S_NOT_POSITIVE = 1
NOT_FINITE = 2      # the update overflowed float64: the measurement is not a plausible value


@njit(cache=True, error_model="numpy", inline="always")
def predict(x, P, Phi, Qd, Bd, u, x_prior, P_prior, work):
    """x- = Phi x + Bd u,  P- = Phi P Phi^T + Qd (exactly symmetric: its upper triangle,
    mirrored). ``work``: (>= 1, n, n)."""
    n = x.shape[0]
    for i in range(n):
        acc = 0.0
        for j in range(n):
            acc += Phi[i, j] * x[j]
        for j in range(u.shape[0]):
            acc += Bd[i, j] * u[j]
        x_prior[i] = acc
    PhiP = work[0]
    matmul(Phi, P, PhiP)
    for i in range(n):
        for j in range(i, n):
            acc = Qd[i, j]
            for k in range(n):
                acc += PhiP[i, k] * Phi[j, k]
            P_prior[i, j] = acc
            P_prior[j, i] = acc


@njit(cache=True, error_model="numpy", inline="always")
def update(x_prior, P_prior, h, r, z, threshold, reject, x, P, K, work):
    """The one-row update with the gate into x, P, K; returns (status, nu, S, beta2, exceeded,
    fused). ``work``: (>= 2, n, n).

    The Joseph form P+ = (I - K h) P- (I - K h)^T + K r K^T is evaluated with the rank-one
    structure of I - K h (one measurement row): (I - K h) P- = P- - K (h P-), then
    [(I - K h) P-] (I - K h)^T = (I - K h) P- - v K^T with v = [(I - K h) P-] h^T; O(n^2), the
    same products in another order (no algebraic simplification: the form keeps P+ positive
    for any K)."""
    n = x_prior.shape[0]
    for i in range(n):                      # K <- P- h^T (divided by S below)
        acc = 0.0
        for j in range(n):
            acc += P_prior[i, j] * h[j]
        K[i] = acc
    S = r
    hx = 0.0
    for i in range(n):
        S += h[i] * K[i]
        hx += h[i] * x_prior[i]
    nu = z - hx
    if not S > 0.0:
        return S_NOT_POSITIVE, nu, S, np.nan, False, False
    beta2 = nu * nu / S
    if not np.isfinite(beta2):
        return NOT_FINITE, nu, S, beta2, False, False
    exceeded = beta2 > threshold
    if exceeded and reject:
        x[:] = x_prior
        P[:, :] = P_prior
        K[:] = 0.0
        return OK, nu, S, beta2, True, False
    finite = True
    hP = work[1, 0]                         # h P- (= (P- h^T)^T: P- is symmetric)
    for j in range(n):
        hP[j] = K[j]
    for i in range(n):
        K[i] = K[i] / S
        x[i] = x_prior[i] + K[i] * nu
        finite = finite and np.isfinite(x[i])
    AP = work[0]                            # (I - K h) P-
    v = work[1, 1]                          # (I - K h) P- h^T
    for i in range(n):
        acc = 0.0
        for j in range(n):
            a = P_prior[i, j] - K[i] * hP[j]
            AP[i, j] = a
            acc += a * h[j]
        v[i] = acc
    for i in range(n):                      # P+ = AP - v K^T + K r K^T, symmetrized
        for j in range(i, n):
            p = 0.5 * ((AP[i, j] - v[i] * K[j]) + (AP[j, i] - v[j] * K[i])) + K[i] * r * K[j]
            P[i, j] = p
            P[j, i] = p
            finite = finite and np.isfinite(p)
    if not finite:
        return NOT_FINITE, nu, S, beta2, exceeded, True
    return OK, nu, S, beta2, exceeded, True


@njit(cache=True, error_model="numpy", inline="always")
def predict_over(F, G, C, norm, dt, u, x, P, dt_held, Phi, Qd, Bd, work, x_prior, P_prior):
    """x-, P- after ``dt`` seconds (none when dt == 0). F, G, C, norm: the model's Van Loan
    series; Phi, Qd, Bd: the discretization last computed, for the dt in dt_held[0] (NaN: none
    yet), recomputed only for a new dt."""
    if dt > 0.0:
        if not dt == dt_held[0]:
            van_loan(F, G, C, norm, dt, Phi, Qd, Bd, work)
            dt_held[0] = dt
        predict(x, P, Phi, Qd, Bd, u, x_prior, P_prior, work)
    else:
        x_prior[:] = x
        P_prior[:, :] = P


@njit(cache=True, error_model="numpy", inline="always")
def step(F, G, C, norm, h, dt, u, z, r, threshold, reject, x, P, dt_held, Phi, Qd, Bd, work,
         x_prior, P_prior, x_post, P_post, K):
    """One step: predict over ``dt`` (:func:`predict_over`; the first sample of a record, dt = 0,
    is an update on the prior), then update with z. The prior goes to x_prior, P_prior, the
    posterior to x_post, P_post (x, P are not changed). Returns (status, nu, S, beta2, exceeded,
    fused)."""
    predict_over(F, G, C, norm, dt, u, x, P, dt_held, Phi, Qd, Bd, work, x_prior, P_prior)
    return update(x_prior, P_prior, h, r, z, threshold, reject, x_post, P_post, K, work)


@njit(cache=True, error_model="numpy", nogil=True)
def forward_pass(F, G, C, norm, h, x0, P0, dt, u, z, r, threshold, reject, s, SS,
                 x_prior, P_prior, x, P, K, nu, S, beta2, fused):
    """:func:`step` over a record (N steps; u is (N, p), p may be 0) on the scaled state,
    every intermediate quantity into the (N, ...) output arrays in physical units (x = x' s,
    P = P' * SS, K = K' s: the products the streaming filter's ``x`` and ``P`` compute).
    Returns (index, status) of the first step that failed, or (-1, OK)."""
    n = x0.shape[0]
    dt_held = np.full(1, np.nan)
    Phi, Qd, Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, G.shape[2]))
    work = np.empty((3, n, n))
    x_k, P_k = x0.copy(), P0.copy()                     # the state, scaled
    x_pri, P_pri = np.empty(n), np.empty((n, n))
    x_post, P_post, K_k = np.empty(n), np.empty((n, n)), np.empty(n)
    for k in range(dt.shape[0]):
        status, nu[k], S[k], beta2[k], _, fused[k] = step(
            F, G, C, norm, h, dt[k], u[k], z[k], r[k], threshold, reject, x_k, P_k, dt_held,
            Phi, Qd, Bd, work, x_pri, P_pri, x_post, P_post, K_k)
        if status != OK:
            return k, status
        for i in range(n):
            x_prior[k, i] = x_pri[i] * s[i]
            x[k, i] = x_post[i] * s[i]
            K[k, i] = K_k[i] * s[i]
            for j in range(n):
                P_prior[k, i, j] = P_pri[i, j] * SS[i, j]
                P[k, i, j] = P_post[i, j] * SS[i, j]
        x_k, x_post = x_post, x_k
        P_k, P_post = P_post, P_k
    return -1, OK
