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


@njit(cache=True, error_model="numpy", inline="always")
def solve(A, n):
    """Gauss-Jordan elimination with partial pivoting on the augmented matrix A = [M | B]
    (M n x n): afterwards A[:, n:] = M^-1 B. False when M is singular."""
    w = A.shape[1]
    for c in range(n):
        p = c
        best = abs(A[c, c])
        for r in range(c + 1, n):
            if abs(A[r, c]) > best:
                best = abs(A[r, c])
                p = r
        if best == 0.0:
            return False
        if p != c:
            for j in range(c, w):
                A[c, j], A[p, j] = A[p, j], A[c, j]
        inv = 1.0 / A[c, c]
        for j in range(c, w):
            A[c, j] *= inv
        for r in range(n):
            f = A[r, c]
            if r != c and f != 0.0:
                for j in range(c, w):
                    A[r, j] -= f * A[c, j]
    return True


@njit(cache=True, error_model="numpy", inline="always")
def backward_step(Y, y, info_i, Phi, Qd, Bd, u_i, A, Bdu):
    """The backward information filter from step i to i-1, in place: the update with the
    measurement of step i (``info_i`` = [H^T R^-1 H | H^T R^-1 z], zero if not fused), then

        Y <- Phi^T (I + Y Qd)^-1 Y Phi,   y <- Phi^T (I + Y Qd)^-1 (y - Y Bd u)

    (Phi, Qd, Bd of step i). A (n, 2n+1) and Bdu (n) are scratch. False when I + Y Qd is
    singular."""
    n = y.shape[0]
    for r in range(n):
        for c in range(n):
            Y[r, c] += info_i[r, c]
        y[r] += info_i[r, n]
    for c in range(n):                      # Bd u
        acc = 0.0
        for j in range(u_i.shape[0]):
            acc += Bd[c, j] * u_i[j]
        Bdu[c] = acc
    for r in range(n):                      # A = [I + Y Qd | Y Phi | y - Y Bd u]
        for c in range(n):
            m = 1.0 if r == c else 0.0
            yp = 0.0
            for j in range(n):
                m += Y[r, j] * Qd[j, c]
                yp += Y[r, j] * Phi[j, c]
            A[r, c] = m
            A[r, n + c] = yp
        acc = y[r]
        for c in range(n):
            acc -= Y[r, c] * Bdu[c]
        A[r, 2 * n] = acc
    if not solve(A, n):
        return False
    for r in range(n):                      # [Y | y] = Phi^T A[:, n:]
        for c in range(n + 1):
            acc = 0.0
            for j in range(n):
                acc += Phi[j, r] * A[j, n + c]
            if c < n:
                Y[r, c] = acc
            else:
                y[r] = acc
    for r in range(n):
        for c in range(r + 1, n):
            sym = 0.5 * (Y[r, c] + Y[c, r])
            Y[r, c] = sym
            Y[c, r] = sym
    return True


@njit(cache=True, error_model="numpy", inline="always")
def combine_step(Y, y, x_f, P_f, rank_tol, W, Wv, x_s, P_s, ref, Lam, informative, v_tilde, d,
                 terms, dof, normalized, A, work):
    """The two-filter combination of one step (see the module doc). ``A``: (n, 2n+1),
    ``work``: (2, n, n) scratch. Returns False when I + Y P_f or
    P_f is singular."""
    n = x_f.shape[0]
    for r in range(n):                      # A = [I + Y P_f | Y | y - Y x_f]
        acc = y[r]
        for c in range(n):
            m = 1.0 if r == c else 0.0
            for j in range(n):
                m += Y[r, j] * P_f[j, c]
            A[r, c] = m
            A[r, n + c] = Y[r, c]
            acc -= Y[r, c] * x_f[c]
        A[r, 2 * n] = acc
    if not solve(A, n):
        return False
    for r in range(n):                      # [W | W v] = A[:, n:]
        Wv[r] = A[r, 2 * n]
        for c in range(n):
            W[r, c] = 0.5 * (A[r, n + c] + A[c, n + r])
    # x_s = x_f + P_f W v;  P_s = P_f - P_f W P_f
    PW = work[0]
    matmul(P_f, W, PW)
    for r in range(n):
        acc = x_f[r]
        for c in range(n):
            acc += P_f[r, c] * Wv[c]
        x_s[r] = acc
    for r in range(n):                      # (symmetric: the upper triangle, mirrored)
        for c in range(r, n):
            acc = P_f[r, c]
            for j in range(n):
                acc -= PW[r, j] * P_f[j, c]
            P_s[r, c] = acc
            P_s[c, r] = acc
    # reference pivots: the forward information P_f^-1 = U^-T D^-1 U^-1 has LDL^T pivots 1 / D
    U = work[1]
    if udu_factor(P_f, U, ref) >= 0:
        return False
    for k in range(n):
        ref[k] = 1.0 / ref[k]
    L = U                                   # (U is not needed any more)
    ldl_factor(W, ref, rank_tol, L, Lam, informative)
    information_terms(L, Lam, informative, Wv, A[:, 0], v_tilde, d, terms, dof, normalized)
    return True


