"""Backward information filter on the time-varying ins3d model, the two-filter combination and
the information about constant body-axis faults for every onset -- one backward sweep.

Backward information filter (Fraser-Potter; the formulas of ``core.information``), from zero
information at the end of the flight, on the same Phi_k, Q_k as the forward pass (``model.fill_F``,
``model.discretize``), scaled coordinates x' = T^-1 x (T = diag(sqrt(p0)), as ``filter``)::

    update at boundary k:  Y <- Y + H' R^-1 H,   y <- y + H' R^-1 z
    predict to k-1:        Y <- Phi' Yt Phi,  y <- Phi' yt,  [Yt | yt] = (I + Y Q)^-1 [Y | y]

(Y, y) at k then holds the information about x_k from the updates at k and after; with the
forward filter's *prior* at k (updates before k) the two-filter combination gives the smoothed
state and the seed method's terms (``information.combine_step``: W = (I + Y P_f)^-1 Y, J, UDU^T
/ LDL^T element terms with the effective degrees of freedom).

Faults. The state is augmented with a constant fault vector b (``FAULT_COLUMNS``): an
accelerometer or gyro error a + r t on each body axis (a step is a alone; a ramp that starts at
theta is a + r t with a = -r theta) entering the velocity or attitude equation through C_b^n like
the bias states do, and an offset of z per reference row (a reference jump). b enters the dynamics
through Gamma_k (x_k+1 = Phi_k x_k + Gamma_k b + w_k) and the measurement through D (z = H x + D b
+ v). The augmented backward filter's x block is the plain one; the fault blocks Y_xb, Y_bb, y_b
follow (A = (I + Y Q)^-1)::

    update:   Y_xb += H' R^-1 D,  Y_bb += D' R^-1 D,  y_b += D' R^-1 z
    predict:  Yt_xb = A Y_xb,  Yt_bb = Y_bb - Y_xb' Q Yt_xb,  yt_b = y_b - Y_xb' Q yt
              Y_xb <- Phi' (Yt Gamma + Yt_xb)
              Y_bb <- Yt_bb + Gamma' Yt_xb + Yt_xb' Gamma + Gamma' Yt Gamma  (group blocks)
              y_b  <- yt_b + Gamma' yt

A fault that starts at boundary k (b = 0 before it) is independent of the forward prior at k, so
combining that prior (x_f, P_f) with the augmented backward information and marginalising the
state gives the information I_b and the information vector eta_b of the fault for the onset k::

    I_b(k) = Y_bb - Y_xb' P_s Y_xb,    eta_b(k) = y_b - Y_xb' x_s

(x_s, P_s the smoothed state of the plain two-filter combination), so b^ = I_b^-1 eta_b and
GLR(k) = eta_b' I_b^-1 eta_b for every onset in one sweep; a hypothesis on one axis (or a ramp
with a = -r theta) is a direction tau in b: GLR = (tau' eta)^2 / (tau' I tau). A reference
outlier at update j is the same with D at that update only: I = R^-1 - R^-1 H P_s H' R^-1,
eta = R^-1 (z - H x_s). The forward signature recursion (``signature.py``) computes the same
statistics for one onset by brute force (the known-answer test).

Gamma_k of one step from the F of the step (E = the bias columns of F on the velocity or
attitude rows, the fault's error a + r (t~_k + s) over the step, e^(F u) = I + F u)::

    Gamma_a = E dt + F E dt^2 / 2,    Gamma_r = Gamma_a t~_k + E dt^2 / 2 + F E dt^3 / 6
"""
from __future__ import annotations

import numpy as np
from numba import njit

from ..information import combine_step, solve
from .filter import _scale, scaled_H
from .model import IBA, IBG, IPHI, IV, discretize, fill_F
from .sparse import mul_left, mul_right

#: columns of the fault vector b: accelerometer a (x, y, z), r (x, y, z), gyro a, r, then one
#: offset per reference row
ACC_A, ACC_R, GYR_A, GYR_R, REF = 0, 3, 6, 9, 12
GROUP_START = (0, 6, 12)          # accelerometer, gyro, reference blocks of b
GROUP_SIZE = 6


@njit(cache=True)
def fault_gamma(F, dt, tt, s, sB, G):
    """Gamma' (n, pB) of one step in scaled coordinates (module docstring); reference columns 0.
    ``tt`` = the step's start time from the start of the flight, sB the fault columns' scales."""
    n = s.size
    G[:, :] = 0.0
    for grp in range(2):
        col0 = ACC_A if grp == 0 else GYR_A
        row0 = IV if grp == 0 else IPHI
        bcol = IBA if grp == 0 else IBG
        for c in range(3):
            for i in range(n):
                e_i = F[i, bcol + c] if row0 <= i < row0 + 3 else 0.0
                fe = 0.0
                for j in range(row0, row0 + 3):
                    fe += F[i, j] * F[j, bcol + c]
                ga = e_i * dt + fe * dt * dt / 2.0
                g1 = e_i * dt * dt / 2.0 + fe * dt * dt * dt / 6.0
                G[i, col0 + c] = ga * sB[col0 + c] / s[i]
                G[i, col0 + 3 + c] = (ga * tt + g1) * sB[col0 + 3 + c] / s[i]


