"""Forward Kalman filter on the time-varying ins3d model, with the beta^2 gate.

One numba kernel (``_forward``, ``njit(cache=True)``) runs the whole flight: per propagation step
k the continuous F is built from the navigation solution (``dynamics.fill_F``), discretised at the
step's dt (``dynamics.discretize``), scaled, and the prediction x = Phi x, P = Phi P Phi' + Q is
taken (loops that skip the zeros of Phi); at the step boundaries that carry reference messages
the update follows (Joseph form, expanded: O(n^2) for the 2-3 rows)::

    nu = z - H x,  S = H P H' + R,  K = P H' S^-1,
    x += K nu,     P = (I - K H) P (I - K H)' + K R K' = P - K H P - (K H P)' + K S K'

Scaled coordinates (SPEC §1, numerics): x' = T^-1 x with T = diag(sqrt(P0)), Phi' = T^-1 Phi T,
Q' = T^-1 Q T^-1, H' = H T; everything returned is in physical units. The gate (SPEC §2):
beta^2 = nu' S^-1 nu against the chi^2(m) threshold of ``GateConfig`` for the m = 2 or 3 rows,
and per row beta_i^2 = nu_i^2 / S_ii against the chi^2(1) threshold; the persistence alarm (M of
the last N updates) of ``kalman.alarm_states``; ``action="reject"`` skips a gated update.
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
from numba import njit

from ..errors import CoreError
from ..information import solve
from ..kalman import GateConfig, alarm_states
from ..threads import usable_threads
from .data import NavSteps, RefRows
from .model import Ins3dModel
from .dynamics import discretize, fill_F
from .sparse import congruence, mul_left, row_pattern


def scale_factors(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(s_j / s_i, 1 / (s_i s_j)) (n, n): what ``_scale`` multiplies Phi and Qd by."""
    return s[None, :] / s[:, None], 1.0 / (s[:, None] * s[None, :])


@njit(cache=True)
def _scale(Phi, Qd, ratio, inv_ss):
    """Phi' = T^-1 Phi T, Qd' = T^-1 Qd T^-1 (T = diag(s)), in place; ``ratio``, ``inv_ss``:
    ``scale_factors(s)`` (products: no division per step)."""
    n = ratio.shape[0]
    for i in range(n):
        for j in range(n):
            Phi[i, j] *= ratio[i, j]
            Qd[i, j] *= inv_ss[i, j]


@njit(cache=True)
def propagate(x, P, C, f_n, v, lat, h, dt, bias, qc, ratio, inv_ss, F, Phi, Qd, T, xt, nz, cnt):
    """One propagation step on the scaled state (in place): F of the step (``dynamics.fill_F``),
    Phi, Qd (``dynamics.discretize``) scaled, x = Phi x, P = Phi P Phi' + Qd; F, Phi, Qd, T (n, n),
    xt (n), nz (n, n), cnt (n) scratch."""
    fill_F(F, C, f_n, v, lat, h, bias)
    discretize(F, dt, qc, Phi, Qd)
    _scale(Phi, Qd, ratio, inv_ss)
    predict(x, P, Phi, Qd, T, xt, nz, cnt)


@njit(cache=True)
def scaled_H(s, a, il, im, rows, hu):
    """H' = H T of one update: the velocity rows (the third one: state ``hu``, dv_U or, for a
    height reference, the height error), the reference Markov states (im > 0) and the latency
    column a (il >= 0: the rate of each row's quantity)."""
    Hs = np.zeros((rows, s.size))
    for i in range(rows):
        c = hu if i == 2 else i
        Hs[i, c] = s[c]
        if im > 0:
            Hs[i, im + i] = s[im + i]
        if il >= 0:
            Hs[i, il] = a[i] * s[il]
    return Hs


