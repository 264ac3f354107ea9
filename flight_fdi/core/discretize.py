"""Exact discretization of a continuous-time linear model for any step dt, compiled (numba).

For ``x' = A x + B u + w``, ``E[w w^T] = Qc`` (spectral density), a step of ``dt`` seconds is::

    Phi = expm(A dt)
    Qd  = int_0^dt expm(A s) Qc expm(A s)^T ds          (Van Loan 1978)
    Bd  = int_0^dt expm(A s) ds B  =  Gamma B

These are the blocks of Van Loan's exponential of [[-A, Qc], [0, A^T]] dt (and of
[[A, B], [0, 0]] dt for Bd). They are computed by scaling and squaring on the blocks themselves:

1. scaling: h = dt / 2^s with ||A h||_1 <= THETA (s = 0 for the usual sample intervals);
2. the blocks at h from their Taylor series in h, whose matrix coefficients depend only on the
   model and are computed once (:class:`VanLoanSeries`)::

       Phi(h) = sum_j h^j A^j / j!
       Bd(h)  = h sum_j h^j A^j B / (j+1)!
       Qd(h)  = h sum_j h^j M_{j+1} / (j+1)!,   M_1 = Qc,  M_{k+1} = A M_k + M_k A^T

   summed by Horner's scheme up to the term whose bound is below rounding (O(terms n^2) per dt;
   at least ``SHORT`` terms, a loop length the compiler knows and unrolls);
3. squaring, s times (the semigroup property, block by block)::

       Qd(2h) = Phi(h) Qd(h) Phi(h)^T + Qd(h),  Gamma(2h) = Gamma(h) + Phi(h) Gamma(h),
       Phi(2h) = Phi(h)^2                        (Bd = Gamma B, Gamma = int_0^h expm(A s) ds)

A Pade approximant of Van Loan's 2n x 2n matrix would cost a dense 2n x 2n solve per step; the
series costs a few n x n multiply-adds. Tested against ``scipy.linalg.expm`` of Van Loan's matrix
to 1e-12 of each state's scale. The filter's kernels call :func:`van_loan` at every new dt inside
their compiled loop: jittered stamps cost what regular ones do, and no Python runs per dt.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .vanloan import TERMS, VanLoanSeries  # noqa: F401 (the series' class, re-exported)

#: ||A h||_1 at or below which the series is summed directly (then at most ~15 terms)
THETA = 0.25
#: a series is cut where the bound of its next term falls below this fraction of its first
_EPS = 1e-16
#: when the bound asks for at most this many terms (the usual sample intervals), Horner's loop
#: runs exactly SHORT terms: a trip count the compiler knows, so it unrolls the loop (3-4x
#: faster than a loop of run-time length; the extra terms lie below rounding)
SHORT = 5


@njit(cache=True, error_model="numpy", inline="always")
def matmul_sized(A, B, out, rows, inner, cols):
    """out = A B over the leading rows x inner and inner x cols blocks (``out`` must not alias A
    or B). With the sizes given, a kernel compiled for constant sizes has loops of known length
    (``glr_kernel``); :func:`matmul` is the same products in the same order, the same bits."""
    for i in range(rows):
        for j in range(cols):
            acc = 0.0
            for k in range(inner):
                acc += A[i, k] * B[k, j]
            out[i, j] = acc


@njit(cache=True, error_model="numpy", inline="always")
def matmul(A, B, out):
    """out = A B (small dense matrices; ``out`` must not alias A or B; ``matmul(A, B.T, out)``
    for A B^T)."""
    matmul_sized(A, B, out, A.shape[0], A.shape[1], B.shape[1])


@njit(cache=True, error_model="numpy", inline="always")
def _add_to(M, D):
    """M += D, element by element."""
    for i in range(M.shape[0]):
        for j in range(M.shape[1]):
            M[i, j] += D[i, j]


@njit(cache=True, error_model="numpy", inline="always")
def _scaling(norm, dt):
    """(s, h): the number of halvings s and h = dt / 2^s with ||A h||_1 <= THETA."""
    s = 0
    h = dt
    while norm * h > THETA and s < 1100:
        h *= 0.5
        s += 1
    return s, h


@njit(cache=True, error_model="numpy", inline="always")
def expm_series(F, norm, dt, Phi, work):
    """Phi = expm(A dt) alone, from the series F[j] = A^j / j! of :class:`VanLoanSeries` (norm =
    ||A||_1): Horner at h = dt / 2^s, then s squarings Phi(2h) = Phi(h)^2. ``work``: (n, n)."""
    s, h = _scaling(norm, dt)
    J = _terms(norm * h)
    if J <= SHORT:
        _horner(F, h, SHORT, Phi)
    else:
        _horner(F, h, J, Phi)
    for _ in range(s):
        matmul(Phi, Phi, work)
        Phi[:, :] = work


@njit(cache=True, error_model="numpy", inline="always")
def _terms(a):
    """Number of series terms for ||A h||_1 = a <= THETA: the bound (2a)^j / (j+1)! of the
    first omitted term of the slowest series (Qd's) is below _EPS."""
    bound = 1.0
    j = 0
    while j < TERMS - 1:
        j += 1
        bound *= 2.0 * a / (j + 1)
        if bound <= _EPS:
            break
    return j


@njit(cache=True, error_model="numpy", inline="always")
def _horner(coef, h, J, out):
    """out = sum_{j < J} h^j coef[j] (Horner's scheme, element by element)."""
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            acc = coef[J - 1, r, c]
            for j in range(J - 2, -1, -1):
                acc = acc * h + coef[j, r, c]
            out[r, c] = acc


@njit(cache=True, error_model="numpy", inline="always")
def van_loan(F, G, C, norm, dt, Phi, Qd, Bd, work):
    """Phi = expm(A dt), Qd, Bd for dt >= 0 into the given arrays (``work``: (3, n, n)).

    Scaling and squaring: h = dt / 2^s with ||A h||_1 <= THETA, the blocks at h from the series
    of :class:`VanLoanSeries`, then s doublings::

        Qd(2h) = Phi(h) Qd(h) Phi(h)^T + Qd(h),  Gamma(2h) = Gamma(h) + Phi(h) Gamma(h),
        Phi(2h) = Phi(h)^2                       (Bd = Gamma B, Gamma = int_0^h expm(A s) ds)
    """
    n = Phi.shape[0]
    s, h = _scaling(norm, dt)
    J = _terms(norm * h)
    if J <= SHORT:
        _phi_qd(F, C, h, SHORT, Phi, Qd)
    else:
        _phi_qd(F, C, h, J, Phi, Qd)
    if s == 0:
        if Bd.shape[1] > 0:
            _horner(G, h, J, Bd)
            for r in range(n):
                for c in range(Bd.shape[1]):
                    Bd[r, c] *= h
        return
    Gamma = work[2]
    _gamma(F, h, J, Gamma)
    for _ in range(s):
        matmul(Phi, Qd, work[0])
        matmul(work[0], Phi.T, work[1])
        _add_to(Qd, work[1])
        matmul(Phi, Gamma, work[0])
        _add_to(Gamma, work[0])
        matmul(Phi, Phi, work[0])
        Phi[:, :] = work[0]
    matmul(Gamma, G[0], Bd)          # Bd = Gamma B (G[0] = B)
    for r in range(n):               # (the doublings leave rounding asymmetry in Qd)
        for c in range(r + 1, n):
            q = 0.5 * (Qd[r, c] + Qd[c, r])
            Qd[r, c] = q
            Qd[c, r] = q


@njit(cache=True, error_model="numpy", inline="always")
def _phi_qd(F, C, h, J, Phi, Qd):
    """Phi = sum_{j < J} h^j F[j] and Qd = h sum_{j < J} h^j C[j] by Horner's scheme, element
    by element (Qd from its upper triangle: every C[j] is symmetric)."""
    n = Phi.shape[0]
    for r in range(n):
        for c in range(n):
            phi = F[J - 1, r, c]
            for j in range(J - 2, -1, -1):
                phi = phi * h + F[j, r, c]
            Phi[r, c] = phi
        for c in range(r, n):
            q = C[J - 1, r, c]
            for j in range(J - 2, -1, -1):
                q = q * h + C[j, r, c]
            Qd[r, c] = q * h
            Qd[c, r] = q * h


@njit(cache=True, error_model="numpy", inline="always")
def _gamma(F, h, J, out):
    """out = h sum_{j < J} h^j F[j] / (j+1) = int_0^h expm(A s) ds (Horner's scheme)."""
    out[:, :] = F[J - 1] / J
    for j in range(J - 2, -1, -1):
        for r in range(out.shape[0]):
            for c in range(out.shape[1]):
                out[r, c] = out[r, c] * h + F[j, r, c] / (j + 1)
    for r in range(out.shape[0]):
        for c in range(out.shape[1]):
            out[r, c] *= h


def discretize(A: np.ndarray, Qc: np.ndarray, B: np.ndarray | None, dt: float,
               series: VanLoanSeries | None = None
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """Phi, Qd, Bd (None without B) for one step of ``dt`` >= 0 seconds (see the module doc).
    ``series``: the model's :class:`VanLoanSeries`, when the caller keeps it."""
    vl = VanLoanSeries(A, Qc, B) if series is None else series
    n = vl.n
    Phi, Qd, Bd = np.empty((n, n)), np.empty((n, n)), np.empty((n, vl.p))
    van_loan(*vl.args(), float(dt), Phi, Qd, Bd, np.empty((3, n, n)))
    return Phi, Qd, (None if B is None else Bd)


def discretize_all(series: VanLoanSeries, dt: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Phi (N, n, n), Qd (N, n, n), Bd (N, n, p) for every dt of an array (compiled loop)."""
    dt = np.ascontiguousarray(dt, dtype=float)
    N, n = dt.size, series.n
    Phi, Qd, Bd = np.empty((N, n, n)), np.empty((N, n, n)), np.empty((N, n, series.p))
    _discretize_all(*series.args(), dt, Phi, Qd, Bd)
    return Phi, Qd, Bd


@njit(cache=True, error_model="numpy", nogil=True)
def _discretize_all(F, G, C, norm, dt, Phi, Qd, Bd):
    work = np.empty((3, Phi.shape[1], Phi.shape[1]))
    for k in range(dt.shape[0]):
        if k > 0 and dt[k] == dt[k - 1]:
            Phi[k] = Phi[k - 1]
            Qd[k] = Qd[k - 1]
            Bd[k] = Bd[k - 1]
        else:
            van_loan(F, G, C, norm, dt[k], Phi[k], Qd[k], Bd[k], work)
