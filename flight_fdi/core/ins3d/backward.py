"""The post-flight backward sweep on the time-varying ins3d model: the two-filter combination
with the forward pass at every boundary with reference updates, and the information about
constant body-axis faults for every onset -- one backward sweep (Bryson-Frazier adjoint form).

The backward information filter (Fraser-Potter: Y, y from zero information at the end, on the
same Phi_k, Q_k as the forward pass) combined with the forward filter's *prior* (x_f, P_f) at a
boundary k gives (``core.information.combine_step``)

    W = (I + Y P_f)^-1 Y,   W v = (I + Y P_f)^-1 (y - Y x_f),
    x_s = x_f + P_f W v,    P_s = P_f - P_f W P_f,

and W, W v (the information of the difference between the backward and the forward estimate)
are what the seed method decomposes (UDU^T of P_f for the reference pivots, LDL^T of W, element
terms with the effective dof). The sweep computes W and W v directly, with the forward filter's
gains K_j = P_j H_j' S_j^-1 (L_j = I - K_j H_j) instead of a (I + Y Q)^-1 solve per step -- the
modified Bryson-Frazier recursion (Bierman 1977, ch. X), from (Lambda, lambda) = (0, 0) after the
last update, in scaled coordinates x' = T^-1 x (T = diag(sqrt(p0)), as ``filter``)::

    update j (backwards):  lambda <- H' S^-1 nu + L' lambda,   Lambda <- H' S^-1 H + L' Lambda L
    step k (backwards):    lambda <- Phi_k' lambda,            Lambda <- Phi_k' Lambda Phi_k

(Lambda, lambda) before the first update at boundary k is (W, W v) there: the same quantities,
no Q_k and no solve (test_backward.py: = the information filter's combination and = FilterPy's
RTS smoother).

Faults. A constant fault vector b (``ACC_A`` ... ``REF``): an accelerometer or gyro error a + r t
on each body axis (a step is a alone; a ramp that starts at theta is a + r t with a = -r theta)
entering the velocity or attitude equation through C_b^n like the bias states do, and an offset of
z per reference row (a reference jump); it enters the dynamics through Gamma_k
(x_k+1 = Phi_k x_k + Gamma_k b + w_k) and the measurement through D (z = H x + D b + v). A fault
that starts at boundary k moves the forward filter's (which ignores it) prior error by mu and its
innovations by rho (the Willsky-Jones signature, ``signature.py``)::

    rho_j = H mu_j + D b,   mu <- L_j mu - K_j D b (update j),   mu <- Phi_k mu + Gamma_k b

with mu = 0 at the onset; the GLR statistics are e = sum rho' S^-1 nu (linear in b) and
d = sum rho' S^-1 rho (quadratic). Both are carried backwards as functions of (mu, b):
e = mu' lambda + b' zeta, d = mu' Lambda mu + 2 mu' Z b + b' Omega b -- with the same lambda,
Lambda as above and (KD = K D, M = Lambda K)::

    update j:  zeta  += D' S^-1 nu - D' K' lambda
               Z     <- H' S^-1 D + L' (Z - M D)
               Omega += D' S^-1 D - D' K' Z - Z' K D + D' K' Lambda K D
    step k:    zeta  += Gamma' lambda
               Omega += Gamma' (Z + Lambda Gamma) + Z' Gamma      (group blocks)
               Z     <- Phi' (Z + Lambda Gamma)

(right-hand sides with the values before the update / step). At the onset boundary k (mu = 0
before its first update) the fault's information vector and information are

    eta_b(k) = zeta,   I_b(k) = Omega,

so b^ = I_b^-1 eta_b and GLR(k) = eta_b' I_b^-1 eta_b for every onset in one sweep (= the
information-filter form Y_bb - Y_xb' P_s Y_xb of the augmented backward filter); a hypothesis on
one axis (or a ramp with a = -r theta) is a direction tau in b: GLR = (tau' eta)^2 / (tau' I tau).
Only the group blocks of Omega (accelerometer, gyro, reference) are kept. A reference outlier at
update j is the same with D at that update only: I = R^-1 - R^-1 H P_s H' R^-1,
eta = R^-1 (z - H x_s). The forward signature recursion (``signature.py``) computes the same
statistics for one onset by brute force (the known-answer test).

Gamma_k of one step from the F of the step (E = the bias columns of F on the velocity or
attitude rows, the fault's error a + r (t~_k + s) over the step, e^(F u) = I + F u)::

    Gamma_a = E dt + F E dt^2 / 2,    Gamma_r = Gamma_a t~_k + E dt^2 / 2 + F E dt^3 / 6

Every update the forward filter fused enters with its gain; an update the forward filter
rejected (gate action ``reject``) has no gain: ``postflight.run_backward`` then re-runs the
forward pass fusing every update (the post-flight part judges all the data).
"""
from __future__ import annotations

