"""The second GLR pass (glr module docstring, "Is the fault explained?"): the signature of the
fitted fault, removed from the innovations, and every hypothesis tested again *given* it.
Built on :mod:`.glr`'s two-level scan (same blocks, same systems)."""
from __future__ import annotations

import numpy as np

from .glr import NONE, _Filter, _Hypothesis, _mul, _System
from .models import LinearModel


def scan_num(system: _System) -> np.ndarray:
    """num(theta) = e^T lambda_theta alone (the lambda recursion of :func:`_scan` without M):
    about a third of its cost, for the second pass, whose den and cross are the first pass's."""
    nb, B = system.flt.nb, system.flt.B
    p, i0 = system.p, system.i0
    lam = np.zeros((nb, p, 1))
    T = np.broadcast_to(np.eye(p), (nb, p, p)).copy()
    num_loc = np.empty((B, nb))
    v = np.empty((B, nb, p))
    for j in range(B - 1, -1, -1):
        F, _, c = system.column(j, with_q=False)
        lam = np.swapaxes(F, 1, 2) @ lam
        lam[:, :, 0] += c
        T = T @ F
        num_loc[j] = lam[:, i0, 0]
        v[j] = T[:, :, i0]
    lam = lam[:, :, 0]
    lam_e = np.zeros((nb, p))
    for b in range(nb - 2, -1, -1):
        lam_e[b] = lam[b + 1] + T[b + 1].T @ lam_e[b + 1]
    return (num_loc + np.einsum("jbp,bp->jb", v, lam_e)).T.reshape(-1)


def signature(system: _System, k0: int) -> np.ndarray:
    """rho_k of a unit fault of ``system`` starting at sample k0, position-major (B, nb, m)
    like ``_Filter.w``: the block of k0 step by step, then the later blocks' start states
    through their transfer matrices and all of them together (~3 sqrt(N) vectorised steps)."""
    flt = system.flt
    nb, B, p = flt.nb, flt.B, system.p
    b0, j0 = divmod(int(k0), B)
    rho = np.zeros((B, nb, system.m))
    s = np.zeros(p)
    s[system.i0] = 1.0
    for j in range(j0, B):
        F, _, _ = system.column(j)
        rho[j, b0] = system.Ct[j, b0].T @ s
        s = F[b0] @ s
    later = nb - b0 - 1
    if later > 0:
        T = np.broadcast_to(np.eye(p), (later, p, p)).copy()
        for j in range(B):
            F, _, _ = system.column(j)
            T = F[b0 + 1:] @ T
        x = np.zeros((later, p))
        x[0] = s
        for i in range(1, later):
            x[i] = T[i - 1] @ x[i - 1]
        for j in range(B):
            F, _, _ = system.column(j)
            rho[j, b0 + 1:] = np.einsum("bpm,bp->bm", system.Ct[j, b0 + 1:], x)
            x = np.einsum("bpq,bq->bp", F[b0 + 1:], x)
    return rho


def residual_pass(model: LinearModel, hyps: list, flt: _Filter, raw: dict, best: _Hypothesis,
                   k0: int) -> dict:
    """Remove the fitted fault (best, onset k0) from the innovations and test what is left:
    for every hypothesis h2 and onset, the GLR of h2 *given* the first fault (both fitted
    jointly): with n_i, d_ij the inner products of the first pass and n2' the numerator on the
    residual, l2 = n2'^2 / (d22 - d12^2 / d11), chi2(1) for each onset when one fault explains
    the data (d12 comes from n2 - n2' = mu1 d12)."""
    num1, den1, _ = raw[best.name]
    mu1 = num1[k0] / den1[k0]
    rho = signature(_System(model, best, flt), k0)
    w = flt.w - mu1 * _mul(flt.Sinv, rho[..., None])[..., 0]
    rest = _Filter(flt.t, flt.nb, flt.B, flt.PhiN, flt.A, flt.G, flt.H, flt.Sinv, w,
                   flt.dt_key, flt.dt_values)
    top = {"hypothesis": NONE, "onset_index": None, "onset_t": None, "statistic": 0.0}
    for hyp in hyps:
        n2r = scan_num(_System(model, hyp, rest))[:flt.t.size]
        n2, d22, _ = raw[hyp.name]
        d12 = (n2 - n2r) / mu1 if mu1 != 0.0 else np.zeros_like(n2)
        cond = d22 - d12 ** 2 / den1[k0]
        ok = cond > 1e-6 * np.maximum(d22, 1e-300)
        l2 = np.zeros_like(n2)
        l2[ok] = n2r[ok] ** 2 / cond[ok]
        k = int(np.argmax(l2))
        if l2[k] > top["statistic"]:
            top = {"hypothesis": hyp.name, "onset_index": k, "onset_t": float(flt.t[k]),
                   "statistic": float(l2[k])}
    return top


