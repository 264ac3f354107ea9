"""The ins3d model's time-varying dynamics as numba kernels: the continuous F of one step from
the navigation solution (``fill_F``; the equations of :mod:`flight_fdi.core.ins3d.model`), its
transition and discretisation at the step's dt (``transition``, ``discretize``: second-order
series and the Van Loan integral to dt^3), and the noise-free propagation of an error state
(``propagate``) for tests, the nonlinear check and reports.
"""
from __future__ import annotations

import math

import numpy as np
from numba import njit

from ..earth import A, E2, GE, GF, GK, GM_RATIO, OMEGA_IE, radii
from ..errors import CoreError
from .model import IBA, IBG, IP, IPHI, IV, Ins3dModel
from .sparse import mul_left
from .vertical import fill_loop


@njit(cache=True)
def dgravity_dh(lat, h):
    """d g / d h of ``core.earth.gravity`` (1/s^2, negative)."""
    s2 = math.sin(lat) ** 2
    g0 = GE * (1.0 + GK * s2) / math.sqrt(1.0 - E2 * s2)
    return g0 * (6.0 * h / (A * A) - (2.0 / A) * (1.0 + GF + GM_RATIO - 2.0 * GF * s2))


@njit(cache=True)
def _cross_into(F, r0, c0, a0, a1, a2, s):
    """F[r0:r0+3, c0:c0+3] += s [a x] (the skew matrix of a)."""
    F[r0, c0 + 1] += -s * a2
    F[r0, c0 + 2] += s * a1
    F[r0 + 1, c0] += s * a2
    F[r0 + 1, c0 + 2] += -s * a0
    F[r0 + 2, c0] += -s * a1
    F[r0 + 2, c0 + 1] += s * a0


@njit(cache=True)
def fill_F(F, C, f_n, v, lat, h, bias):
    """Fill the (n, n) F (n = 12, 15, +1 latency: a constant) of one step;
    ``bias`` = Ins3dModel.kernel_params()."""
    F[:, :] = 0.0
    r_n, r_m = radii(lat)
    rn = r_n + h
    rm = r_m + h
    sl, cl = math.sin(lat), math.cos(lat)
    tl = sl / cl
    ve, vn, vu = v[0], v[1], v[2]
    wie_n, wie_u = OMEGA_IE * cl, OMEGA_IE * sl
    wen_e, wen_n, wen_u = -vn / rm, ve / rn, ve * tl / rn
    # D = d w_en / d dv (rows E, N, U of w_en; columns dv_E, dv_N)
    d10, d01, d20 = 1.0 / rn, -1.0 / rm, tl / rn
    # velocity rows
    _cross_into(F, IV, IPHI, f_n[0], f_n[1], f_n[2], 1.0)                    # f x phi
    _cross_into(F, IV, IV, 2.0 * 0.0 + wen_e, 2.0 * wie_n + wen_n, 2.0 * wie_u + wen_u, -1.0)
    # + [v x] D dv : [v x] columns applied to D
    for j in range(2):
        de = d01 if j == 1 else 0.0
        dn = d10 if j == 0 else 0.0
        du = d20 if j == 0 else 0.0
        F[IV, IV + j] += vn * du - vu * dn
        F[IV + 1, IV + j] += vu * de - ve * du
        F[IV + 2, IV + j] += ve * dn - vn * de
    for i in range(3):
        for j in range(3):
            F[IV + i, IBA + j] = C[i, j]
            F[IPHI + i, IBG + j] = -C[i, j]
    # attitude rows
    _cross_into(F, IPHI, IPHI, wen_e, wie_n + wen_n, wie_u + wen_u, -1.0)   # -w_in x phi
    F[IPHI, IV + 1] += d01
    F[IPHI + 1, IV] += d10
    F[IPHI + 2, IV] += d20
    # biases
    for i in range(3):
        F[IBA + i, IBA + i] = -bias[0]
        F[IBG + i, IBG + i] = -bias[1]
    pos = bias[3] > 0.0
    if pos:
        _fill_position(F, ve, vn, vu, lat, h, rn, rm, sl, cl, tl)
    if bias[2] > 0.0:          # damped vertical channel: dv_U a Markov state of its own
        F[IV + 2, :] = 0.0
        F[:, IV + 2] = 0.0
        F[IV + 2, IV + 2] = -bias[2]
        if pos:
            F[IP + 2, IV + 2] = 1.0
            F[IV + 2, IP + 2] = 0.0
    if bias[7] > 0.0:
        fill_loop(F, bias, IV + 2, -dgravity_dh(lat, h), pos)
    im = int(bias[5])
    for i in range(int(bias[6])):  # reference Markov noise states
        F[im + i, im + i] = -bias[14] if i == 2 else -bias[4]