import numpy as np
from numba import njit

from .combination import combination_scratch, combine_boundary
from .filter import scaled_H
from .model import IBA, IBG, IPHI, IV
from .dynamics import fill_F, transition
from .sparse import congruence, mul_pattern, row_pattern

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
def _adjoint_update(lam, Lam, zeta, Z, Om, Hs, K, Si, nu, sB, M, KtM, KtZ, Kl, Snu, faults):
    """The update j of the adjoint recursion (module docstring), in place (``faults``: also
    zeta, Z, Omega)."""
    rows, n = Hs.shape
    pB = sB.size
    for a in range(n):                          # M = Lambda K
        for i in range(rows):
            acc = 0.0
            for b in range(n):
                acc += Lam[a, b] * K[b, i]
            M[a, i] = acc
    for i in range(rows):
        acc = 0.0
        for a in range(n):
            acc += K[a, i] * lam[a]
        Kl[i] = acc
        acc = 0.0
        for c in range(rows):
            acc += Si[i, c] * nu[c]
        Snu[i] = acc
        for c in range(rows):                  # K' Lambda K
            acc = 0.0
            for a in range(n):
                acc += K[a, i] * M[a, c]
            KtM[i, c] = acc
    if faults:
        _fault_update(zeta, Z, Om, Hs, K, Si, sB, M, KtM, KtZ, Kl, Snu)
    for i in range(rows):                      # lambda <- H' S^-1 nu + L' lambda
        for a in range(n):
            lam[a] += Hs[i, a] * (Snu[i] - Kl[i])
    # Lambda <- H' S^-1 H + Lambda - H' M' - M H + H' K'M H
    for i in range(rows):
        for a in range(n):
            h = Hs[i, a]
            if h == 0.0:
                continue
            for b in range(n):
                Lam[a, b] -= h * M[b, i]
                Lam[b, a] -= h * M[b, i]
            for c in range(rows):
                w = h * (Si[i, c] + KtM[i, c])
                for b in range(n):
                    Lam[a, b] += w * Hs[c, b]


@njit(cache=True, inline="always")
def _fault_update(zeta, Z, Om, Hs, K, Si, sB, M, KtM, KtZ, Kl, Snu):
    """The fault part of the update (zeta, Z, Omega; with the old lambda, Lambda, Z)."""
    rows, n = Hs.shape
    pB = sB.size
    for i in range(rows):
        for p in range(pB):                    # K' Z (the old Z)
            acc = 0.0
            for a in range(n):
                acc += K[a, i] * Z[a, p]
            KtZ[i, p] = acc
    # Omega's reference block and zeta (old Z, lambda, Lambda)
    for i in range(rows):
        p = REF + i
        zeta[p] += sB[p] * (Snu[i] - Kl[i])
        for c in range(rows):
            q = REF + c
            Om[p, q] += sB[p] * sB[q] * (Si[i, c] + KtM[i, c]) - sB[p] * KtZ[i, q] \
                - sB[q] * KtZ[c, p]
    # Z <- H' S^-1 D + (Z - M D) - H' K' (Z - M D);  K' (Z - M D) = K'Z - K'M D
    for i in range(rows):
        p = REF + i
        for a in range(n):
            Z[a, p] -= M[a, i] * sB[p]
        for c in range(rows):
            KtZ[c, p] -= KtM[c, i] * sB[p]
    for i in range(rows):
        for a in range(n):
            h = Hs[i, a]
            if h != 0.0:
                for p in range(pB):
                    Z[a, p] -= h * KtZ[i, p]
                for c in range(rows):
                    Z[a, REF + c] += h * Si[i, c] * sB[REF + c]