#: state sizes whose sweep is compiled with n as a compile-time constant (the built-in models:
#: the attitude axis, 3 states, and the INS channel, 4): LLVM then unrolls the n x n loops,
#: ~1.7x faster. Any other n runs the generic sweep (n read from the arrays), same arithmetic.
SPECIALISED = (3, 4)


def _sweep(n_fixed):
    """The backward sweep compiled for ``n_fixed`` states (0: any n). numba keys its cache on
    the closure's value, so each size is compiled once (``make setup``) and loaded from disk."""

    @njit(cache=True, error_model="numpy", nogil=True)
    def smooth_pass(F, G, C, norm, dt, u, info, Y0, y0, x_f, P_f, s, rank_tol, Y_out, y_out, W,
                    Wv, x_s, P_s, info_ratio, informative, v_tilde, d, terms, dof, normalized):
        """The backward information filter and the two-filter combination in one backward
        sweep: at every step i (N-1 ... 0) :func:`combine_step` with the backward prediction
        (Y, y) and the forward posterior x_f[i], P_f[i] (physical units, scaled here by s), then
        :func:`backward_step` to i-1. Every output in physical units (Y = Y' / s s^T,
        x_s = s x_s', ...); ``info_ratio`` = Lam_k over its reference pivot, in [0, 1]. Returns
        (index, code) of a failure -- code 1: I + Y Qd singular, 2: I + Y P_f or P_f singular
        -- or (-1, 0)."""
        N = x_f.shape[0]
        n = x_f.shape[1] if n_fixed == 0 else n_fixed   # every n x n array below has n rows
        Phi, Qd, Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, G.shape[2]))
        work = np.empty((3, n, n))
        A, Bdu = np.empty((n, 2 * n + 1)), np.empty(n)
        xf, Pf = np.empty(n), np.empty((n, n))          # the forward posterior, scaled
        Wi, Pi = np.empty((n, n)), np.empty((n, n))     # W and P_s of the step, scaled
        Wvi, xi, ref, Lam, vt, dd = (np.empty(n), np.empty(n), np.empty(n), np.empty(n),
                                     np.empty(n), np.empty(n))
        Y, y, inv_s = np.empty((n, n)), np.empty(n), np.empty(n)
        for r in range(n):
            inv_s[r] = 1.0 / s[r]
            y[r] = y0[r]
            for c in range(n):
                Y[r, c] = Y0[r, c]
        dt_held = np.nan
        for i in range(N - 1, -1, -1):
            for r in range(n):
                xf[r] = x_f[i, r] * inv_s[r]
                for c in range(n):
                    Pf[r, c] = P_f[i, r, c] * inv_s[r] * inv_s[c]
            if not combine_step(Y, y, xf, Pf, rank_tol, Wi, Wvi, xi, Pi, ref, Lam,
                                informative[i], vt, dd, terms[i], dof[i], normalized[i], A, work):
                return i, 2
            for r in range(n):
                y_out[i, r] = y[r] * inv_s[r]
                Wv[i, r] = Wvi[r] * inv_s[r]
                x_s[i, r] = xi[r] * s[r]
                v_tilde[i, r] = vt[r] * s[r]
                d[i, r] = dd[r] * s[r] * s[r]
                info_ratio[i, r] = min(max(Lam[r] / ref[r], 0.0), 1.0)
                for c in range(n):
                    Y_out[i, r, c] = Y[r, c] * inv_s[r] * inv_s[c]
                    W[i, r, c] = Wi[r, c] * inv_s[r] * inv_s[c]
                    P_s[i, r, c] = Pi[r, c] * s[r] * s[c]
            if i == 0:
                break
            if not dt[i] == dt_held:
                van_loan(F, G, C, norm, dt[i], Phi, Qd, Bd, work)
                dt_held = dt[i]
            if not backward_step(Y, y, info[i], Phi, Qd, Bd, u[i], A, Bdu):
                return i, 1
        return -1, 0

    return smooth_pass


#: the generic sweep (any n)
smooth_pass = _sweep(0)
_SWEEPS = {0: smooth_pass}


def sweep_for(n: int):
    """The sweep for ``n`` states: compiled for that n when it is in :data:`SPECIALISED`,
    else the generic :data:`smooth_pass`."""
    key = n if n in SPECIALISED else 0
    if key not in _SWEEPS:
        _SWEEPS[key] = _sweep(key)
    return _SWEEPS[key]