@njit(cache=True)
def _update(x, P, s, z, r, a, il, im, rows, hu, thr, reject, j, nu_o, S_o, b2_o, b2r_o, exc_o, K_o,
            Si_o):
    """One reference update (scaled x, P; z, r physical); fills output row j (and the scaled
    gain K' = T^-1 K and S^-1 into K_o[j], Si_o[j] when they have that row; also of a
    rejected update). Joseph form, expanded: P <- P - K H P - (K H P)' + K S K'
    (= (I - K H) P (I - K H)' + K R K' for any K), computed in O(n^2 rows^2)."""
    n = x.size
    keep = K_o.shape[0] > j
    Hs = scaled_H(s, a, il, im, rows, hu)
    HP = np.zeros((rows, n))
    mul_left(Hs, P, HP, False)
    A = np.empty((rows, 2 * rows))              # [S | I] -> [I | S^-1]
    nu = np.empty(rows)
    for i in range(rows):
        acc = z[i]
        for b in range(n):
            acc -= Hs[i, b] * x[b]
        nu[i] = acc
        for c in range(rows):
            acc = r[i] if i == c else 0.0
            for b in range(n):
                acc += HP[i, b] * Hs[c, b]
            A[i, c] = acc
            A[i, rows + c] = 1.0 if i == c else 0.0
    for i in range(rows):
        nu_o[j, i] = nu[i]
        for c in range(rows):
            S_o[j, i, c] = A[i, c]
        b2r_o[j, i] = nu[i] * nu[i] / A[i, i]
    solve(A, rows)
    Sinu = np.zeros(rows)
    b2 = 0.0
    for i in range(rows):
        for c in range(rows):
            Sinu[i] += A[i, rows + c] * nu[c]
        b2 += nu[i] * Sinu[i]
    b2_o[j] = b2
    exc_o[j] = b2 > thr
    K = np.zeros((n, rows))                     # P H' S^-1
    for a_ in range(n):
        for i in range(rows):
            hp = HP[i, a_]
            for c in range(rows):
                K[a_, c] += hp * A[i, rows + c]
    if keep:
        for a_ in range(n):
            for c in range(rows):
                K_o[j, a_, c] = K[a_, c]
        for i in range(rows):
            for c in range(rows):
                Si_o[j, i, c] = A[i, rows + c]
    if reject and b2 > thr:
        return
    for a_ in range(n):
        for i in range(rows):
            x[a_] += HP[i, a_] * Sinu[i]
    KS = np.zeros((n, rows))                    # K S (= P H')
    for a_ in range(n):
        for i in range(rows):
            for c in range(rows):
                KS[a_, c] += K[a_, i] * S_o[j, i, c]
    for p_ in range(n):
        for q_ in range(p_, n):
            acc = P[p_, q_]
            for i in range(rows):
                acc += -K[p_, i] * HP[i, q_] - HP[i, p_] * K[q_, i] + KS[p_, i] * K[q_, i]
            P[p_, q_] = acc
            P[q_, p_] = acc


@njit(cache=True)
def predict(x, P, Phi, Qd, T, xt, nz, cnt):
    """x <- Phi x, P <- Phi P Phi' + Qd (exactly symmetric), over the nonzero entries of Phi
    (T (n, n), xt (n), nz (n, n) int, cnt (n) int scratch)."""
    n = x.size
    row_pattern(Phi, nz, cnt)
    for i in range(n):
        acc = 0.0
        for m in range(cnt[i]):
            acc += Phi[i, nz[i, m]] * x[nz[i, m]]
        xt[i] = acc
    for i in range(n):
        x[i] = xt[i]
    congruence(Phi, nz, cnt, P, Qd, T)


@njit(cache=True, nogil=True)
def _discretize_steps(C, f_n, v, lat, h, dt, bias, qc, ratio, inv_ss, k0, k1, Phi_o, Qd_o):
    """The scaled Phi', Qd' of steps k0 .. k1-1 into Phi_o[0 .. k1-k0-1], Qd_o (as
    ``propagate`` computes them): what the second thread prepares for ``_forward``."""
    n = ratio.shape[0]
    F = np.empty((n, n))
    for k in range(k0, k1):
        fill_F(F, C[k], f_n[k], v[k], lat[k], h[k], bias)
        discretize(F, dt[k], qc, Phi_o[k - k0], Qd_o[k - k0])
        _scale(Phi_o[k - k0], Qd_o[k - k0], ratio, inv_ss)