@njit(cache=True)
def _adjoint_step(lam, Lam, zeta, Z, Om, PhiT, nz, cnt, G, grows, ng, T2, lt, zero, faults):
    """The step k of the adjoint recursion (module docstring), in place: PhiT = Phi_k' with its
    row pattern (nz, cnt), G = Gamma_k whose nonzero rows are grows[:ng]; T2 (n, pB), lt (n, n)
    scratch, ``zero`` (n, n) zeros (``faults``: also zeta, Z, Omega)."""
    n, pB = Z.shape
    if faults:
        _fault_step(lam, Lam, zeta, Z, Om, PhiT, nz, cnt, G, grows, ng, T2)
    for i in range(n):                          # lambda = Phi' lambda
        acc = 0.0
        for m in range(cnt[i]):
            acc += PhiT[i, nz[i, m]] * lam[nz[i, m]]
        lt[0, i] = acc
    for i in range(n):
        lam[i] = lt[0, i]
    congruence(PhiT, nz, cnt, Lam, zero, lt)     # Lambda = Phi' Lambda Phi


@njit(cache=True, inline="always")
def _fault_step(lam, Lam, zeta, Z, Om, PhiT, nz, cnt, G, grows, ng, T2):
    """The fault part of the step (zeta, Z, Omega; with the old lambda, Lambda)."""
    n, pB = Z.shape
    for m in range(ng):                         # zeta += Gamma' lambda
        a = grows[m]
        for p in range(pB):
            zeta[p] += G[a, p] * lam[a]
    for a in range(n):                          # T2 = Z + Lambda Gamma
        for p in range(pB):
            T2[a, p] = Z[a, p]
        for m in range(ng):
            k = grows[m]
            lk = Lam[a, k]
            for p in range(pB):
                T2[a, p] += lk * G[k, p]
    for p in range(pB):                         # Omega += Gamma' T2 + Z' Gamma (group blocks)
        grp = p // GROUP_SIZE
        for q in range(p, min(pB, (grp + 1) * GROUP_SIZE)):
            acc = 0.0
            for m in range(ng):
                a = grows[m]
                acc += G[a, p] * T2[a, q] + Z[a, p] * G[a, q]
            Om[p, q] += acc
            Om[q, p] = Om[p, q]
    mul_pattern(PhiT, nz, cnt, T2, Z)           # Z = Phi' T2


@njit(cache=True)
def _write_faults(j0, j1, zeta, Om, eta_o, I_o):
    """eta and the group blocks of Omega into the rows j0..j1-1."""
    pB = zeta.size
    for j in range(j0, j1):
        for p in range(pB):
            eta_o[j, p] = zeta[p]
        for g in range(3):
            c0 = GROUP_START[g]
            for p in range(min(GROUP_SIZE, pB - c0)):
                for c in range(min(GROUP_SIZE, pB - c0)):
                    I_o[j, g, p, c] = Om[c0 + p, c0 + c]


