"""The Taylor coefficients of a model's Van Loan blocks (:class:`VanLoanSeries`), computed once per
model with numpy -- the inputs of the compiled discretization (:mod:`flight_fdi.core.discretize`,
whose module doc has the method). A module of its own so that building a model's scaled form
(``core.scaled``, at a filter's construction) does not import numba: a filter node loads it at
its first step."""
from __future__ import annotations

import numpy as np

#: coefficients kept: enough for ||A h||_1 <= discretize.THETA to rounding
TERMS = 20


class VanLoanSeries:
    """The Taylor coefficients of the Van Loan blocks of one model, in powers of dt::

        Phi(h) = sum_j h^j F[j],      F[j] = A^j / j!
        Bd(h)  = h sum_j h^j G[j],    G[j] = A^j B / (j+1)!
        Qd(h)  = h sum_j h^j C[j],    C[j] = M_{j+1} / (j+1)!,  M_1 = Qc,  M_{k+1} = A M_k + M_k A^T

    computed once per model (``TERMS`` coefficients each); ``norm`` = ||A||_1. The compiled
    :func:`~flight_fdi.core.discretize.van_loan` then costs O(terms n^2) per dt instead of
    O(terms n^3).
    """

    def __init__(self, A: np.ndarray, Qc: np.ndarray, B: np.ndarray | None) -> None:
        A = np.ascontiguousarray(A, dtype=float)
        n = A.shape[0]
        Bm = np.zeros((n, 0)) if B is None else np.ascontiguousarray(B, dtype=float)
        F = np.empty((TERMS, n, n))
        G = np.empty((TERMS, n, Bm.shape[1]))
        C = np.empty((TERMS, n, n))
        F[0] = np.eye(n)
        Qc = np.asarray(Qc, dtype=float)
        C[0] = 0.5 * (Qc + Qc.T)
        for j in range(1, TERMS):
            F[j] = F[j - 1] @ A / j
            AC = A @ C[j - 1]
            C[j] = (AC + AC.T) / (j + 1)            # (exactly symmetric: C[j-1] is)
        for j in range(TERMS):
            G[j] = F[j] @ Bm / (j + 1)
        self.F, self.G, self.C = F, G, C
        self.norm = float(np.abs(A).sum(axis=0).max())
        self.n, self.p = n, Bm.shape[1]

    def args(self) -> tuple:
        """(F, G, C, norm): the first arguments of :func:`~flight_fdi.core.discretize.van_loan`."""
        return self.F, self.G, self.C, self.norm
