"""The GLR signature recursion and the onset search, compiled (numba); the math is in the
:mod:`flight_fdi.core.glr` docstring ("Signature recursion"). Scaled coordinates throughout.

The forward filter, for the step k -> k+1 (Phi_{k+1} of dt[k+1]; K_k = 0 where not fused)::

    A_k = Phi_{k+1} (I - K_k H_k),   G_k = Phi_{k+1} K_k

A fault hypothesis is a fault state f (q elements) with ``f_{k+1} = Psi_{k+1} f_k``
(Psi = expm(A_bar dt) for a step or a ramp, 1 for a jump, 0 for an outlier) that shows in the
measurement as ``D_k f`` with ``D_k = H_k E + R_sel`` (E: fault state -> state deviation, R_sel:
fault state -> measurement row). With the filter's response d (= delta x_hat_{k|k-1})::

    rho_k   = D_k f_k - H_k d_k                      the signature
    d_{k+1} = A_k d_k + G_k D_k f_k                  (= Phi_{k+1} (d_k + K_k rho_k))

i.e. s = [f; d], ``s_{k+1} = F_k s_k``, ``rho_k = C_k s_k`` with
``F_k = [[Psi, 0], [G D, A]]`` and ``C_k = [D, -H]``. Every onset theta at once, backwards::

    lambda_k = C_k^T w_k + F_k^T lambda_{k+1}          (w_k = S_k^-1 nu_k)
    M_k      = C_k^T S_k^-1 C_k + F_k^T M_{k+1} F_k
    num(theta) = lambda_theta[i0],  den(theta) = M_theta[i0, i0],
    cross(theta) = (M_{theta+1} F_theta)[i0, i0] = <rho(theta), rho(theta+1)>_{S^-1}

In blocks (M = [[M_ff, M_fd], [M_df, M_dd]], lambda = [lambda_f; lambda_d]) the d-blocks do
not depend on the hypothesis (:func:`filter_information`, once per flight)::

    M_dd     <- A^T M_dd A + H^T S^-1 H,        lambda_d <- A^T lambda_d - H^T w

and each hypothesis adds its f-blocks (:func:`hypothesis_scan`), with GD = G D (the products
with M_dd and lambda_d through G, shared by the hypotheses: M_dd G, G^T M_dd G, G^T lambda_d)::

    M_ff     <- Psi^T M_ff Psi + Y + Y^T + GD^T M_dd GD + D^T S^-1 D,   Y = Psi^T M_fd GD
    M_fd     <- (Psi^T M_fd + GD^T M_dd) A - D^T S^-1 H
    lambda_f <- Psi^T lambda_f + GD^T lambda_d + D^T w

The three recursions over the samples (:func:`filter_information`, :func:`hypothesis_scan`,
:func:`hypothesis_num`) are compiled per size (n, m, q) with the sizes as compile-time
constants for the INS channel's fault systems (:data:`SPECIALISED`; LLVM unrolls their small
loops, ~2.5x faster), and generically for any other size: :func:`kernel_for`. Same source, same
order of operations, the same bits. No numpy product over the flight's arrays is left outside
the kernels (a multithreaded BLAS would split it and leave its threads spinning).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .discretize import expm_series, matmul, matmul_sized


@njit(cache=True, error_model="numpy", nogil=True)
def transitions(F, norm, dt, H, K, A, G):
    """A_k = Phi_{k+1} (I - K_k H_k), G_k = Phi_{k+1} K_k for k < N-1 (zero at N-1: nothing
    follows the last sample). F, norm: the filter model's series (Phi = expm(A dt) per new dt)."""
    N, m, n = H.shape
    Phi, work = np.zeros((n, n)), np.empty((n, n))
    dt_held = np.nan
    A[N - 1] = 0.0
    G[N - 1] = 0.0
    for k in range(N - 1):
        if not dt[k + 1] == dt_held:
            expm_series(F, norm, dt[k + 1], Phi, work)
            dt_held = dt[k + 1]
        matmul(Phi, K[k], G[k])
        for r in range(n):
            for c in range(n):
                acc = Phi[r, c]
                for i in range(m):
                    acc -= G[k, r, i] * H[k, i, c]
                A[k, r, c] = acc


@njit(cache=True, error_model="numpy", nogil=True)
def fault_measurement(H, E, R_sel, D):
    """D_k = H_k E + R_sel for every sample: how the fault state shows in the measurement
    (compiled rather than one numpy product over all samples, which a multithreaded BLAS would
    split across threads that then spin beside the scan)."""
    for k in range(H.shape[0]):
        matmul(H[k], E, D[k])
        for i in range(D.shape[1]):
            for a in range(D.shape[2]):
                D[k, i, a] += R_sel[i, a]


