"""UDU^T and LDL^T decompositions and the seed method's element terms (SPEC section 3; seed 000,
formulas 7.12-7.17), compiled (numba) for one matrix and looped over stacks.

* :func:`udu` -- P = U diag(D) U^T with U unit upper triangular (bottom-up, 7.15).
* :func:`ldl` -- W = L diag(Lam) L^T with L unit lower triangular (top-down), for positive
  *semi*definite W: a pivot at or below ``rank_tol`` times its reference counts as zero.
* :func:`localize` -- the decomposition of J into element terms and the first element whose
  cumulative bound J(i/k) <= gamma_k^2 = k + 3 sqrt(2k) is violated (7.16, 7.17), from the
  difference covariance dP (seed form) or from its information W = dP^-1 (information form).

Information form (used over a flight, where the backward information Y is often singular):
W = L Lam L^T with L = dU^-T and Lam = dD^-1. With q = L^-1 (W v) = Lam L^T v = Lam v~, the k-th
term is v~_k^2 / dD_kk = q_k^2 / Lam_k. A pivot Lam_k that is zero (no backward information on
element k given elements 1..k-1) contributes 0 and one degree of freedom fewer. Pivots are judged
relative to the same pivot of the forward information P_f^-1, which bounds W from above.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numba import njit

from .errors import CoreError

DEFAULT_RANK_TOL = 1e-9


def seed_threshold(dof: Any) -> np.ndarray:
    """gamma^2 = k + 3 sqrt(2k) for k degrees of freedom (7.14, 7.17); NaN where k = 0."""
    k = np.asarray(dof, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.where(k > 0, k + 3.0 * np.sqrt(2.0 * k), np.nan)


# --------------------------------------------------------------------------- kernels

@njit(cache=True, error_model="numpy", inline="always")
def udu_factor(P, U, D):
    """P = U diag(D) U^T, bottom-up. Returns the first pivot index that is not > 0, or -1."""
    n = P.shape[0]
    for j in range(n - 1, -1, -1):
        # D_j = P_jj - sum_{k>j} U_jk^2 D_k
        d = P[j, j]
        for k in range(j + 1, n):
            d -= U[j, k] * U[j, k] * D[k]
        D[j] = d
        U[j, j] = 1.0
        for i in range(j + 1, n):
            U[i, j] = 0.0
        if not d > 0.0:
            return j
        # U_ij = (P_ij - sum_{k>j} U_ik U_jk D_k) / D_j,  i < j
        for i in range(j):
            acc = P[i, j]
            for k in range(j + 1, n):
                acc -= U[i, k] * U[j, k] * D[k]
            U[i, j] = acc / d
    return -1


@njit(cache=True, error_model="numpy", inline="always")
def ldl_factor(W, ref, rank_tol, L, Lam, informative):
    """W = L diag(Lam) L^T, top-down; pivot j is zero (not informative) when it is at or below
    rank_tol * ref[j], and its column of L is then that of the identity."""
    n = W.shape[0]
    for j in range(n):
        # pivot = W_jj - sum_{k<j} L_jk^2 Lam_k
        piv = W[j, j]
        for k in range(j):
            piv -= L[j, k] * L[j, k] * Lam[k]
        ok = piv > rank_tol * ref[j]
        informative[j] = ok
        Lam[j] = piv if ok else 0.0
        L[j, j] = 1.0
        for i in range(j):
            L[i, j] = 0.0
        for i in range(j + 1, n):
            if ok:
                acc = W[i, j]
                for k in range(j):
                    acc -= L[i, k] * L[j, k] * Lam[k]
                L[i, j] = acc / piv
            else:
                L[i, j] = 0.0


@njit(cache=True, error_model="numpy", inline="always")
def information_terms(L, Lam, informative, Wv, q, v_tilde, d, terms, dof, normalized):
    """The element terms of J in information form: q = L^-1 (W v) (forward substitution),
    term_k = q_k^2 / Lam_k, v~_k = q_k / Lam_k, dD_k = 1 / Lam_k, normalized v~_k / sqrt(dD_k) =
    q_k / sqrt(Lam_k); cumulative terms J(i/k) and effective degrees of freedom."""
    n = Lam.shape[0]
    total = 0.0
    count = 0
    for k in range(n):
        acc = Wv[k]
        for j in range(k):
            acc -= L[k, j] * q[j]
        q[k] = acc
        if informative[k]:
            total += q[k] * q[k] / Lam[k]
            count += 1
            v_tilde[k] = q[k] / Lam[k]
            d[k] = 1.0 / Lam[k]
            normalized[k] = q[k] / np.sqrt(Lam[k])
        else:
            v_tilde[k] = np.nan
            d[k] = np.inf
            normalized[k] = np.nan
        terms[k] = total
        dof[k] = count


@njit(cache=True, error_model="numpy", nogil=True)
def _udu_stack(P, U, D):
    for i in range(P.shape[0]):
        bad = udu_factor(P[i], U[i], D[i])
        if bad >= 0:
            return bad
    return -1


@njit(cache=True, error_model="numpy", nogil=True)
def _ldl_stack(W, ref, rank_tol, L, Lam, informative):
    for i in range(W.shape[0]):
        ldl_factor(W[i], ref[i], rank_tol, L[i], Lam[i], informative[i])


@njit(cache=True, error_model="numpy", nogil=True)
def _terms_stack(W, Wv, ref, rank_tol, L, Lam, informative, v_tilde, d, terms, dof, normalized):
    q = np.empty(W.shape[1])
    for i in range(W.shape[0]):
        ldl_factor(W[i], ref[i], rank_tol, L[i], Lam[i], informative[i])
        information_terms(L[i], Lam[i], informative[i], Wv[i], q, v_tilde[i], d[i], terms[i],
                          dof[i], normalized[i])


# --------------------------------------------------------------------------- numpy interface

def _square(P: Any, what: str) -> np.ndarray:
    arr = np.asarray(P, dtype=float)
    if arr.ndim < 2 or arr.shape[-1] != arr.shape[-2]:
        raise CoreError(f"{what}: expected square matrices, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"{what}: contains NaN or Inf")
    sym = np.abs(arr - np.swapaxes(arr, -1, -2))
    if np.any(sym > 1e-9 * np.maximum(np.abs(arr), np.abs(np.swapaxes(arr, -1, -2))) + 1e-300):
        raise CoreError(f"{what}: not symmetric")
    return arr


def _stack(A: np.ndarray) -> np.ndarray:
    n = A.shape[-1]
    return np.ascontiguousarray(A, dtype=float).reshape(-1, n, n)


def udu(P: Any, *, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """U, D with P = U diag(D) U^T, U unit upper triangular (bottom-up). Works on stacks
    (..., n, n). P must be symmetric positive definite (CoreError otherwise; ``check=False``
    skips the finiteness / symmetry checks for arrays the core computed itself)."""
    A = _square(P, "udu") if check else np.asarray(P, dtype=float)
    S = _stack(A)
    U = np.empty(S.shape)
    D = np.empty(S.shape[:-1])
    bad = _udu_stack(S, U, D)
    if bad >= 0:
        raise CoreError(f"udu: matrix is not positive definite (pivot {bad} = "
                        f"{np.nanmin(D[:, bad]):.3g})")
    return U.reshape(A.shape), D.reshape(A.shape[:-1])


def ldl(W: Any, ref: Any = None, rank_tol: float = DEFAULT_RANK_TOL, *, check: bool = True
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """L, Lam, informative with W = L diag(Lam) L^T, L unit lower triangular (top-down), for
    symmetric positive *semi*definite W (stacks allowed). Pivot k counts as zero when
    Lam_k <= rank_tol * ref_k (``ref``: reference pivots, default the diagonal of W); its
    column of L is then left as that of the identity."""
    A = _square(W, "ldl") if check else np.asarray(W, dtype=float)
    n = A.shape[-1]
    refs = (np.abs(A[..., np.arange(n), np.arange(n)]) if ref is None
            else np.broadcast_to(np.asarray(ref, dtype=float), A.shape[:-1]))
    S = _stack(A)
    L = np.empty(S.shape)
    Lam = np.empty(S.shape[:-1])
    inf = np.empty(S.shape[:-1], dtype=bool)
    _ldl_stack(S, np.ascontiguousarray(refs).reshape(-1, n), float(rank_tol), L, Lam, inf)
    return L.reshape(A.shape), Lam.reshape(A.shape[:-1]), inf.reshape(A.shape[:-1])


@dataclass
class Localization:
    """The decomposition of J into element terms (7.16, 7.17); arrays over elements k.

    v_tilde: dU^-1 v (NaN where an element carries no information); d: dD (inf there);
    terms: cumulative J(i/k); J: the total; gammas: gamma^2 for the cumulative effective degrees
    of freedom ``dof`` (NaN while 0); element: index of the first k with J(i/k) > gamma_k^2, or
    None. For stacks of steps, ``element`` is an integer array with -1 for none.
    """

    v_tilde: np.ndarray
    d: np.ndarray
    terms: np.ndarray
    J: Any
    gammas: np.ndarray
    element: Any
    dof: np.ndarray
    normalized: np.ndarray = field(default_factory=lambda: np.zeros(0))  # v~_k / sqrt(d_k)


def first_violation(terms: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gamma^2 of every cumulative term, index of the first violated element or -1)."""
    gammas = seed_threshold(dof)
    with np.errstate(invalid="ignore"):
        viol = (dof > 0) & (terms > gammas)
    first = np.where(viol.any(axis=-1), np.argmax(viol, axis=-1), -1)
    return gammas, first


