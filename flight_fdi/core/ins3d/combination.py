"""The two-filter combination of the ins3d backward sweep (``backward.py``) at a boundary with
reference updates: from the forward prior (x_f, P_f) and the sweep's W = Lambda, W v = lambda
there (Bryson-Frazier adjoint form)::

    x_s = x_f + P_f W v,    P_s = P_f - P_f W P_f,

the seed method's element terms (UDU' of P_f for the reference pivots, LDL' of W:
``core.ldl``) and the outlier information of each update. ``combine_boundary`` is called by the
sweep itself (one thread) or, from the (lambda, Lambda) the sweep kept, by ``combine_kept``
on a second thread while the sweep goes on (``postflight.run_backward``): the same arithmetic.
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..ldl import information_terms, ldl_factor, udu_factor
from .filter import scaled_H
from .sparse import mul_left


@njit(cache=True, inline="always")
def _combine(lam, Lam, xf, Pf, rank_tol, x_s, PW, U, ref, L, Lam_d, informative, q, vt, dd,
             terms, dof, norm, ps_diag):
    """The two-filter combination at a boundary from W = Lambda, W v = lambda (module
    docstring): x_s, diag P_s, P_f W, and the seed method's element terms (UDU' of P_f for the
    reference pivots, LDL' of W: ``core.ldl``). False when P_f is not positive definite."""
    n = xf.size
    for a in range(n):
        acc = xf[a]
        for b in range(n):
            acc += Pf[a, b] * lam[b]
        x_s[a] = acc
    PW[:, :] = 0.0
    mul_left(Pf, Lam, PW, False)
    for a in range(n):
        acc = Pf[a, a]
        for b in range(n):
            acc -= PW[a, b] * Pf[b, a]
        ps_diag[a] = acc
    if udu_factor(Pf, U, ref) >= 0:
        return False
    for k in range(n):
        ref[k] = 1.0 / ref[k]
    ldl_factor(Lam, ref, rank_tol, L, Lam_d, informative)
    information_terms(L, Lam_d, informative, lam, q, vt, dd, terms, dof, norm)
    return True


@njit(cache=True)
def _outliers(Hs, z_j, r_j, x_s, Pf, PW, e_o, I_o, HP, HPW):
    """Outlier information of one update: eta = R^-1 (z - H x_s), I = R^-1 - R^-1 H P_s H' R^-1
    with H P_s H' = H P_f H' - (H P_f W) (P_f H')."""
    rows, n = Hs.shape
    for i in range(rows):
        for b in range(n):
            HP[i, b] = 0.0
            HPW[i, b] = 0.0
        for a in range(n):
            h = Hs[i, a]
            if h != 0.0:
                for b in range(n):
                    HP[i, b] += h * Pf[a, b]
                    HPW[i, b] += h * PW[a, b]
    for i in range(rows):
        res = z_j[i]
        for a in range(n):
            res -= Hs[i, a] * x_s[a]
        e_o[i] = res / r_j[i]
        for k in range(rows):
            acc = 0.0
            for a in range(n):
                acc += HP[i, a] * Hs[k, a] - HPW[i, a] * HP[k, a]
            I_o[i, k] = (1.0 / r_j[i] if i == k else 0.0) - acc / (r_j[i] * r_j[k])


@njit(cache=True)
def _write_combination(j0, j1, s, x_s, psd, vt, dd, x_s_o, sd_s_o, terms_o, dof_o, norm_o,
                       vt_o, d_o):
    """The combination of one boundary into the rows j0..j1-1 (physical units)."""
    n = s.size
    for j in range(j0, j1):
        for a in range(n):
            x_s_o[j, a] = x_s[a] * s[a]
            sd_s_o[j, a] = np.sqrt(max(psd[a], 0.0)) * s[a]
            terms_o[j, a] = terms_o[j0, a]
            dof_o[j, a] = dof_o[j0, a]
            norm_o[j, a] = norm_o[j0, a]
            vt_o[j, a] = vt[a] * s[a]
            d_o[j, a] = dd[a] * s[a] * s[a]


@njit(cache=True)
def combination_scratch(n, rows):
    """The work arrays of ``combine_boundary`` (n states, ``rows`` reference rows)."""
    return (np.empty(n), np.empty((n, n)), np.empty((n, n)), np.empty((n, n)),
            np.empty((rows, n)), np.empty((rows, n)), np.empty(n), np.empty(n), np.empty(n),
            np.empty(n), np.empty(n), np.empty(n), np.empty(n, dtype=np.bool_))


@njit(cache=True)
def combine_boundary(j0, j1, lam, Lam, s, acc, il, im, rows, hu, z, r, x_pr, P_pr, rank_tol, out,
                     work):
    """The combination at the boundary of the updates j0 .. j1-1 (scaled x_pr, P_pr: the
    forward prior; lam, Lam: the sweep's there) into the rows j0 .. j1-1 of ``out`` = (x_s,
    sd_s, terms, dof, normalized, v~, dD, oe, oI), physical units. False when P_f is not
    positive definite."""
    x_s_o, sd_s_o, terms_o, dof_o, norm_o, vt_o, d_o, oe_o, oI_o = out
    x_s, PW, U, L, HP, HPW, ref, Lam_d, q, vt, dd, psd, informative = work
    Pf = P_pr[j0]
    if not _combine(lam, Lam, x_pr[j0], Pf, rank_tol, x_s, PW, U, ref, L, Lam_d, informative,
                    q, vt, dd, terms_o[j0], dof_o[j0], norm_o[j0], psd):
        return False
    _write_combination(j0, j1, s, x_s, psd, vt, dd, x_s_o, sd_s_o, terms_o, dof_o, norm_o,
                       vt_o, d_o)
    for j in range(j0, j1):
        _outliers(scaled_H(s, acc[j], il, im, rows, hu), z[j], r[j], x_s, Pf, PW, oe_o[j], oI_o[j],
                  HP, HPW)
    return True


@njit(cache=True, nogil=True)
def combine_kept(count, kb, jb, lam_b, Lam_b, s, acc, il, im, rows, hu, z, r, x_pr, P_pr, rank_tol,
                 out):
    """``combine_boundary`` at the ``count`` boundaries the sweep kept (``backward_sweep`` with
    ``part`` & 4). Returns the boundary where P_f is not positive definite, or -1."""
    work = combination_scratch(s.size, rows)
    for u in range(count):
        if not combine_boundary(jb[u, 0], jb[u, 1], lam_b[u], Lam_b[u], s, acc, il, im, rows, hu, z,
                                r, x_pr, P_pr, rank_tol, out, work):
            return kb[u]
    return -1


__all__ = ["combination_scratch", "combine_boundary", "combine_kept"]