@njit(cache=True, error_model="numpy", inline="always")
def fault_transition(Fpsi, norm_psi, persists, dt, Psi, work):
    """Psi = expm(A_bar dt) of the fault state (its series Fpsi), with the rows and columns of
    the one-sample elements (an outlier: ``persists`` False) zeroed."""
    expm_series(Fpsi, norm_psi, dt, Psi, work)
    for a in range(Psi.shape[0]):
        if not persists[a]:
            for b in range(Psi.shape[0]):
                Psi[a, b] = 0.0
                Psi[b, a] = 0.0


@njit(cache=True, error_model="numpy", inline="always")
def psi_at(k, dt, dt_held, Fpsi, norm_psi, persists, Psi, work):
    """Psi_{k+1} into Psi, recomputed only for a new dt (none after the last sample); returns
    the dt Psi is held for."""
    if k < dt.shape[0] - 1 and not dt[k + 1] == dt_held:
        fault_transition(Fpsi, norm_psi, persists, dt[k + 1], Psi, work)
        dt_held = dt[k + 1]
    return dt_held


@njit(cache=True, error_model="numpy", inline="always")
def lambda_f_step(Psi, D, Glam_k, w_k, lam_f, lam_new, q, m):
    """lambda_f <- Psi^T lambda_f + GD^T lambda_d + D^T w = Psi^T lambda_f + D^T (Glam + w)
    (q fault states, m measurements)."""
    for a in range(q):
        acc = 0.0
        for b in range(q):
            acc += Psi[b, a] * lam_f[b]
        for i in range(m):
            acc += D[i, a] * (Glam_k[i] + w_k[i])
        lam_new[a] = acc
    for a in range(q):
        lam_f[a] = lam_new[a]


#: the (n, m, q) compiled with constant sizes: the INS channel's fault systems (a step or ramp
#: of an instrument, 4 fault states; the reference's jump and outlier, 2). LLVM unrolls their
#: loops; any other size runs the generic scan (sizes read from the arrays), same arithmetic.
SPECIALISED = ((4, 1, 4), (4, 1, 2))


def _scan(sizes):
    """:func:`hypothesis_scan` compiled for ``sizes`` = (n, m, q) (all 0: read from the
    arrays). numba keys its cache on the closure's value: each size compiles once."""
    n_fixed, m_fixed, q_fixed = sizes

    @njit(cache=True, error_model="numpy", nogil=True)
    def hypothesis_scan(A, G, H, Sinv, w, dt, MG, GMG, Glam, D_all, Fpsi, norm_psi, persists,
                        i0, num, den, cross):
        """num[h], den[h], cross[h] for every onset (module doc) of the faults that enter as
        f = e_i0[h] (several hypotheses can share one fault state, e.g. a step and a ramp of
        the same instrument: the step's states are part of the ramp's). A, G:
        :func:`transitions`; MG, GMG, Glam: :func:`filter_information` (so that GD^T M_dd =
        D^T MG^T, GD^T M_dd GD = D^T GMG D, GD^T lambda_d = D^T Glam); D_all: D_k of every
        sample."""
        N = H.shape[0]
        n = H.shape[2] if n_fixed == 0 else n_fixed
        m = H.shape[1] if m_fixed == 0 else m_fixed
        q = D_all.shape[2] if q_fixed == 0 else q_fixed
        Mff, Mfd, lam_f = np.zeros((q, q)), np.zeros((q, n)), np.zeros(q)
        Psi, work = np.zeros((q, q)), np.empty((q, q))
        GD, SD = np.empty((n, q)), np.empty((m, q))
        MddGD, GMGD = np.empty((n, q)), np.empty((m, q))
        PtMfd, PtMfdG, Y = np.empty((q, n)), np.empty((q, m)), np.empty((q, q))
        PtMff, Mff_new, lam_new = np.empty((q, q)), np.empty((q, q)), np.empty(q)
        dt_held = np.nan
        for k in range(N - 1, -1, -1):
            dt_held = psi_at(k, dt, dt_held, Fpsi, norm_psi, persists, Psi, work)
            D, Gk = D_all[k], G[k]
            matmul_sized(Gk, D, GD, n, m, q)
            matmul_sized(Sinv[k], D, SD, m, m, q)
            for h in range(i0.shape[0]):            # cross = (M_ff Psi + M_fd GD)[i0, i0]
                e = i0[h]
                acc = 0.0
                for a in range(q):
                    acc += Mff[e, a] * Psi[a, e]
                for b in range(n):
                    acc += Mfd[e, b] * GD[b, e]
                cross[h, k] = acc
            lambda_f_step(Psi, D, Glam[k], w[k], lam_f, lam_new, q, m)
            matmul_sized(Psi.T, Mfd, PtMfd, q, q, n)
            matmul_sized(PtMfd, Gk, PtMfdG, q, n, m)
            matmul_sized(PtMfdG, D, Y, q, m, q)     # Y = Psi^T M_fd GD
            matmul_sized(MG[k], D, MddGD, n, m, q)  # M_dd GD
            matmul_sized(GMG[k], D, GMGD, m, m, q)
            matmul_sized(Psi.T, Mff, PtMff, q, q, q)
            matmul_sized(PtMff, Psi, Mff_new, q, q, q)
            for a in range(q):                      # M_ff
                for b in range(a, q):
                    acc = Mff_new[a, b] + Y[a, b] + Y[b, a]
                    for i in range(m):
                        acc += D[i, a] * (GMGD[i, b] + SD[i, b])
                    Mff[a, b] = acc
                    Mff[b, a] = acc
            for a in range(q):          # M_fd = (Psi^T M_fd + GD^T M_dd) A - D^T S^-1 H
                for b in range(n):
                    PtMfd[a, b] += MddGD[b, a]
            matmul_sized(PtMfd, A[k], Mfd, q, n, n)
            for a in range(q):
                for b in range(n):
                    acc = 0.0
                    for i in range(m):
                        acc += SD[i, a] * H[k, i, b]
                    Mfd[a, b] -= acc
            for h in range(i0.shape[0]):
                num[h, k] = lam_f[i0[h]]
                den[h, k] = Mff[i0[h], i0[h]]

    return hypothesis_scan