@njit(cache=True)
def _add_updates(Y, y, YxB, YBB, yB, ref_step, z, r, acc, s, sB, il, im, rows, j0, j1):
    """The updates j0..j1-1 (one boundary) into the plain and the fault information."""
    n = s.size
    for j in range(j0, j1):
        Hs = scaled_H(s, acc[j], il, im, rows)
        for i in range(rows):
            w = 1.0 / r[j, i]
            for a in range(n):
                ha = Hs[i, a] * w
                if ha != 0.0:
                    y[a] += ha * z[j, i]
                    YxB[a, REF + i] += ha * sB[REF + i]
                    for b in range(n):
                        Y[a, b] += ha * Hs[i, b]
            YBB[REF + i, REF + i] += sB[REF + i] * sB[REF + i] * w
            yB[REF + i] += sB[REF + i] * z[j, i] * w


@njit(cache=True)
def _fault_info(YxB, YBB, yB, x_s, P_s, eta, I3):
    """eta = y_b - Y_xb' x_s and the group blocks of I_b = Y_bb - Y_xb' P_s Y_xb."""
    n, pB = YxB.shape
    PY = np.zeros((n, pB))
    for a in range(n):
        for b in range(n):
            p = P_s[a, b]
            for c in range(pB):
                PY[a, c] += p * YxB[b, c]
    for c in range(pB):
        acc = yB[c]
        for a in range(n):
            acc -= YxB[a, c] * x_s[a]
        eta[c] = acc
    for g in range(3):
        c0 = GROUP_START[g]
        m = min(GROUP_SIZE, pB - c0)
        for p in range(m):
            for q in range(m):
                acc = YBB[c0 + p, c0 + q]
                for a in range(n):
                    acc -= YxB[a, c0 + p] * PY[a, c0 + q]
                I3[g, p, q] = acc


@njit(cache=True)
def _outliers(s, acc_j, il, im, rows, z_j, r_j, x_s, P_s, e_o, I_o):
    """Outlier information of one update: eta = R^-1 (z - H x_s), I = R^-1 - R^-1 H P_s H' R^-1."""
    Hs = scaled_H(s, acc_j, il, im, rows)
    HP = Hs @ P_s
    for i in range(rows):
        res = z_j[i]
        for a in range(s.size):
            res -= Hs[i, a] * x_s[a]
        e_o[i] = res / r_j[i]
        for k in range(rows):
            hph = 0.0
            for a in range(s.size):
                hph += HP[i, a] * Hs[k, a]
            I_o[i, k] = (1.0 / r_j[i] if i == k else 0.0) - hph / (r_j[i] * r_j[k])


@njit(cache=True)
def _predict_back(Y, y, YxB, YBB, yB, Phi, Qd, G, A):
    """The backward prediction of the plain and the fault information (module docstring)."""
    n, pB = YxB.shape
    w = n + 1 + pB
    for a in range(n):                      # A = [I + Y Q | Y | y | Y_xb]
        for c in range(n):
            acc = 1.0 if a == c else 0.0
            for j in range(n):
                q = Qd[j, c]
                if q != 0.0:
                    acc += Y[a, j] * q
            A[a, c] = acc
            A[a, n + c] = Y[a, c]
        A[a, 2 * n] = y[a]
        for c in range(pB):
            A[a, 2 * n + 1 + c] = YxB[a, c]
    if not solve(A, n):
        return False
    Yt = A[:, n:2 * n]
    # Y_bb, y_b first (they need the old Y_xb)
    QYt = np.zeros((n, pB + 1))             # Q [yt | Yt_xb]
    mul_left(Qd, A[:, 2 * n:], QYt, False)
    YtG = np.zeros((n, pB))
    mul_right(Yt, G, YtG)
    for p in range(pB):
        acc_y = yB[p]
        for a in range(n):
            acc_y += -YxB[a, p] * QYt[a, 0] + G[a, p] * A[a, 2 * n]
        yB[p] = acc_y
        grp = p // GROUP_SIZE                # the group blocks of Y_bb only (what is used)
        for q in range(p, min(pB, (grp + 1) * GROUP_SIZE)):
            acc = YBB[p, q]
            for a in range(n):
                acc += (-YxB[a, p] * QYt[a, 1 + q] + G[a, p] * A[a, 2 * n + 1 + q]
                        + A[a, 2 * n + 1 + p] * G[a, q] + G[a, p] * YtG[a, q])
            YBB[p, q] = acc
            YBB[q, p] = acc
    for c in range(pB):                     # Y_xb <- Phi' (Yt Gamma + Yt_xb), y <- Phi' yt
        for a in range(n):
            YtG[a, c] += A[a, 2 * n + 1 + c]
    YxB[:, :] = 0.0
    mul_left(Phi, YtG, YxB, True)
    y[:] = 0.0
    mul_left(Phi, A[:, 2 * n:2 * n + 1], y.reshape((n, 1)), True)
    YtPhi = np.zeros((n, n))                # Y <- Phi' Yt Phi
    mul_right(Yt, Phi, YtPhi)
    Y[:, :] = 0.0
    mul_left(Phi, YtPhi, Y, True)
    for a in range(n):
        for c in range(a + 1, n):
            sym = 0.5 * (Y[a, c] + Y[c, a])
            Y[a, c] = sym
            Y[c, a] = sym
    return True