def localization(v_tilde: np.ndarray, d: np.ndarray, terms: np.ndarray, dof: np.ndarray,
                 normalized: np.ndarray) -> Localization:
    """A :class:`Localization` from the element terms (one vector or stacks)."""
    gammas, first = first_violation(terms, dof)
    if terms.ndim == 1:
        element: Any = None if first < 0 else int(first)
        J: Any = float(terms[-1])
    else:
        element, J = first, terms[..., -1]
    return Localization(v_tilde=v_tilde, d=d, terms=terms, J=J, gammas=gammas, element=element,
                        dof=dof, normalized=normalized)


def _vector(v: Any, what: str) -> np.ndarray:
    vv = np.asarray(v, dtype=float)
    if not np.all(np.isfinite(vv)):
        raise CoreError(f"localize: {what} contains NaN or Inf")
    return vv


def localize(v: Any = None, dP: Any = None, W: Any = None, Wv: Any = None, ref: Any = None,
             rank_tol: float = DEFAULT_RANK_TOL, *, check: bool = True) -> Localization:
    """Localize a violation to a state element.

    Seed form: ``localize(v, dP=dP)`` -- dP = U D U^T, v~ = U^-1 v, term_k = v~_k^2 / D_k.
    Information form: ``localize(v, W=W)`` or ``localize(Wv=Wv, W=W)`` (W v is defined even
    where v is not) -- W = L Lam L^T, q = L^-1 (W v), term_k = q_k^2 / Lam_k, 0 where Lam_k is
    zero (see :func:`ldl`; ``ref`` are the reference pivots, e.g. 1 / udu(P_f)[1]).
    Works on one vector (n,) or stacks (..., n). ``check=False`` skips the input checks (for
    arrays the core computed itself).
    """
    if (dP is None) == (W is None):
        raise CoreError("localize: give exactly one of dP (seed form) and W (information form)")
    if dP is not None:
        if v is None:
            raise CoreError("localize: the seed form needs v")
        vv = _vector(v, "v")
        U, D = udu(dP)
        if vv.shape != D.shape:
            raise CoreError(f"localize: v has shape {vv.shape}, dP {np.shape(dP)}")
        vt = vv.copy()
        for i in range(vt.shape[-1] - 2, -1, -1):  # v~ = U^-1 v (back substitution)
            vt[..., i] -= np.einsum("...k,...k->...", U[..., i, i + 1:], vt[..., i + 1:])
        terms = np.cumsum(vt * vt / D, axis=-1)
        dof = np.cumsum(np.ones(D.shape, dtype=np.int64), axis=-1)
        return localization(vt, D, terms, dof, vt / np.sqrt(D))
    Wm = _square(W, "ldl") if check else np.asarray(W, dtype=float)
    if Wv is None:
        if v is None:
            raise CoreError("localize: the information form needs v or Wv")
        Wvv = np.einsum("...ij,...j->...i", Wm, _vector(v, "v"))
    else:
        Wvv = np.asarray(Wv, dtype=float)
        if check and not np.all(np.isfinite(Wvv)):
            raise CoreError("localize: W v contains NaN or Inf")
    n = Wm.shape[-1]
    if Wvv.shape != Wm.shape[:-1]:
        raise CoreError(f"localize: W v has shape {Wvv.shape}, W {Wm.shape}")
    refs = (np.abs(Wm[..., np.arange(n), np.arange(n)]) if ref is None
            else np.broadcast_to(np.asarray(ref, dtype=float), Wm.shape[:-1]))
    shape = Wvv.shape
    S = _stack(Wm)
    K = S.shape[0]
    vt, d, terms, normalized = (np.empty((K, n)) for _ in range(4))
    dof = np.empty((K, n), dtype=np.int64)
    _terms_stack(S, np.ascontiguousarray(Wvv).reshape(K, n),
                 np.ascontiguousarray(refs).reshape(K, n), float(rank_tol), np.empty(S.shape),
                 np.empty((K, n)), np.empty((K, n), dtype=bool), vt, d, terms, dof, normalized)
    return localization(vt.reshape(shape), d.reshape(shape), terms.reshape(shape),
                        dof.reshape(shape), normalized.reshape(shape))
