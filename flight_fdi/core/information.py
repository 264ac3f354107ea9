"""The backward information filter and the two-filter combination, compiled (numba); the
formulas are those of :mod:`flight_fdi.core.smoother` (SPEC section 3), which calls these
kernels. Scaled coordinates throughout.

Backward information filter, i = N-1 ... 0, starting from (Y, y) = (0, 0) or a prior::

    (Y_i, y_i) is recorded: the information about x_i from the measurements i+1..N
    update at i:     Y <- Y + H^T R^-1 H,   y <- y + H^T R^-1 z       (``info``: zero if not fused)
    predict to i-1:  Y <- Phi^T (I + Y Qd)^-1 Y Phi
                     y <- Phi^T (I + Y Qd)^-1 (y - Y Bd u)             (Phi, Qd, Bd of dt_i)

Two-filter combination at every step with the forward posterior x_f, P_f::

    [W | W v] = (I + Y P_f)^-1 [Y | y - Y x_f]
    x_s = x_f + P_f (W v),   P_s = P_f - P_f W P_f
    P_f = U D U^T  ->  reference pivots 1 / D;   W = L Lam L^T (rank-revealing, ldl_factor)
    element terms q = L^-1 (W v), J = sum_k q_k^2 / Lam_k          (ldl.information_terms)
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .discretize import matmul, van_loan
from .ldl import information_terms, ldl_factor, udu_factor


@njit(cache=True)
def solve(M, B, X):
    """X = M^-1 B by Gaussian elimination with partial pivoting (M n x n, B n x k; M and B
    are overwritten). Returns False when M is singular."""
    n = M.shape[0]
    k = B.shape[1]
    for c in range(n):
        p = c
        for r in range(c + 1, n):
            if abs(M[r, c]) > abs(M[p, c]):
                p = r
        if M[p, c] == 0.0:
            return False
        if p != c:
            for j in range(n):
                M[c, j], M[p, j] = M[p, j], M[c, j]
            for j in range(k):
                B[c, j], B[p, j] = B[p, j], B[c, j]
        for r in range(c + 1, n):
            f = M[r, c] / M[c, c]
            if f != 0.0:
                for j in range(c, n):
                    M[r, j] -= f * M[c, j]
                for j in range(k):
                    B[r, j] -= f * B[c, j]
    for c in range(n - 1, -1, -1):
        for j in range(k):
            acc = B[c, j]
            for q in range(c + 1, n):
                acc -= M[c, q] * X[q, j]
            X[c, j] = acc / M[c, c]
    return True


@njit(cache=True)
def backward_step(Y, y, info_i, Phi, Qd, Bd, u_i, M, rhs, X):
    """The backward information filter from step i to i-1, in place: the update with the
    measurement of step i (``info_i`` = [H^T R^-1 H | H^T R^-1 z], zero if not fused), then

        Y <- Phi^T (I + Y Qd)^-1 Y Phi,   y <- Phi^T (I + Y Qd)^-1 (y - Y Bd u)

    (Phi, Qd, Bd of step i). M (n, n), rhs and X (n, n+1) are scratch. False when I + Y Qd is
    singular."""
    n = y.shape[0]
    for r in range(n):
        for c in range(n):
            Y[r, c] += info_i[r, c]
        y[r] += info_i[r, n]
    matmul(Y, Qd, M)                        # M = I + Y Qd
    for r in range(n):
        M[r, r] += 1.0
    for c in range(n):                      # X[:, 0] = Bd u (scratch)
        acc = 0.0
        for j in range(u_i.shape[0]):
            acc += Bd[c, j] * u_i[j]
        X[c, 0] = acc
    matmul(Y, Phi, rhs[:, :n])              # rhs = [Y Phi | y - Y Bd u]
    for r in range(n):
        acc = y[r]
        for c in range(n):
            acc -= Y[r, c] * X[c, 0]
        rhs[r, n] = acc
    if not solve(M, rhs, X):
        return False
    matmul(Phi.T, X[:, :n], Y)              # Y = Phi^T X[:, :n], y = Phi^T X[:, n]
    for r in range(n):
        acc = 0.0
        for j in range(n):
            acc += Phi[j, r] * X[j, n]
        y[r] = acc
        for c in range(r + 1, n):
            sym = 0.5 * (Y[r, c] + Y[c, r])
            Y[r, c] = sym
            Y[c, r] = sym
    return True


@njit(cache=True, nogil=True)
def backward_pass(F, G, C, norm, dt, u, info, Y0, y0, Ys, ys):
    """The backward information recursion over a record (see the module doc) into Ys (N, n, n),
    ys (N, n). F, G, C, norm: the model's Van Loan series; ``info`` (N, n, n+1) holds
    [H^T R^-1 H | H^T R^-1 z] per step. Returns the index where I + Y Qd was singular, or -1."""
    N, n = ys.shape
    Phi, Qd, Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, G.shape[2]))
    work = np.empty((3, n, n))
    M, rhs, X = np.empty((n, n)), np.empty((n, n + 1)), np.empty((n, n + 1))
    dt_held = np.nan
    Y = Y0.copy()
    y = y0.copy()
    for i in range(N - 1, -1, -1):
        Ys[i] = Y
        ys[i] = y
        if i == 0:
            break
        if not dt[i] == dt_held:
            van_loan(F, G, C, norm, dt[i], Phi, Qd, Bd, work)
            dt_held = dt[i]
        if not backward_step(Y, y, info[i], Phi, Qd, Bd, u[i], M, rhs, X):
            return i
    return -1


@njit(cache=True)
def combine_step(Y, y, x_f, P_f, rank_tol, W, Wv, x_s, P_s, ref, Lam, informative, v_tilde, d,
                 terms, dof, normalized, work, work1):
    """The two-filter combination of one step (see the module doc). ``work``: (3, n, n),
    ``work1``: (2, n, n+1) scratch. Returns False when I + Y P_f or P_f is singular."""
    n = x_f.shape[0]
    M, PW, U = work[0], work[1], work[2]
    rhs, X = work1[0], work1[1]
    matmul(Y, P_f, M)
    for r in range(n):
        M[r, r] += 1.0
        acc = y[r]
        for c in range(n):
            rhs[r, c] = Y[r, c]
            acc -= Y[r, c] * x_f[c]
        rhs[r, n] = acc
    if not solve(M, rhs, X):
        return False
    for r in range(n):
        Wv[r] = X[r, n]
        for c in range(n):
            W[r, c] = 0.5 * (X[r, c] + X[c, r])
    # x_s = x_f + P_f W v;  P_s = P_f - P_f W P_f
    matmul(P_f, W, PW)
    matmul(PW, P_f, P_s)
    for r in range(n):
        acc = x_f[r]
        for c in range(n):
            acc += P_f[r, c] * Wv[c]
        x_s[r] = acc
    for r in range(n):
        for c in range(r, n):
            s = 0.5 * ((P_f[r, c] - P_s[r, c]) + (P_f[c, r] - P_s[c, r]))
            P_s[r, c] = s
            P_s[c, r] = s
    # reference pivots: the forward information P_f^-1 = U^-T D^-1 U^-1 has LDL^T pivots 1 / D
    if udu_factor(P_f, U, ref) >= 0:
        return False
    for k in range(n):
        ref[k] = 1.0 / ref[k]
    L = U                                   # (U is not needed any more)
    ldl_factor(W, ref, rank_tol, L, Lam, informative)
    information_terms(L, Lam, informative, Wv, rhs[:, 0], v_tilde, d, terms, dof, normalized)
    return True


@njit(cache=True, nogil=True)
def smooth_pass(F, G, C, norm, dt, u, info, Y0, y0, x_f, P_f, s, rank_tol, Y_out, y_out, W, Wv,
                x_s, P_s, info_ratio, informative, v_tilde, d, terms, dof, normalized):
    """The backward information filter and the two-filter combination in one backward sweep:
    at every step i (N-1 ... 0) :func:`combine_step` with the backward prediction (Y, y) and the
    forward posterior x_f[i], P_f[i] (physical units, scaled here by s), then
    :func:`backward_step` to i-1. Every output in physical units (Y = Y' / s s^T, x_s = s x_s',
    ...); ``info_ratio`` = Lam_k over its reference pivot, in [0, 1]. Returns (index, code) of a
    failure -- code 1: I + Y Qd singular, 2: I + Y P_f or P_f singular -- or (-1, 0)."""
    N, n = x_f.shape
    Phi, Qd, Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, G.shape[2]))
    work = np.empty((3, n, n))
    work1 = np.empty((2, n, n + 1))
    M, rhs, X = np.empty((n, n)), np.empty((n, n + 1)), np.empty((n, n + 1))
    xf, Pf = np.empty(n), np.empty((n, n))          # the forward posterior, scaled
    Wi, Pi = np.empty((n, n)), np.empty((n, n))     # W and P_s of the step, scaled
    Wvi, xi, ref, Lam, vt, dd = (np.empty(n), np.empty(n), np.empty(n), np.empty(n),
                                 np.empty(n), np.empty(n))
    dt_held = np.nan
    Y = Y0.copy()
    y = y0.copy()
    for i in range(N - 1, -1, -1):
        for r in range(n):
            xf[r] = x_f[i, r] / s[r]
            for c in range(n):
                Pf[r, c] = P_f[i, r, c] / (s[r] * s[c])
        if not combine_step(Y, y, xf, Pf, rank_tol, Wi, Wvi, xi, Pi, ref, Lam, informative[i],
                            vt, dd, terms[i], dof[i], normalized[i], work, work1):
            return i, 2
        for r in range(n):
            y_out[i, r] = y[r] / s[r]
            Wv[i, r] = Wvi[r] / s[r]
            x_s[i, r] = xi[r] * s[r]
            v_tilde[i, r] = vt[r] * s[r]
            d[i, r] = dd[r] * s[r] * s[r]
            info_ratio[i, r] = min(max(Lam[r] / ref[r], 0.0), 1.0)
            for c in range(n):
                ss = s[r] * s[c]
                Y_out[i, r, c] = Y[r, c] / ss
                W[i, r, c] = Wi[r, c] / ss
                P_s[i, r, c] = Pi[r, c] * ss
        if i == 0:
            break
        if not dt[i] == dt_held:
            van_loan(F, G, C, norm, dt[i], Phi, Qd, Bd, work)
            dt_held = dt[i]
        if not backward_step(Y, y, info[i], Phi, Qd, Bd, u[i], M, rhs, X):
            return i, 1
    return -1, 0