@njit(cache=True, nogil=True)
def backward_sweep(C, f_n, v, lat, h, dt, tt, kp, qc, s, sB, ref_step, z, r, acc, il, im,
                   rows, x_pr, P_pr, rank_tol, x_s_o, sd_s_o, terms_o, dof_o, norm_o, vt_o,
                   d_o, eta_o, I_o, oe_o, oI_o):
    """The backward sweep (module docstring). Per update j (sorted by step; x_pr, P_pr the
    forward prior before it, physical) it writes the combination at its boundary: x_s, sd_s
    (physical), the cumulative element terms J(i/k), their effective dof and the normalised
    residuals, v~ and dD (seed method; physical units); the fault information eta (pB,) and
    the group blocks I (3, 6, 6) (scaled fault units, ``sB``); the outlier information oe
    (rows,), oI (rows, rows).
    Returns (boundary, code) of a failure (1: I + Y Q singular, 2: the combination) or
    (-1, 0)."""
    n = s.size
    pB = sB.size
    K = dt.size
    F = np.empty((n, n))
    Phi = np.empty((n, n))
    Qd = np.empty((n, n))
    G = np.empty((n, pB))
    Y = np.zeros((n, n))
    y = np.zeros(n)
    YxB = np.zeros((n, pB))
    YBB = np.zeros((pB, pB))
    yB = np.zeros(pB)
    A = np.empty((n, 2 * n + 1 + pB))
    Ac = np.empty((n, 2 * n + 1))
    work = np.empty((2, n, n))
    W, P_s, xf, Pf = np.empty((n, n)), np.empty((n, n)), np.empty(n), np.empty((n, n))
    Wv, x_s, ref, Lam, vt, dd = (np.empty(n), np.empty(n), np.empty(n), np.empty(n),
                                 np.empty(n), np.empty(n))
    informative = np.empty(n, dtype=np.bool_)
    eta = np.empty(pB)
    I3 = np.zeros((3, GROUP_SIZE, GROUP_SIZE))
    j1 = ref_step.size
    for k in range(K, -1, -1):
        j0 = j1
        while j0 > 0 and ref_step[j0 - 1] == k:
            j0 -= 1
        if j0 < j1:
            _add_updates(Y, y, YxB, YBB, yB, ref_step, z, r, acc, s, sB, il, im, rows, j0, j1)
            for a in range(n):
                xf[a] = x_pr[j0, a] / s[a]
                for b in range(n):
                    Pf[a, b] = P_pr[j0, a, b] / (s[a] * s[b])
            if not combine_step(Y, y, xf, Pf, rank_tol, W, Wv, x_s, P_s, ref, Lam, informative,
                                vt, dd, terms_o[j0], dof_o[j0], norm_o[j0], Ac, work):
                return k, 2
            _fault_info(YxB, YBB, yB, x_s, P_s, eta, I3)
            for j in range(j0, j1):
                for a in range(n):
                    x_s_o[j, a] = x_s[a] * s[a]
                    sd_s_o[j, a] = np.sqrt(max(P_s[a, a], 0.0)) * s[a]
                    terms_o[j, a] = terms_o[j0, a]
                    dof_o[j, a] = dof_o[j0, a]
                    norm_o[j, a] = norm_o[j0, a]
                    vt_o[j, a] = vt[a] * s[a]
                    d_o[j, a] = dd[a] * s[a] * s[a]
                eta_o[j, :] = eta
                I_o[j] = I3
                _outliers(s, acc[j], il, im, rows, z[j], r[j], x_s, P_s, oe_o[j], oI_o[j])
            j1 = j0
        if k == 0:
            break
        fill_F(F, C[k - 1], f_n[k - 1], v[k - 1], lat[k - 1], h[k - 1], kp)
        fault_gamma(F, dt[k - 1], tt[k - 1], s, sB, G)
        discretize(F, dt[k - 1], qc, Phi, Qd)
        _scale(Phi, Qd, s)
        if not _predict_back(Y, y, YxB, YBB, yB, Phi, Qd, G, A):
            return k, 1
    return -1, 0


__all__ = ["ACC_A", "ACC_R", "GROUP_SIZE", "GROUP_START", "GYR_A", "GYR_R", "REF",
           "backward_sweep", "fault_gamma"]
