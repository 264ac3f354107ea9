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

from dataclasses import dataclass
from typing import Any

import numpy as np

from . import information as kernel
from .errors import CoreError
from .ldl import DEFAULT_RANK_TOL, localization, seed_threshold
from .models import LinearModel
from .records import ForwardResult, output_arrays
from .scaled import scaled_model

__all__ = ["DEFAULT_RANK_TOL", "BackwardResult", "run_backward", "seed_threshold"]


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


def _inputs(model: LinearModel, fwd: Any, prior: tuple[Any, Any] | None) -> tuple:
    """(scaled model, info, u, Y0, y0) of the backward recursion of a record."""
    sm = scaled_model(model)
    n, N = model.n, len(fwd.t)
    info = _info_contributions(sm, fwd)
    if fwd.u is not None and model.B is None:
        raise CoreError(f"model {model.name!r} has no input matrix B but the record has u")
    u = np.zeros((N, sm.p)) if fwd.u is None else np.ascontiguousarray(fwd.u, dtype=float)
    Y0, y0 = np.zeros((n, n)), np.zeros(n)
    if prior is not None:
        xp, Pp = prior
        xs, Ps = sm.to_scaled(np.asarray(xp, dtype=float).reshape(n),
                              np.asarray(Pp, dtype=float).reshape(n, n))
        try:
            Yp = np.linalg.inv(np.linalg.cholesky(0.5 * (Ps + Ps.T)))
        except np.linalg.LinAlgError:
            raise CoreError("backward prior: P must be positive definite") from None
        Y0 = Yp.T @ Yp
        y0 = Y0 @ xs
    return sm, info, u, Y0, y0


def run_backward(model: LinearModel, fwd: ForwardResult, prior: tuple[Any, Any] | None = None,
                 rank_tol: float = DEFAULT_RANK_TOL) -> BackwardResult:
    """Backward information filter over ``fwd``'s record and the two-filter combination with
    its posterior x(i/i), P(i/i), in one compiled backward sweep (the one for the model's n,
    :func:`flight_fdi.core.information.sweep_for`). See the module docstring for the formulas."""
    if not isinstance(fwd, ForwardResult):
        raise CoreError(f"run_backward: expected a ForwardResult, got {type(fwd).__name__}")
    if not (np.isfinite(rank_tol) and 0 < rank_tol < 1):
        raise CoreError(f"run_backward: rank_tol must be in (0, 1), got {rank_tol!r}")
    n = model.n
    if fwd.x.shape[1] != n:
        raise CoreError(f"run_backward: the record has {fwd.x.shape[1]} states, the model {n}")
    sm, info, u, Y0, y0 = _inputs(model, fwd, prior)
    N = len(fwd.t)
    o = output_arrays({"Y": (N, n, n), "W": (N, n, n), "P_s": (N, n, n), "y": (N, n),
                       "Wv": (N, n), "x_s": (N, n), "info_ratio": (N, n), "v_tilde": (N, n),
                       "d": (N, n), "terms": (N, n), "normalized": (N, n)})
    Y, W, P_s, y, Wv, x_s, info_ratio, v_tilde, d, terms, normalized = o.values()
    informative = np.empty((N, n), dtype=bool)
    dof_k = np.empty((N, n), dtype=np.int64)
    bad, code = kernel.sweep_for(n)(
        *sm.series.args(), np.ascontiguousarray(fwd.dt, dtype=float), u, info, Y0, y0,
        np.ascontiguousarray(fwd.x), np.ascontiguousarray(fwd.P), sm.s, float(rank_tol), Y, y,
        W, Wv, x_s, P_s, info_ratio, informative, v_tilde, d, terms, dof_k, normalized)
    if code == 1:
        raise CoreError(f"backward filter: singular I + Y Q at index {bad}")
    if code == 2:
        raise CoreError(f"two-filter combination: I + Y P_f or P_f is singular at index {bad}")
    loc = localization(v_tilde, d, terms, dof_k, normalized)
    dof = dof_k[:, -1]
    invertible = dof == n
    x_b = np.full((N, n), np.nan)
    P_b = np.full((N, n, n), np.nan)
    if np.any(invertible):  # the backward estimate itself, where it exists (scaled solve)
        Yi = Y[invertible] * sm.SS
        Pb = np.linalg.inv(Yi)
        P_b[invertible] = 0.5 * (Pb + np.swapaxes(Pb, 1, 2)) * sm.SS
        x_b[invertible] = np.linalg.solve(Yi, (y[invertible] * sm.s)[:, :, None])[:, :, 0] * sm.s
    return BackwardResult(
        t=np.asarray(fwd.t, dtype=float), Y=Y, y=y, x_b=x_b, P_b=P_b, invertible=invertible,
        x_s=x_s, P_s=P_s, v=x_b - fwd.x, W=W, Wv=Wv, J=np.asarray(loc.J, dtype=float),
        dof=dof.astype(np.int64), threshold=seed_threshold(dof), info_ratio=info_ratio,
        localization=loc, rank_tol=float(rank_tol))