def _information(sizes):
    """:func:`filter_information` compiled for ``sizes`` = (n, m, q) (q unused)."""
    n_fixed, m_fixed, _ = sizes

    @njit(cache=True, error_model="numpy", nogil=True)
    def filter_information(A, G, H, Sinv, w, with_M, MG, GMG, Glam):
        """The hypothesis-free d-blocks M_dd, lambda_d, backwards, as the products with G_k
        the hypotheses need (at step k, of M_dd and lambda_d of step k+1; zero for k = N-1)::

            MG_k = M_dd G_k,   GMG_k = G_k^T M_dd G_k,   Glam_k = G_k^T lambda_d

        ``with_M`` False: Glam only (MG, GMG untouched)."""
        N = H.shape[0]
        n = H.shape[2] if n_fixed == 0 else n_fixed
        m = H.shape[1] if m_fixed == 0 else m_fixed
        M, lam = np.zeros((n, n)), np.zeros(n)
        MA, HtSinv = np.empty((n, n)), np.empty((n, m))
        lam_new = np.empty(n)
        for k in range(N - 1, -1, -1):
            for i in range(m):
                acc = 0.0
                for r in range(n):
                    acc += G[k, r, i] * lam[r]
                Glam[k, i] = acc
            for r in range(n):                      # lambda_d <- A^T lambda_d - H^T w
                acc = 0.0
                for j in range(n):
                    acc += A[k, j, r] * lam[j]
                for i in range(m):
                    acc -= H[k, i, r] * w[k, i]
                lam_new[r] = acc
            for r in range(n):
                lam[r] = lam_new[r]
            if not with_M:
                continue
            Gk = G[k]
            matmul_sized(M, Gk, MG[k], n, n, m)
            matmul_sized(Gk.T, MG[k], GMG[k], m, n, m)
            matmul_sized(M, A[k], MA, n, n, n)      # M_dd <- A^T M_dd A + H^T S^-1 H
            matmul_sized(H[k].T, Sinv[k], HtSinv, n, m, m)
            for r in range(n):
                for c in range(r, n):
                    acc = 0.0
                    for j in range(n):
                        acc += A[k, j, r] * MA[j, c]
                    for i in range(m):
                        acc += HtSinv[r, i] * H[k, i, c]
                    M[r, c] = acc
                    M[c, r] = acc

    return filter_information


