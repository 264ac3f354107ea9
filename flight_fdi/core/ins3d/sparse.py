"""Products with the sparse matrices of the ins3d model (F, Phi, Q, Gamma, H: about a quarter of
their entries are nonzero): loops that skip the zeros, accumulating into ``out``."""
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


__all__ = ["mul_left", "mul_right"]