@njit(cache=True)
def _fill_position(F, ve, vn, vu, lat, h, rn, rm, sl, cl, tl):
    """The position columns and rows of F (15-state model)."""
    # rate errors per metre of north position (dL = dp_N / rm) and of height
    ie_n_n, ie_u_n = -OMEGA_IE * sl / rm, OMEGA_IE * cl / rm        # d w_ie / d dp_N
    en_u_n = ve / (cl * cl) / rn / rm                               # d w_en,U / d dp_N
    en_e_u, en_n_u, en_u_u = vn / (rm * rm), -ve / (rn * rn), -ve * tl / (rn * rn)
    # Np (attitude) = d w_ie + d w_en; Mp (velocity) = 2 d w_ie + d w_en
    F[IPHI + 1, IP + 1] += ie_n_n
    F[IPHI + 2, IP + 1] += ie_u_n + en_u_n
    F[IPHI, IP + 2] += en_e_u
    F[IPHI + 1, IP + 2] += en_n_u
    F[IPHI + 2, IP + 2] += en_u_u
    m = np.zeros((3, 2))       # Mp columns for dp_N, dp_U
    m[1, 0], m[2, 0] = 2.0 * ie_n_n, 2.0 * ie_u_n + en_u_n
    m[0, 1], m[1, 1], m[2, 1] = en_e_u, en_n_u, en_u_u
    for j in range(2):
        c = IP + 1 + j
        F[IV, c] += vn * m[2, j] - vu * m[1, j]
        F[IV + 1, c] += vu * m[0, j] - ve * m[2, j]
        F[IV + 2, c] += ve * m[1, j] - vn * m[0, j]
    F[IV + 2, IP + 2] += -dgravity_dh(lat, h)                       # dg_U = -dg/dh dh
    for i in range(3):
        F[IP + i, IV + i] = 1.0
    F[IP, IP] = -vn * tl / rm + vu / rn
    F[IP, IP + 1] = ve * tl / rm
    F[IP, IP + 2] = -ve / rn
    F[IP + 1, IP + 1] = vu / rm
    F[IP + 1, IP + 2] = -vn / rm


@njit(cache=True)
def square(F, F2):
    """F2 = F F, skipping the zeros of F (about a quarter of its entries are nonzero)."""
    F2[:, :] = 0.0
    mul_left(F, F, F2, False)


@njit(cache=True)
def transition(F, dt, Phi, F2):
    """Phi = I + F dt + (F dt)^2 / 2 alone (``discretize`` without Qd); F2 = F F (scratch)."""
    n = F.shape[0]
    square(F, F2)
    h = 0.5 * dt * dt
    for i in range(n):
        for j in range(n):
            Phi[i, j] = F[i, j] * dt + F2[i, j] * h
        Phi[i, i] += 1.0


@njit(cache=True)
def discretize(F, dt, qc, Phi, Qd):
    """Phi = I + F dt + (F dt)^2 / 2 and the Van Loan integral Qd = int_0^dt e^(Fs) Qc
    e^(F's) ds by its Taylor series to dt^3 (Qc = diag(qc), A = F Qc):
    Qd = Qc dt + (A + A') dt^2 / 2 + (F A + (F A)' + 2 A F') dt^3 / 6, with F A = F^2 Qc and
    (A F')_ij = sum_k F_ik qc_k F_jk; the products skip the zeros of F."""
    n = F.shape[0]
    F2 = np.empty((n, n))
    transition(F, dt, Phi, F2)
    AF = np.zeros((n, n))
    for i in range(n):
        for k in range(n):
            a = F[i, k] * qc[k]
            if a != 0.0:
                for j in range(n):
                    AF[i, j] += a * F[j, k]
    c2 = 0.5 * dt * dt
    c3 = dt * dt * dt / 6.0
    for i in range(n):
        for j in range(i, n):
            q = (F[i, j] * qc[j] + F[j, i] * qc[i]) * c2 \
                + (F2[i, j] * qc[j] + F2[j, i] * qc[i] + 2.0 * AF[i, j]) * c3
            if i == j:
                q += qc[i] * dt
            Qd[i, j] = q
            Qd[j, i] = q


@njit(cache=True)
def _propagate(x0, C, f_n, v, lat, h, dt, bias, u_a, u_g, override, out):
    """out[k] = x_k; x_k+1 = Phi_k x_k. With ``override`` the bias states are replaced by the
    given body errors u_a, u_g (K, 3) of each step before it is taken (known-input test)."""
    n = x0.size
    F = np.empty((n, n))
    Phi = np.empty((n, n))
    Qd = np.empty((n, n))
    qc = np.zeros(n)
    x = x0.copy()
    out[0] = x
    for k in range(dt.size):
        if override:
            x[IBA:IBA + 3] = u_a[k]
            x[IBG:IBG + 3] = u_g[k]
        fill_F(F, C[k], f_n[k], v[k], lat[k], h[k], bias)
        discretize(F, dt[k], qc, Phi, Qd)
        x = Phi @ x
        out[k + 1] = x


def propagate(model: Ins3dModel, steps, x0: np.ndarray, u_a: np.ndarray | None = None,
              u_g: np.ndarray | None = None) -> np.ndarray:
    """(K+1, n) noise-free propagation of x0 through the steps; with u_a, u_g (K, 3) the bias
    states are the given body-axis errors of each step (the true sensor errors in tests)."""
    x0 = np.asarray(x0, dtype=float)
    if x0.shape != (model.n,):
        raise CoreError(f"propagate: x0 must have {model.n} elements")
    k = len(steps)
    override = u_a is not None
    ua = np.zeros((k, 3)) if u_a is None else np.ascontiguousarray(u_a, dtype=float)
    ug = np.zeros((k, 3)) if u_g is None else np.ascontiguousarray(u_g, dtype=float)
    out = np.empty((k + 1, model.n))
    _propagate(x0, steps.C, steps.f_n, steps.v, steps.lat, steps.h, steps.dt,
               model.kernel_params(), ua, ug, override, out)
    return out


def F_matrix(model: Ins3dModel, steps, k: int) -> np.ndarray:
    """The continuous F of step k (for tests and reports)."""
    F = np.empty((model.n, model.n))
    fill_F(F, steps.C[k], steps.f_n[k], steps.v[k], float(steps.lat[k]), float(steps.h[k]),
           model.kernel_params())
    return F


__all__ = ["F_matrix", "dgravity_dh", "discretize", "fill_F", "propagate", "square",
           "transition"]