@njit(cache=True, nogil=True)
def backward_sweep(C, f_n, v, lat, h, dt, tt, kp, s, sB, ref_step, z, r, acc, il, im, rows, hu,
                   x_pr, P_pr, K_pr, Si_pr, nu, rank_tol, out, eta_o, I_o, state, k, j1, part,
                   kb, jb, lam_b, Lam_b):
    """The backward sweep (module docstring) from boundary k down (``j1``: the first update
    after it; the start: k = K, j1 = M, ``state`` = (lambda, Lambda, zeta, Z, Omega) zero).
    Per update j (sorted by step; x_pr, P_pr the forward prior before it, K_pr its gain, Si_pr
    = S^-1, all scaled: ``Ins3dForward``; nu the innovation) it writes, with ``part`` & 1, the
    combination at its boundary into ``out`` (``combination.combine_boundary``); with ``part``
    & 2 the fault information eta (pB,) and the group blocks I (3, 6, 6) (scaled fault units,
    ``sB``); with ``part`` & 4 it keeps (lambda, Lambda) of every boundary with updates in
    lam_b, Lam_b (its k in kb, its updates j0, j1 in jb) and stops before the boundary that
    finds them full (``combination.combine_kept`` makes the combination from them: on another
    thread, while the sweep goes on). Returns (the boundary to go on from, -1 at the end; its
    j1; the boundaries kept; the boundary where P_f is not positive definite, or -1)."""
    n, pB = s.size, sB.size
    comb, faults, keep = (part & 1) != 0, (part & 2) != 0, (part & 4) != 0
    lam, Lam, zeta, Z, Om = state
    inv_s = 1.0 / s
    F, Phi, F2 = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    G = np.zeros((n, pB))
    T2, lt, zero, PhiT = np.empty((n, pB)), np.empty((n, n)), np.zeros((n, n)), np.empty((n, n))
    nz, cnt, grows = np.empty((n, n), np.int64), np.empty(n, np.int64), np.empty(n, np.int64)
    M, KtM, KtZ = np.empty((n, rows)), np.empty((rows, rows)), np.empty((rows, pB))
    Kl, Snu = np.empty(rows), np.empty(rows)
    work = combination_scratch(n, rows)
    count = 0
    while k >= 0:
        j0 = j1
        while j0 > 0 and ref_step[j0 - 1] == k:
            j0 -= 1
        if j0 < j1:
            if keep and count == kb.size:
                break
            for j in range(j1 - 1, j0 - 1, -1):
                _adjoint_update(lam, Lam, zeta, Z, Om, scaled_H(s, acc[j], il, im, rows, hu),
                                K_pr[j], Si_pr[j], nu[j], sB, M, KtM, KtZ, Kl, Snu, faults)
            if comb and not combine_boundary(j0, j1, lam, Lam, s, acc, il, im, rows, hu, z, r,
                                             x_pr, P_pr, rank_tol, out, work):
                return k, j1, count, k
            if keep:
                kb[count], jb[count, 0], jb[count, 1] = k, j0, j1
                lam_b[count] = lam
                Lam_b[count] = Lam
                count += 1
            if faults:
                _write_faults(j0, j1, zeta, Om, eta_o, I_o)
            j1 = j0
        if k == 0:
            k = -1
            break
        fill_F(F, C[k - 1], f_n[k - 1], v[k - 1], lat[k - 1], h[k - 1], kp)
        transition(F, dt[k - 1], Phi, F2)
        for a in range(n):                      # Phi' scaled
            for b in range(n):
                PhiT[b, a] = Phi[a, b] * s[b] * inv_s[a]
        row_pattern(PhiT, nz, cnt)
        ng = 0
        if faults:
            fault_gamma(F, dt[k - 1], tt[k - 1], s, sB, G)
            for a in range(n):                  # the nonzero rows of Gamma
                for p in range(pB):
                    if G[a, p] != 0.0:
                        grows[ng] = a
                        ng += 1
                        break
        _adjoint_step(lam, Lam, zeta, Z, Om, PhiT, nz, cnt, G, grows, ng, T2, lt, zero, faults)
        k -= 1
    return k, j1, count, -1


__all__ = ["ACC_A", "ACC_R", "GROUP_SIZE", "GROUP_START", "GYR_A", "GYR_R", "REF",
           "backward_sweep", "fault_gamma"]
