"""The forward GLR signature of one fault hypothesis with a fixed onset (Willsky & Jones 1976):
the brute-force counterpart of the backward sweep's fault information (``backward.py``), and the
GLR "with the data up to t" that tells when an ambiguity resolved.

For a fault b along the direction tau of the fault vector (``backward.FAULT_COLUMNS``) starting
at boundary k0, the forward filter's (which ignores it) prior error and innovations move by::

    rho_j = H' mu_j + D tau           (d nu_j / d b)
    mu <- mu - K_j rho_j              (update j, K_j = P_j H' S_j^-1 of the forward filter)
    mu <- Phi_k mu + Gamma_k tau      (step k >= k0; Phi_k mu = mu + F mu dt + F F mu dt^2 / 2)

with mu = 0 at k0; then e(t) = sum_{t_j <= t} rho' S^-1 nu, d(t) = sum rho' S^-1 rho give
b^ = e / d and GLR(t) = e^2 / d. With all the data it equals the backward sweep's
(tau' eta)^2 / (tau' I tau) for the same onset (test_glr3d.py).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .backward import REF, fault_gamma
from .filter import scaled_H
from .dynamics import fill_F
from .sparse import row_pattern


@njit(cache=True, nogil=True)
def signature_stats(C, f_n, v, lat, h, dt, tt, kp, qc, s, sB, ref_step, acc, il, im, rows, hu,
                    K_pr, Si_pr, nu, k0, tau, e_o, d_o):
    """Cumulative e and d (module docstring) at every update j (0 before the onset); K_pr,
    Si_pr: the forward filter's scaled gains and S^-1 (``Ins3dForward.Ks``, ``S_inv``)."""
    signature_series(C, f_n, v, lat, h, dt, tt, kp, qc, s, sB, ref_step, acc, il, im, rows, hu,
                     K_pr, Si_pr, nu, k0, tau, e_o, d_o, np.empty((0, rows)))


@njit(cache=True, nogil=True)
def signature_series(C, f_n, v, lat, h, dt, tt, kp, qc, s, sB, ref_step, acc, il, im, rows, hu,
                     K_pr, Si_pr, nu, k0, tau, e_o, d_o, rho_o):
    """``signature_stats``, and the signature rho_j itself (m/s per scaled unit of tau) into
    ``rho_o`` (M, rows) when it has M rows (0 before the onset; an empty ``rho_o``: not kept)
    -- what the onset's Fisher information needs (``eval.onset_bound``)."""
    keep = rho_o.shape[0] > 0
    n = s.size
    pB = sB.size
    F = np.empty((n, n))
    nz, cnt = np.empty((n, n), np.int64), np.empty(n, np.int64)
    G = np.empty((n, pB))
    mu = np.zeros(n)                            # scaled: T^-1 mu
    y, Fy, FFy = np.empty(n), np.empty(n), np.empty(n)
    rho, Sr = np.empty(rows), np.empty(rows)
    e = 0.0
    d = 0.0
    j = 0
    m = ref_step.size
    while j < m and ref_step[j] < k0:
        e_o[j] = 0.0
        d_o[j] = 0.0
        if keep:
            for i in range(rows):
                rho_o[j, i] = 0.0
        j += 1
    for k in range(k0, dt.size + 1):
        while j < m and ref_step[j] == k:
            Hs = scaled_H(s, acc[j], il, im, rows, hu)
            for i in range(rows):               # rho = H mu + D tau
                r_i = sB[REF + i] * tau[REF + i]
                for b in range(n):
                    r_i += Hs[i, b] * mu[b]
                rho[i] = r_i
                if keep:
                    rho_o[j, i] = r_i
            for i in range(rows):               # S^-1 rho
                acc_ = 0.0
                for c in range(rows):
                    acc_ += Si_pr[j, i, c] * rho[c]
                Sr[i] = acc_
                e += Sr[i] * nu[j, i]
                d += Sr[i] * rho[i]
            e_o[j] = e
            d_o[j] = d
            for a in range(n):                  # mu -= K rho (K = P H' S^-1)
                acc_ = 0.0
                for i in range(rows):
                    acc_ += K_pr[j, a, i] * rho[i]
                mu[a] -= acc_
            j += 1
        if k == dt.size:
            break
        fill_F(F, C[k], f_n[k], v[k], lat[k], h[k], kp)
        fault_gamma(F, dt[k], tt[k], s, sB, G)
        row_pattern(F, nz, cnt)
        for a in range(n):
            y[a] = s[a] * mu[a]
        _mul_vec(F, nz, cnt, y, Fy)
        _mul_vec(F, nz, cnt, Fy, FFy)
        h2 = 0.5 * dt[k] * dt[k]
        for a in range(n):                      # mu <- Phi' mu + Gamma' tau (scaled), with
            acc_ = y[a] + Fy[a] * dt[k] + FFy[a] * h2   # Phi = I + F dt + (F dt)^2 / 2
            for c in range(pB):
                acc_ += G[a, c] * tau[c] * s[a]
            mu[a] = acc_ / s[a]


@njit(cache=True, inline="always")
def _mul_vec(A, nz, cnt, x, out):
    """out = A x over the row pattern (nz, cnt) of A."""
    for i in range(A.shape[0]):
        acc = 0.0
        for m in range(cnt[i]):
            acc += A[i, nz[i, m]] * x[nz[i, m]]
        out[i] = acc


__all__ = ["signature_series", "signature_stats"]
