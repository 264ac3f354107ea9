"""Post-flight backward information filter and two-filter smoother (SPEC section 3, seed 000).

The record is replayed backwards (i = N ... 1) with an information filter that starts with zero
information (Fraser--Potter), or with an optional prior at the end. At step i it holds the
backward prediction ``Y_i, y_i`` -- the information about x_i from the measurements i+1..N::

    update at i:          Y <- Y + H^T R^-1 H,   y <- y + H^T R^-1 z         (fused samples only)
    predict to i-1:       Y <- Phi^T (I + Y Q)^-1 Y Phi
                          y <- Phi^T (I + Y Q)^-1 (y - Y Bd u)

(``x_i = Phi_i x_{i-1} + Bd_i u_i + w_i``, w ~ N(0, Qd_i)), which needs no inverse of Y.
Combined with the forward filter's x_f = x(i/i), P_f = P(i/i) (independent errors):

    W   = (P_f + Y^-1)^-1       = (I + Y P_f)^-1 Y             information of v = x_b - x_f
    W v                         = (I + Y P_f)^-1 (y - Y x_f)
    x(i/N) = (P_f^-1 + Y)^-1 (P_f^-1 x_f + y) = x_f + P_f (W v)
    P(i/N) = (P_f^-1 + Y)^-1                  = P_f - P_f W P_f

all of which exist for singular Y. The seed's statistic J = v^T (P_f + P_b)^-1 v (7.12) and its
element terms (7.16) come from the LDL^T decomposition of W and W v
(:func:`flight_fdi.core.diagnosis.localize`, information form): J = sum_k q_k^2 / Lam_k over the
pivots where the backward filter has information; their number is the effective degrees of
freedom (the numerical rank of W). A pivot counts when it exceeds ``rank_tol`` times the same
pivot of the forward information P_f^-1, which bounds W from above -- a scale-free fraction in
[0, 1] (``info_ratio``). The arithmetic is done in scaled coordinates x' = T^-1 x; results are in
physical units.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.linalg import lapack

from .errors import CoreError
from .kalman import ForwardResult, _gc_paused, scaled_model
from .models import LinearModel

DEFAULT_RANK_TOL = 1e-9


def seed_threshold(dof: Any) -> np.ndarray:
    """gamma^2 = k + 3 sqrt(2k) for k degrees of freedom (7.14, 7.17); NaN where k = 0."""
    k = np.asarray(dof, dtype=float)
    with np.errstate(invalid="ignore"):
        return np.where(k > 0, k + 3.0 * np.sqrt(2.0 * k), np.nan)


@dataclass
class BackwardResult:
    """The backward pass over a record (physical units; N steps, n states).

    ``Y, y``: backward prediction in information form at step i (measurements i+1..N).
    ``x_b, P_b``: the same as an estimate where Y is invertible (``invertible``), NaN elsewhere.
    ``x_s, P_s``: smoothed x(i/N), P(i/N). ``v = x_b - x_f`` (NaN where Y is singular),
    ``W``: the information of v, ``Wv``: W v (both always defined). ``J``: the chi-square
    statistic over ``dof`` informative directions, ``threshold``: gamma^2(dof) (NaN where
    dof = 0). ``info_ratio``: per element, its LDL^T pivot of W over that of P_f^-1, in [0, 1].
    ``localization``: the element decomposition of J at every step (terms J(i/k), effective
    dof per element, v~ and dD in physical units, normalized residuals).
    """

    t: np.ndarray
    Y: np.ndarray
    y: np.ndarray
    x_b: np.ndarray
    P_b: np.ndarray
    invertible: np.ndarray
    x_s: np.ndarray
    P_s: np.ndarray
    v: np.ndarray
    W: np.ndarray
    Wv: np.ndarray
    J: np.ndarray
    dof: np.ndarray
    threshold: np.ndarray
    info_ratio: np.ndarray
    localization: Any
    rank_tol: float = DEFAULT_RANK_TOL

    def __len__(self) -> int:
        return len(self.t)


def _info_contributions(sm, fwd: ForwardResult) -> np.ndarray:
    """[H^T R^-1 H | H^T R^-1 z] per step in scaled coordinates, zero where not fused."""
    N, m, n = fwd.H.shape
    Hs = fwd.H * sm.s                                  # (N, m, n)
    R = np.asarray(fwd.R, dtype=float)
    if m == 1:
        r = R[:, 0, 0]
        if np.any(~(r > 0)):
            raise CoreError("backward filter: R must be positive definite at every fused step "
                            f"(R <= 0 at index {int(np.argmax(~(r > 0)))})")
        Rinv = (1.0 / r)[:, None, None]
    else:
        try:
            np.linalg.cholesky(R)
        except np.linalg.LinAlgError:
            raise CoreError("backward filter: R must be positive definite at every step") from None
        Rinv = np.linalg.inv(R)
    HtRinv = np.swapaxes(Hs, 1, 2) @ Rinv              # (N, n, m)
    out = np.empty((N, n, n + 1))
    out[:, :, :n] = HtRinv @ Hs
    out[:, :, n] = np.einsum("kim,km->ki", HtRinv, fwd.z)
    out[~np.asarray(fwd.fused, dtype=bool)] = 0.0
    return out


def backward_information(model: LinearModel, fwd: ForwardResult,
                         prior: tuple[Any, Any] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """The backward recursion alone: (Y', y') per step in *scaled* coordinates (see module doc).

    Uses only dt, z, R, H, fused and u of the record: ``fwd`` may be a ForwardResult or a
    :class:`~flight_fdi.core.kalman.MeasurementRecord`. ``prior = (x, P)``: information about the
    last state before the last measurement (default: none).
    """
    sm = scaled_model(model)
    n = model.n
    N = len(fwd.t)
    info = _info_contributions(sm, fwd)
    mats, idx = sm.matrices_for(fwd.dt)
    idx_l = idx.tolist()
    steps = [mats[i] for i in idx_l]
    if fwd.u is not None:
        if model.B is None:
            raise CoreError(f"model {model.name!r} has no input matrix B but the record has u")
        Bd = np.stack([mt.Bd for mt in mats])[idx]
        bus = np.einsum("kip,kp->ki", Bd, np.asarray(fwd.u, dtype=float))
    # Z = [Y | y], the information about x_i from the measurements after i; Phi_aug =
    # [[Phi, -Bd u], [0, 1]] so that Z Phi_aug = [Y Phi | y - Y Bd u]
    Z = np.zeros((n, n + 1))
    if prior is not None:
        xp, Pp = prior
        xs, Ps = sm.to_scaled(np.asarray(xp, dtype=float).reshape(n),
                              np.asarray(Pp, dtype=float).reshape(n, n))
        try:
            Yp = np.linalg.inv(np.linalg.cholesky(0.5 * (Ps + Ps.T)))
        except np.linalg.LinAlgError:
            raise CoreError("backward prior: P must be positive definite") from None
        Yp = Yp.T @ Yp
        Z[:, :n] = Yp
        Z[:, n] = Yp @ xs
    # One product gives the right-hand side and the matrix of the solve. With the information
    # of step i added, Z = [Y | y] + [H^T R^-1 H | H^T R^-1 z] =: Z_pred + Z_meas:
    #   G = Z [Phi_aug | Q_aug] = [Y Phi | y - Y Bd u | Y Q],   Q_aug = [[Qd], [0]],
    #   solve (I + Y Q) C = G[:, :n+1],   Z_pred(i-1) = Phi^T C.
    # The loop carries Z^T, so that LAPACK gets Fortran-ordered operands without copies, and the
    # parts that do not depend on the recursion -- Z_meas [Phi_aug | Q_aug] and the I of I + Y Q
    # -- are formed for all steps at once beforehand:
    #   G^T + [0 | I]^T = [Phi_aug | Q_aug]^T Z_pred^T + ([Phi_aug | Q_aug]^T Z_meas^T + [0 | I]^T)
    def product_matrix_T(mt) -> np.ndarray:
        G = np.zeros((n + 1, 2 * n + 1))
        G[:n, :n] = mt.Phi
        G[n, n] = 1.0
        G[:n, n + 1:] = mt.Qd
        return np.ascontiguousarray(G.T)

    base = [product_matrix_T(mt) for mt in mats]
    if fwd.u is None:
        prodT = [base[i] for i in idx_l]
        allT = np.stack(base)[idx]
    else:
        allT = np.stack(base)[idx]
        allT[:, n, :n] = -bus                       # row n of G^T holds -Bd u
        prodT = list(allT)
    infoT = np.swapaxes(info, 1, 2)                 # Z_meas^T, (N, n+1, n)
    fixed = np.einsum("kab,kbc->kac", allT, infoT)
    fixed[:, n + 1:, :] += sm.I
    fixed_l = list(fixed)
    # (memory: these per-step arrays are large on long flights and not used in the loop)
    del info, infoT
    if fwd.u is None:
        del allT
    Phis = [mt.Phi for mt in steps]
    Zt = np.ascontiguousarray(Z.T)
    dgesv = lapack.dgesv
    out: list[np.ndarray] = [None] * N  # type: ignore[list-item]
    with _gc_paused():
        for i in range(N - 1, 0, -1):
            out[i] = Zt
            Gt = prodT[i].dot(Zt) + fixed_l[i]
            _, _, C, info_ = dgesv(Gt[n + 1:].T, Gt[:n + 1].T, overwrite_a=1, overwrite_b=1)
            if info_ != 0:
                raise CoreError(f"backward filter: singular I + Y Q at index {i}")
            Zt = C.T.dot(Phis[i])
            if i & 31 == 0:
                # Y is symmetric in exact arithmetic; the rounding asymmetry stays near 1e-14
                # relative, so it is removed periodically here and in the result below
                Zt[:n] = 0.5 * (Zt[:n] + Zt[:n].T)
        out[0] = Zt
    del fixed_l, fixed, prodT
    Zs = np.swapaxes(np.array(out), 1, 2)
    del out
    Ys = Zs[:, :, :n]
    return 0.5 * (Ys + np.swapaxes(Ys, 1, 2)), np.ascontiguousarray(Zs[:, :, n])


def run_backward(model: LinearModel, fwd: ForwardResult, prior: tuple[Any, Any] | None = None,
                 rank_tol: float = DEFAULT_RANK_TOL,
                 information: tuple[np.ndarray, np.ndarray] | None = None) -> BackwardResult:
    """Backward information filter over ``fwd``'s record and the two-filter combination with
    its posterior x(i/i), P(i/i). See the module docstring for the formulas.

    ``information``: the result of :func:`backward_information` for this record, computed
    beforehand (e.g. in another process while the forward pass ran); ``prior`` is then unused."""
    if not isinstance(fwd, ForwardResult):
        raise CoreError(f"run_backward: expected a ForwardResult, got {type(fwd).__name__}")
    if not (np.isfinite(rank_tol) and 0 < rank_tol < 1):
        raise CoreError(f"run_backward: rank_tol must be in (0, 1), got {rank_tol!r}")
    sm = scaled_model(model)
    n = model.n
    if fwd.x.shape[1] != n:
        raise CoreError(f"run_backward: the record has {fwd.x.shape[1]} states, the model {n}")
    if information is None:
        Ys, ys = backward_information(model, fwd, prior)
    else:
        Ys, ys = information
        if Ys.shape != (len(fwd.t), n, n) or ys.shape != (len(fwd.t), n):
            raise CoreError(f"run_backward: information for {Ys.shape[0]} steps and "
                            f"{Ys.shape[1]} states does not fit the record ({len(fwd.t)}, {n})")
    s, SS = sm.s, sm.SS
    xf, Pf = sm.to_scaled(fwd.x, fwd.P)
    return _combine(Ys, ys, xf, Pf, s, SS, fwd.t, rank_tol)


#: steps combined per block: the combination is per step, and its temporaries (a dozen n x n
#: arrays per step) for a 10-hour flight in one piece would be several hundred MB
_COMBINE_BLOCK = 32768


def _combine(Ys: np.ndarray, ys: np.ndarray, xf: np.ndarray, Pf: np.ndarray, s: np.ndarray,
             SS: np.ndarray, t: np.ndarray, rank_tol: float) -> BackwardResult:
    """Two-filter combination (scaled inputs, physical outputs), block by block into
    preallocated results (the same numbers as one vectorised call: every step is independent)."""
    N = xf.shape[0]
    if N <= _COMBINE_BLOCK:
        return _combine_block(Ys, ys, xf, Pf, s, SS, t, rank_tol)
    out: BackwardResult | None = None
    for a in range(0, N, _COMBINE_BLOCK):
        b = min(N, a + _COMBINE_BLOCK)
        part = _combine_block(Ys[a:b], ys[a:b], xf[a:b], Pf[a:b], s, SS, t[a:b], rank_tol)
        if out is None:  # preallocate every array field (and those of the localization)
            def full(x: Any) -> Any:
                return np.empty((N,) + x.shape[1:], x.dtype) if isinstance(x, np.ndarray) \
                    and x.ndim >= 1 and x.shape[0] == b - a else x
            loc = part.localization
            out = BackwardResult(**{f.name: full(getattr(part, f.name))
                                    for f in dataclasses.fields(BackwardResult)})
            out.localization = type(loc)(**{f.name: full(getattr(loc, f.name))
                                            for f in dataclasses.fields(type(loc))})
        for obj, src in ((out, part), (out.localization, part.localization)):
            for f in dataclasses.fields(obj):
                dst = getattr(obj, f.name)
                if isinstance(dst, np.ndarray) and dst.ndim >= 1 and dst.shape[0] == N:
                    dst[a:b] = getattr(src, f.name)
        del part
    return out


def _combine_block(Ys: np.ndarray, ys: np.ndarray, xf: np.ndarray, Pf: np.ndarray,
                   s: np.ndarray, SS: np.ndarray, t: np.ndarray,
                   rank_tol: float) -> BackwardResult:
    """Two-filter combination, vectorised over the steps (scaled inputs, physical outputs)."""
    from .diagnosis import localize, udu  # diagnosis builds on this module

    N, n = xf.shape
    I = np.eye(n)
    r = ys - np.einsum("kij,kj->ki", Ys, xf)                 # y - Y x_f
    rhs = np.concatenate([Ys, r[:, :, None]], axis=2)
    sol = np.linalg.solve(I + Ys @ Pf, rhs)                  # (I + Y P_f)^-1 [Y | y - Y x_f]
    W = sol[:, :, :n]
    W = 0.5 * (W + np.swapaxes(W, 1, 2))
    Wv = np.ascontiguousarray(sol[:, :, n])
    x_s = xf + np.einsum("kij,kj->ki", Pf, Wv)
    P_s = Pf - Pf @ W @ Pf
    P_s = 0.5 * (P_s + np.swapaxes(P_s, 1, 2))
    # J and its element terms from W = L Lam L^T; reference pivots 1/D of P_f = U D U^T
    _, Df = udu(Pf, check=False)
    ref = 1.0 / Df
    loc = localize(W=W, Wv=Wv, ref=ref, rank_tol=rank_tol, check=False)
    info_ratio = np.clip(1.0 / np.where(np.isfinite(loc.d), loc.d, np.inf) / ref, 0.0, 1.0)
    dof = loc.dof[:, -1]
    invertible = dof == n
    x_b = np.full((N, n), np.nan)
    P_b = np.full((N, n, n), np.nan)
    if np.any(invertible):
        Yi = Ys[invertible]
        Pb = np.linalg.inv(Yi)
        P_b[invertible] = 0.5 * (Pb + np.swapaxes(Pb, 1, 2))
        x_b[invertible] = np.linalg.solve(Yi, ys[invertible][:, :, None])[:, :, 0]
    v = x_b - xf
    inv_s = 1.0 / s
    loc.v_tilde = loc.v_tilde * s      # back to physical units
    loc.d = loc.d * s * s
    return BackwardResult(
        t=np.asarray(t, dtype=float), Y=Ys / SS, y=ys * inv_s, x_b=x_b * s, P_b=P_b * SS,
        invertible=invertible, x_s=x_s * s, P_s=P_s * SS, v=v * s, W=W / SS, Wv=Wv * inv_s,
        J=np.asarray(loc.J, dtype=float), dof=dof.astype(np.int64),
        threshold=seed_threshold(dof), info_ratio=info_ratio, localization=loc,
        rank_tol=float(rank_tol))