@njit(cache=True, nogil=True)
def _forward(C, f_n, v, lat, h, dt, bias, qc, s, ratio, inv_ss, b0, b1, Phi_pre, Qd_pre, x, P,
             j, ref_step, z, r, acc, il, im, rows, hu, thr, reject, keep_cov, keep_prior, x_o, sd_o,
             nu_o, S_o, b2_o, b2r_o, exc_o, Ppost_o, xpr_o, Ppr_o, K_o, Si_o):
    """The boundaries b0 .. b1-1 (scaled x, P in place; j: the first update not yet fused;
    returns the next). Boundary k > 0 first takes step k-1: with its Phi', Qd' from Phi_pre,
    Qd_pre (row k-1 - max(b0-1, 0)) when given, else computed here."""
    n = s.size
    F = np.empty((n, n))
    Phi = np.empty((n, n))
    Qd = np.empty((n, n))
    T, xt = np.empty((n, n)), np.empty(n)
    nz, cnt = np.empty((n, n), dtype=np.int64), np.empty(n, dtype=np.int64)
    m = ref_step.size
    pre = Phi_pre.shape[0] > 0
    s0 = max(b0 - 1, 0)
    for k in range(b0, b1):
        if k > 0:
            if pre:
                predict(x, P, Phi_pre[k - 1 - s0], Qd_pre[k - 1 - s0], T, xt, nz, cnt)
            else:
                propagate(x, P, C[k - 1], f_n[k - 1], v[k - 1], lat[k - 1], h[k - 1],
                          dt[k - 1], bias, qc, ratio, inv_ss, F, Phi, Qd, T, xt, nz, cnt)
        while j < m and ref_step[j] == k:
            if keep_prior:                      # scaled
                for a in range(n):
                    xpr_o[j, a] = x[a]
                    for b in range(n):
                        Ppr_o[j, a, b] = P[a, b]
            _update(x, P, s, z[j], r[j], acc[j], il, im, rows, hu, thr, reject, j, nu_o, S_o,
                    b2_o, b2r_o, exc_o, K_o, Si_o)
            if keep_cov:
                for a in range(n):
                    for b in range(n):
                        Ppost_o[j, a, b] = P[a, b] * s[a] * s[b]
            j += 1
        for i in range(n):
            x_o[k, i] = x[i] * s[i]
            sd_o[k, i] = np.sqrt(max(P[i, i], 0.0)) * s[i]
    return j


#: bytes of one chunk's Phi', Qd' (``_filter``): the hand-over between the threads stays in
#: the cores' caches
CHUNK_BYTES = 1 << 19


