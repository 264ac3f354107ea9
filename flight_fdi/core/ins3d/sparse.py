"""Products with the sparse matrices of the ins3d model (F, Phi, Q, Gamma, H: about a quarter of
their entries are nonzero): loops that skip the zeros, accumulating into ``out``; the pattern
of a matrix's nonzero columns per row (found at run time: nothing assumes the model's layout)
and the congruence A P A' over it."""
from __future__ import annotations

from numba import njit


@njit(cache=True)
def mul_left(M, X, out, transpose):
    """out += M X (``transpose``: out += M' X), skipping the zeros of M."""
    w = X.shape[1]
    for i in range(M.shape[0]):
        for k in range(M.shape[1]):
            m = M[i, k]
            if m != 0.0:
                if transpose:
                    for c in range(w):
                        out[k, c] += m * X[i, c]
                else:
                    for c in range(w):
                        out[i, c] += m * X[k, c]


@njit(cache=True)
def mul_right(X, M, out):
    """out += X M, skipping the zeros of M."""
    for k in range(M.shape[0]):
        for c in range(M.shape[1]):
            m = M[k, c]
            if m != 0.0:
                for a in range(X.shape[0]):
                    out[a, c] += X[a, k] * m


@njit(cache=True)
def row_pattern(A, nz, cnt):
    """nz[i, :cnt[i]] = the columns of the nonzero entries of row i of A."""
    for i in range(A.shape[0]):
        c = 0
        for k in range(A.shape[1]):
            if A[i, k] != 0.0:
                nz[i, c] = k
                c += 1
        cnt[i] = c


@njit(cache=True)
def congruence(A, nz, cnt, P, Q, T):
    """P <- A P A' + Q (P symmetric, exactly symmetric afterwards) over the row pattern
    (nz, cnt) of A; T (n, n) scratch. Entry (i, j), i <= j: Q_ij + sum_m (A P)_ik A_jk over the
    pattern k = nz[j, m] in order; computed as row j of A times (A P)' so that the inner loops
    run over contiguous rows."""
    n = P.shape[0]
    for i in range(n):                          # T = A P
        for c in range(n):
            T[i, c] = 0.0
        for m in range(cnt[i]):
            k = nz[i, m]
            f = A[i, k]
            for c in range(n):
                T[i, c] += f * P[k, c]
    for i in range(n):                          # T <- T' = (A P)'
        for c in range(i + 1, n):
            T[i, c], T[c, i] = T[c, i], T[i, c]
    for j in range(n):                          # P_ji = Q_ji + sum_m A_jk T'_ki, i <= j
        for i in range(j + 1):
            P[j, i] = Q[j, i]
        for m in range(cnt[j]):
            k = nz[j, m]
            f = A[j, k]
            for i in range(j + 1):
                P[j, i] += f * T[k, i]
    for j in range(n):                          # mirrored
        for i in range(j):
            P[i, j] = P[j, i]


@njit(cache=True)
def mul_pattern(A, nz, cnt, X, out):
    """out = A X over the row pattern (nz, cnt) of A (X, out: (n, w); out is overwritten)."""
    for i in range(A.shape[0]):
        for c in range(X.shape[1]):
            out[i, c] = 0.0
        for m in range(cnt[i]):
            k = nz[i, m]
            f = A[i, k]
            for c in range(X.shape[1]):
                out[i, c] += f * X[k, c]


__all__ = ["congruence", "mul_left", "mul_pattern", "mul_right", "row_pattern"]
