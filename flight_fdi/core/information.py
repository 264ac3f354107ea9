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


@njit(cache=True, nogil=True)
def backward_pass(F, G, C, norm, dt, u, info, Y0, y0, Ys, ys):
    """The backward information recursion over a record (see the module doc) into Ys (N, n, n),
    ys (N, n). F, G, C, norm: the model's Van Loan series; ``info`` (N, n, n+1) holds
    [H^T R^-1 H | H^T R^-1 z] per step. Returns the index where I + Y Qd was singular, or -1."""
    N, n = ys.shape
    p = G.shape[2]
    Phi, Qd, Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, p))
    work = np.empty((3, n, n))
    dt_held = np.nan
    Y = Y0.copy()
    y = y0.copy()
    M = np.empty((n, n))          # I + Y Qd
    rhs = np.empty((n, n + 1))    # [Y Phi | y - Y Bd u]
    X = np.empty((n, n + 1))      # (I + Y Qd)^-1 rhs
    Bdu = np.empty(n)
    for i in range(N - 1, -1, -1):
        for r in range(n):
            ys[i, r] = y[r]
            for c in range(n):
                Ys[i, r, c] = Y[r, c]
        if i == 0:
            break
        for r in range(n):
            for c in range(n):
                Y[r, c] += info[i, r, c]
            y[r] += info[i, r, n]
        if not dt[i] == dt_held:
            van_loan(F, G, C, norm, dt[i], Phi, Qd, Bd, work)
            dt_held = dt[i]
        matmul(Y, Qd, M)
        for r in range(n):
            M[r, r] += 1.0
        for c in range(n):                  # Bd u
            acc = 0.0
            for j in range(p):
                acc += Bd[c, j] * u[i, j]
            Bdu[c] = acc
        for r in range(n):                  # rhs = [Y Phi | y - Y Bd u]
            for c in range(n):
                acc = 0.0
                for j in range(n):
                    acc += Y[r, j] * Phi[j, c]
                rhs[r, c] = acc
            acc = y[r]
            for c in range(n):
                acc -= Y[r, c] * Bdu[c]
            rhs[r, n] = acc
        if not solve(M, rhs, X):
            return i
        # Y <- Phi^T X[:, :n],  y <- Phi^T X[:, n]
        for r in range(n):
            for c in range(n + 1):
                acc = 0.0
                for j in range(n):
                    acc += Phi[j, r] * X[j, c]
                if c < n:
                    Y[r, c] = acc
                else:
                    y[r] = acc
        for r in range(n):
            for c in range(r + 1, n):
                s = 0.5 * (Y[r, c] + Y[c, r])
                Y[r, c] = s
                Y[c, r] = s
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
def combine_all(Ys, ys, xf, Pf, rank_tol, W, Wv, x_s, P_s, ref, Lam, informative, v_tilde, d,
                terms, dof, normalized):
    """:func:`combine_step` at every step. Returns the first step that failed, or -1."""
    n = xf.shape[1]
    work = np.empty((3, n, n))
    work1 = np.empty((2, n, n + 1))
    for i in range(xf.shape[0]):
        if not combine_step(Ys[i], ys[i], xf[i], Pf[i], rank_tol, W[i], Wv[i], x_s[i], P_s[i],
                            ref[i], Lam[i], informative[i], v_tilde[i], d[i], terms[i], dof[i],
                            normalized[i], work, work1):
            return i
    return -1