def _filter(steps: NavSteps, bias: np.ndarray, qc: np.ndarray, s: np.ndarray, x0: np.ndarray,
            P0: np.ndarray, updates: tuple, threads: int, chunk: int | None = None) -> None:
    """Run ``_forward`` over the whole flight (``updates``: its arguments from ``ref_step``
    on). With ``threads`` > 1 and more than two chunks of steps, a second thread computes the
    Phi', Qd' of the next ``chunk`` steps (default: ``CHUNK_BYTES`` of them, 64 to 512 steps)
    while the filter takes the current ones (the same kernels: the same numbers)."""
    nav = (steps.C, steps.f_n, steps.v, steps.lat, steps.h, steps.dt, bias, qc)
    ratio, inv_ss = scale_factors(s)
    n, K = s.size, len(steps)
    if chunk is None:
        chunk = int(np.clip(CHUNK_BYTES // (16 * n * n), 64, 512))
    x, P = x0 / s, P0 / (s[:, None] * s[None, :])
    if threads < 2 or K <= 2 * chunk:
        none = np.empty((0, n, n))
        _forward(*nav, s, ratio, inv_ss, 0, K + 1, none, none, x, P, 0, *updates)
        return
    bounds = [*range(0, K + 1, chunk), K + 1]
    buf = [(np.empty((chunk, n, n)), np.empty((chunk, n, n))) for _ in range(2)]

    def steps_of(c: int) -> None:
        _discretize_steps(*nav, ratio, inv_ss, max(bounds[c] - 1, 0), bounds[c + 1] - 1,
                          *buf[c % 2])

    j = 0
    with ThreadPoolExecutor(max_workers=1) as pool:
        ready = pool.submit(steps_of, 0)
        for c in range(len(bounds) - 1):
            ready.result()
            if c + 2 < len(bounds):
                ready = pool.submit(steps_of, c + 1)
            j = _forward(*nav, s, ratio, inv_ss, bounds[c], bounds[c + 1], *buf[c % 2], x, P, j,
                         *updates)


@dataclass
class Ins3dForward:
    """The forward pass: states on the step grid, innovations and gate per reference update."""

    names: tuple[str, ...]
    t: np.ndarray            # (K+1,) step boundaries
    x: np.ndarray            # (K+1, n) filtered state (after the updates at the boundary)
    sd: np.ndarray           # (K+1, n) its standard deviations
    t_ref: np.ndarray        # (M,) update times
    nu: np.ndarray           # (M, rows) innovations
    S: np.ndarray            # (M, rows, rows)
    beta2: np.ndarray        # (M,)
    beta2_row: np.ndarray    # (M, rows)
    exceeded: np.ndarray     # (M,) bool: beta^2 > the chi^2(rows) gate
    exceeded_row: np.ndarray  # (M, rows) bool: per row against the chi^2(1) gate
    alarm: np.ndarray        # (M,) alarm states (kalman.ALARM_*)
    threshold: float
    threshold_row: float
    P_post: np.ndarray | None = None   # (M, n, n) posterior covariances (keep_cov)
    # keep_prior, in scaled coordinates x' = T^-1 x (T = diag(s)): what the post-flight
    # kernels work in (``x_prior``, ``P_prior``: the same in physical units)
    xs_prior: np.ndarray | None = None  # (M, n) state before each update
    Ps_prior: np.ndarray | None = None  # (M, n, n) its covariance
    Ks: np.ndarray | None = None        # (M, n, rows) the gain T^-1 K (also of a rejected one)
    S_inv: np.ndarray | None = None     # (M, rows, rows) S^-1
    s: np.ndarray | None = None         # (n,) the scales
    x0: np.ndarray | None = None       # (n,) the initial state
    P0: np.ndarray | None = None       # (n, n) its covariance
    fused: np.ndarray | None = None    # (M,) bool: the update was fused (not rejected)

    @property
    def x_prior(self) -> np.ndarray | None:
        """(M, n) the state before each update, physical units (keep_prior; built at each
        access: the whole array -- one update's is ``prior``)."""
        return None if self.xs_prior is None else self.xs_prior * self.s

    @property
    def P_prior(self) -> np.ndarray | None:
        """(M, n, n) its covariance, physical units (keep_prior; built at each access, as
        ``x_prior``)."""
        return None if self.Ps_prior is None else \
            self.Ps_prior * self.s[:, None] * self.s[None, :]

    def prior(self, j: int) -> tuple[np.ndarray, np.ndarray]:
        """(x, P) before update ``j``, physical units (keep_prior): the rows of ``x_prior`` and
        ``P_prior`` without building the whole arrays (M n^2: 130 MB on a 2-hour flight)."""
        if self.xs_prior is None:
            raise CoreError("ins3d filter: the pass kept no priors (keep_prior)")
        return self.xs_prior[j] * self.s, self.Ps_prior[j] * self.s[:, None] * self.s[None, :]

    def neg2_log_likelihood(self) -> float:
        """-2 ln L of the pass (up to a constant): sum(nu' S^-1 nu + ln det S) over the updates."""
        return float(self.beta2.sum() + np.linalg.slogdet(self.S)[1].sum())


def white_variance(model: Ins3dModel, r: np.ndarray) -> np.ndarray:
    """The white part of the reference variance: the published one minus the Markov states'
    sigma^2 (floored at 10 % of the published one)."""
    r = np.asarray(r, dtype=float)
    s2 = np.zeros(3)
    s2[:model.rows] = model.markov_sigma() ** 2
    return np.ascontiguousarray(np.maximum(r - s2[None, :], 0.1 * r))


def run_forward(model: Ins3dModel, steps: NavSteps, refs: RefRows,
                gate: GateConfig = GateConfig(), x0: np.ndarray | None = None,
                P0: np.ndarray | None = None, keep_cov: bool = False,
                keep_prior: bool = False, threads: int | None = None) -> Ins3dForward:
    """Filter the whole flight (x0 default 0, P0 default diag(model.p0())); ``keep_cov``
    keeps the posterior covariance of every update, ``keep_prior`` the state and covariance
    before every update (what the two-filter combination and GLR need). ``threads`` (default
    ``threads.usable_threads()``): with 2, the discretisation of the steps runs ahead on a
    second thread (``_filter``; the results are the same: it pays when that core is idle --
    ``analyze_ins3d`` passes 1 while the observability Gramian runs beside)."""
    n, rows = model.n, model.rows
    p0 = model.p0()
    P0 = np.diag(p0) if P0 is None else np.asarray(P0, dtype=float)
    x0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float)
    if P0.shape != (n, n) or x0.shape != (n,):
        raise CoreError(f"ins3d filter: x0 and P0 must be ({n},) and ({n}, {n})")
    if refs.step.size and (refs.step.min() < 0 or refs.step.max() > len(steps)):
        raise CoreError("ins3d filter: reference updates outside the step grid")
    s = np.sqrt(p0)
    m = refs.t.size
    x_o, sd_o = np.empty((len(steps) + 1, n)), np.empty((len(steps) + 1, n))
    nu, S = np.empty((m, rows)), np.empty((m, rows, rows))
    b2, b2r, exc = np.empty(m), np.empty((m, rows)), np.zeros(m, dtype=np.bool_)
    Pp = np.empty((m if keep_cov else 0, n, n))
    mp = m if keep_prior else 0
    xpr, Ppr = np.empty((mp, n)), np.empty((mp, n, n))
    Ks, Si = np.empty((mp, n, rows)), np.empty((mp, rows, rows))
    thr, thr_row = gate.threshold(rows), gate.threshold(1)
    order = np.argsort(refs.step, kind="stable")
    _filter(steps, model.kernel_params(), model.qc(), s, x0, P0,
            (refs.step[order], np.ascontiguousarray(refs.z[order]),
             white_variance(model, refs.r[order]), np.ascontiguousarray(refs.a[order]),
             *model.row_args(), thr, gate.action == "reject",
             keep_cov, keep_prior, x_o, sd_o, nu, S, b2, b2r, exc, Pp, xpr, Ppr, Ks, Si),
            usable_threads() if threads is None else threads)
    return Ins3dForward(model.names, steps.t, x_o, sd_o, refs.t[order], nu, S, b2, b2r, exc,
                        b2r > thr_row, alarm_states(exc, gate), thr, thr_row,
                        Pp if keep_cov else None, *((xpr, Ppr, Ks, Si) if keep_prior else
                                                    (None,) * 4), s, x0, P0,
                        ~exc if gate.action == "reject" else np.ones(m, dtype=bool))


__all__ = ["Ins3dForward", "predict", "propagate", "run_forward", "scale_factors", "scaled_H",
           "white_variance"]