def _num(sizes):
    """:func:`hypothesis_num` compiled for ``sizes`` = (n, m, q) (n unused)."""
    _, m_fixed, q_fixed = sizes

    @njit(cache=True, error_model="numpy", nogil=True)
    def hypothesis_num(w, dt, Glam, D_all, Fpsi, norm_psi, persists, i0, num):
        """num(theta) = lambda_theta[i0] alone (the lambda recursion of
        :func:`hypothesis_scan` without M): for the second pass, whose den and cross are the
        first pass's."""
        N = D_all.shape[0]
        m = D_all.shape[1] if m_fixed == 0 else m_fixed
        q = D_all.shape[2] if q_fixed == 0 else q_fixed
        lam_f, lam_new = np.zeros(q), np.empty(q)
        Psi, work = np.zeros((q, q)), np.empty((q, q))
        dt_held = np.nan
        for k in range(N - 1, -1, -1):
            dt_held = psi_at(k, dt, dt_held, Fpsi, norm_psi, persists, Psi, work)
            lambda_f_step(Psi, D_all[k], Glam[k], w[k], lam_f, lam_new, q, m)
            for h in range(i0.shape[0]):
                num[h, k] = lam_f[i0[h]]

    return hypothesis_num


@njit(cache=True, error_model="numpy", nogil=True)
def signature(A, G, H, dt, D_all, Fpsi, norm_psi, persists, i0, k0, rho):
    """rho_k of a unit fault starting at sample k0 (zero before), forwards:
    rho_k = D_k f_k - H_k d_k, d_{k+1} = A_k d_k + G_k D_k f_k, f_{k+1} = Psi_{k+1} f_k."""
    N, m, n = H.shape
    q = D_all.shape[2]
    f, d = np.zeros(q), np.zeros(n)
    f_new, d_new, Df = np.empty(q), np.empty(n), np.empty(m)
    Psi, work = np.zeros((q, q)), np.empty((q, q))
    f[i0] = 1.0
    rho[:k0] = 0.0
    dt_held = np.nan
    for k in range(k0, N):
        dt_held = psi_at(k, dt, dt_held, Fpsi, norm_psi, persists, Psi, work)
        for i in range(m):
            acc = 0.0
            for a in range(q):
                acc += D_all[k, i, a] * f[a]
            Df[i] = acc
            for b in range(n):
                acc -= H[k, i, b] * d[b]
            rho[k, i] = acc
        if k == N - 1:
            break
        for r in range(n):
            acc = 0.0
            for b in range(n):
                acc += A[k, r, b] * d[b]
            for i in range(m):
                acc += G[k, r, i] * Df[i]
            d_new[r] = acc
        matmul(Psi, f.reshape(q, 1), f_new.reshape(q, 1))
        f[:] = f_new
        d[:] = d_new


@njit(cache=True, error_model="numpy", nogil=True)
def onset_statistics(num, den, cross, edges, l, ok, counts):
    """l = num^2 / den for every onset that is a test (ok: den > 1e-300), and, for every pair
    of neighbouring tests, a = sqrt((1 - |c|) / (1 + |c|)) of their correlation
    c = cross / sqrt(den den') counted into ``counts`` by the bin of ``edges`` it falls in
    (``glr_threshold``: edges[i-1] < a <= edges[i]; neighbouring pairs mostly share a bin, so
    the last one is tried before a binary search). Returns the number of onsets that start a
    run of tests."""
    fresh = 0
    i = edges.shape[0]
    for k in range(num.shape[0]):
        ok[k] = den[k] > 1e-300
        l[k] = num[k] * num[k] / den[k] if ok[k] else 0.0
        if not ok[k]:
            continue
        if k == 0 or not ok[k - 1]:
            fresh += 1
            continue
        c = min(abs(cross[k - 1] / np.sqrt(den[k - 1] * den[k])), 1.0)
        a = np.sqrt((1.0 - c) / (1.0 + c))
        if not (i < edges.shape[0] and a <= edges[i] and (i == 0 or a > edges[i - 1])):
            i = np.searchsorted(edges, a)
        counts[i] += 1
    return fresh


#: the kernels compiled for one size (n, m, q), by kernel
_FACTORIES = {"filter_information": _information, "hypothesis_scan": _scan,
              "hypothesis_num": _num}
_COMPILED: dict = {}


def kernel_for(name: str, n: int, m: int, q: int = 0):
    """The kernel ``name`` (``filter_information``, ``hypothesis_scan``, ``hypothesis_num``)
    for a filter of n states and m measurements and a fault system of q states: compiled for
    those sizes when (n, m, q) is in :data:`SPECIALISED` (q = 0: the filter's kernel, for the
    n, m of any of them), else the generic kernel (sizes read from the arrays)."""
    sizes = (n, m, q)
    if not (sizes in SPECIALISED or q == 0 and (n, m) in {s[:2] for s in SPECIALISED}):
        sizes = (0, 0, 0)
    key = (name, sizes)
    if key not in _COMPILED:
        _COMPILED[key] = _FACTORIES[name](sizes)
    return _COMPILED[key]
