"""Kalman filtering with redundant sensors that fail (seed 001, SPEC sections 2 and 5).

The discrete system (the seed's notation)::

    x(k+1) = Phi x(k) + G w(k) + B u(k),            E[G w w^T G^T] = Qd
    z(k)   = H x(k) + v(k) + theta(k) C f(k),       v ~ N(0, R),  f = anomalous noise

``C`` is the boolean matrix that picks the failed rows of ``z`` (one column per failed row). The
anomaly ``f`` has an unknown mean and covariance ``Gamma`` with tr Gamma >> tr R. Two filters are
run while sensors are failed:

* **KF2** (``known_anomaly``, Gamma known): the innovation covariance of the failed rows grows by
  the anomaly, ``S = H P- H^T + R + C Gamma C^T``; K = P- H^T S^-1.
* **AF** (``exclude``, no prior on f): the failed rows are struck out by the exclusion matrix
  ``E`` (the identity with the failed rows removed): ``K = P- H^T E^T (E S E^T)^-1 E`` with
  S = H P- H^T + R. This is the plain Kalman filter on the rows ``E z``.

Both use P = (I - K H) P- (the gain is optimal for its own model, so the short form equals the
Joseph form). The estimation accuracy is ``J = tr(D P)`` with a weight ``D >= 0``.

The steady state (k -> infinity) of the a priori covariance P- solves the discrete algebraic
Riccati equation (DARE)::

    P- = Phi P- Phi^T - Phi P- H^T (H P- H^T + R)^-1 H P- Phi^T + Qd

solved with :func:`scipy.linalg.solve_discrete_are` (the filter DARE is the control DARE of
(Phi^T, H^T)) in the model's scaled coordinates; when that solver fails (a mode on the unit circle
that the noise does not excite makes its Hamiltonian pencil singular) the structure-preserving
doubling algorithm (SDA) is used instead, which converges for every detectable pair. A mode with
|lambda| >= 1 that the remaining rows do not observe has no finite steady state: J = +inf.

The control u = K* x_hat of the seed moves the state but not the estimation error of a linear
system, so P and J do not depend on it.

:func:`criticality` evaluates J in both modes for every set of failed sensors and classifies
sensors (vital / less important) and fault sets (admissible / inadmissible against a bound).
A model file for it is a model YAML (``models.model_from_dict``) with a ``redundancy:`` section
(:func:`redundancy_from_dict` in ``redundancy_spec``, documented in docs/criticality.md).
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field
from typing import Any, Sequence

import numpy as np

from .errors import CoreError
from .models import LinearModel
from .redundancy_spec import (  # noqa: F401 (the model file's section, re-exported)
    MAX_SENSORS, RedundancySpec, Sensor, load_redundant_model, redundancy_from_dict,
    redundant_model_from_dict)


def solve_discrete_are(*args, **kwargs):
    """:func:`scipy.linalg.solve_discrete_are`, imported at the first call: a flight analysis
    imports this module (through the multi-row update) but never solves a DARE, and
    ``scipy.linalg`` costs a fresh ``flight-fdi analyze`` ~0.15 s CPU (docs/performance.md)."""
    from scipy.linalg import solve_discrete_are as solve

    return solve(*args, **kwargs)


MODES = ("kf2", "af")


# --------------------------------------------------------------------------- the one-step math

def exclusion_matrix(m: int, failed_rows: Sequence[int]) -> np.ndarray:
    """E: the m x m identity with the rows ``failed_rows`` struck out ((m - r) x m)."""
    failed = _rows(m, failed_rows)
    return np.eye(m)[[i for i in range(m) if i not in failed]]


def anomaly_matrix(m: int, failed_rows: Sequence[int]) -> np.ndarray:
    """C: the m x r boolean (0/1) matrix whose column j is the unit vector of failed row j."""
    failed = sorted(_rows(m, failed_rows))
    return np.eye(m)[:, failed]


def _rows(m: int, rows: Sequence[int]) -> set[int]:
    out = set()
    for r in rows:
        if isinstance(r, (bool, np.bool_)) or not isinstance(r, (int, np.integer)) \
                or not 0 <= r < m:
            raise CoreError(f"failed row {r!r} is not a row index in 0..{m - 1}")
        out.add(int(r))
    return out


def kf2_gain(P_prior: Any, H: Any, R: Any, failed_rows: Sequence[int] = (),
             Gamma: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """KF2 gain and innovation covariance: S = H P- H^T + R + C Gamma C^T, K = P- H^T S^-1.

    ``Gamma``: r x r covariance of the anomaly on the r failed rows (in the order of
    ``sorted(failed_rows)``), or a vector of r variances. Returns (K (n x m), S (m x m)).
    """
    P_prior, H, R = _check_step(P_prior, H, R)
    m = H.shape[0]
    C = anomaly_matrix(m, failed_rows)
    r = C.shape[1]
    if r:
        if Gamma is None:
            raise CoreError("kf2_gain: Gamma (the anomaly covariance) is required for failed rows")
        G = np.asarray(Gamma, dtype=float)
        G = np.diag(G) if G.ndim == 1 else G
        if G.shape != (r, r) or not np.all(np.isfinite(G)):
            raise CoreError(f"kf2_gain: Gamma must be {r} x {r} (one row/column per failed row), "
                            f"got shape {np.shape(Gamma)}")
        R = R + C @ G @ C.T
    S = H @ P_prior @ H.T + R
    S = 0.5 * (S + S.T)
    K = np.linalg.solve(S, H @ P_prior).T  # P- H^T S^-1 (S symmetric)
    return K, S


def af_gain(P_prior: Any, H: Any, R: Any, failed_rows: Sequence[int] = ()
            ) -> tuple[np.ndarray, np.ndarray]:
    """AF gain K = P- H^T E^T (E S E^T)^-1 E (n x m, zero columns for the failed rows) and S."""
    P_prior, H, R = _check_step(P_prior, H, R)
    E = exclusion_matrix(H.shape[0], failed_rows)
    S = H @ P_prior @ H.T + R
    S = 0.5 * (S + S.T)
    if E.shape[0] == 0:
        return np.zeros((H.shape[1], H.shape[0])), S
    ESE = E @ S @ E.T
    K = (np.linalg.solve(ESE, E @ H @ P_prior).T) @ E
    return K, S


def _check_step(P_prior: Any, H: Any, R: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    P_prior = np.atleast_2d(np.asarray(P_prior, dtype=float))
    H = np.atleast_2d(np.asarray(H, dtype=float))
    R = np.atleast_2d(np.asarray(R, dtype=float))
    n = P_prior.shape[0]
    m = H.shape[0]
    if P_prior.shape != (n, n) or H.shape != (m, n) or R.shape != (m, m):
        raise CoreError(f"gain: shapes P {P_prior.shape}, H {H.shape}, R {R.shape} do not fit")
    for nm, a in (("P", P_prior), ("H", H), ("R", R)):
        if not np.all(np.isfinite(a)):
            raise CoreError(f"gain: {nm} contains NaN or Inf")
    return P_prior, H, R


def accuracy(D: Any, P: Any) -> float:
    """J = tr(D P) (the seed's estimation accuracy); +inf when P is infinite."""
    P = np.asarray(P, dtype=float)
    if not np.all(np.isfinite(P)):
        return math.inf
    return float(np.trace(np.asarray(D, dtype=float) @ P))


# --------------------------------------------------------------------------- steady state

@dataclass(frozen=True)
class SteadyState:
    """Steady-state Kalman filter of one measurement set (physical units).

    ``finite`` is False when a mode with |lambda| >= 1 is not observed by the rows in use: the
    covariances are then +inf and ``reason`` says which mode.
    """

    P_prior: np.ndarray      # P(k|k-1)
    P: np.ndarray            # P(k|k)
    K: np.ndarray            # gain on the rows in use (n x m_used)
    S: np.ndarray            # innovation covariance of the rows in use
    method: str              # "scipy" | "doubling" | "no-measurement" | "undetectable"
    finite: bool = True
    reason: str = ""


def _undetectable(Phi: np.ndarray, H: np.ndarray, tol: float = 1e-9) -> str:
    """'' when (Phi, H) is detectable, else a description of the first bad mode.

    PBH test: a mode lambda of Phi with |lambda| >= 1 is unobserved when [lambda I - Phi; H] has
    rank < n (smallest singular value <= tol times the matrix norm)."""
    n = Phi.shape[0]
    for lam in np.linalg.eigvals(Phi):
        if abs(lam) < 1.0 - 1e-12:
            continue
        M = np.vstack([lam * np.eye(n) - Phi, H.astype(complex)])
        sv = np.linalg.svd(M, compute_uv=False)
        if sv[-1] <= tol * max(1.0, sv[0]):
            return f"a mode with eigenvalue {complex(lam):.6g} (|lambda| >= 1) is not observed"
    return ""


def _dare_doubling(A: np.ndarray, G: np.ndarray, Q: np.ndarray, tol: float = 1e-13,
                   max_iter: int = 200) -> np.ndarray:
    """X = A^T X (I + G X)^-1 A + Q by the structure-preserving doubling algorithm.

    Filter form: A = Phi^T, G = H^T R^-1 H, Q = Qd; X = P- (the limit of the Riccati recursion
    started at 0, which is the steady state for every detectable (Phi, H)).
    """
    n = A.shape[0]
    I = np.eye(n)
    Ak, Gk, Hk = A.copy(), G.copy(), Q.copy()
    for _ in range(max_iter):
        W = np.linalg.solve(I + Gk @ Hk, np.hstack([Ak, Gk]))  # (I + G H)^-1 [A, G]
        WA, WG = W[:, :n], W[:, n:]
        H_next = Hk + Ak.T @ Hk @ WA
        G_next = Gk + Ak @ WG @ Ak.T
        Ak = Ak @ WA
        H_next = 0.5 * (H_next + H_next.T)
        G_next = 0.5 * (G_next + G_next.T)
        change = np.linalg.norm(H_next - Hk, 1)
        Hk, Gk = H_next, G_next
        if change <= tol * max(1.0, np.linalg.norm(Hk, 1)):
            return Hk
    raise CoreError("steady state: the Riccati doubling iteration did not converge")


def steady_state(Phi: Any, Qd: Any, H: Any, R: Any, scale: Any = None) -> SteadyState:
    """Steady-state a priori / a posteriori covariance and gain of the Kalman filter.

    ``scale``: typical standard deviation of each state (e.g. ``model.scale``); the DARE is
    solved in the coordinates x' = x / scale, which keeps states of very different magnitudes
    accurate. ``H`` may have zero rows (no measurement): P- then solves the Lyapunov equation
    when Phi is stable, else the result is infinite.
    """
    Phi = np.atleast_2d(np.asarray(Phi, dtype=float))
    n = Phi.shape[0]
    Qd = np.atleast_2d(np.asarray(Qd, dtype=float))
    H = np.asarray(H, dtype=float).reshape(-1, n)
    m = H.shape[0]
    R = np.asarray(R, dtype=float).reshape(m, m)
    if Phi.shape != (n, n) or Qd.shape != (n, n):
        raise CoreError(f"steady state: Phi {Phi.shape} and Qd {Qd.shape} must be {n} x {n}")
    for nm, a in (("Phi", Phi), ("Qd", Qd), ("H", H), ("R", R)):
        if not np.all(np.isfinite(a)):
            raise CoreError(f"steady state: {nm} contains NaN or Inf")
    if m and np.min(np.linalg.eigvalsh(0.5 * (R + R.T))) <= 0:
        raise CoreError("steady state: R must be positive definite")
    s = np.ones(n) if scale is None else np.asarray(scale, dtype=float).reshape(-1)
    if s.shape != (n,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise CoreError(f"steady state: scale must be {n} positive numbers")
    # scaled coordinates x' = T^-1 x
    Phis = Phi * (s[None, :] / s[:, None])
    Qs = Qd / np.outer(s, s)
    Qs = 0.5 * (Qs + Qs.T)
    Hs = H * s[None, :]

    bad = _undetectable(Phis, Hs)
    if bad:
        inf = np.full((n, n), math.inf)
        return SteadyState(inf, inf, np.full((n, m), math.nan), np.full((m, m), math.inf),
                           "undetectable", finite=False, reason=bad)
    if m == 0:
        # stable Phi: P = Phi P Phi^T + Q (Lyapunov), by doubling with G = 0
        Ps = _dare_doubling(Phis.T, np.zeros((n, n)), Qs)
        method = "no-measurement"
    else:
        Rinv_Hs = np.linalg.solve(R, Hs)
        try:
            Ps = solve_discrete_are(Phis.T, Hs.T, Qs, R)
            method = "scipy"
            if not _dare_ok(Ps, Phis, Qs, Hs, R):
                raise np.linalg.LinAlgError("inaccurate solution")
        except (np.linalg.LinAlgError, ValueError):
            Ps = _dare_doubling(Phis.T, Hs.T @ Rinv_Hs, Qs)
            method = "doubling"
        if not _dare_ok(Ps, Phis, Qs, Hs, R):
            raise CoreError("steady state: the Riccati solution does not satisfy the DARE")
    Ps = 0.5 * (Ps + Ps.T)
    P_prior = Ps * np.outer(s, s)
    if m:
        S = H @ P_prior @ H.T + R
        S = 0.5 * (S + S.T)
        K = np.linalg.solve(S, H @ P_prior).T
        IKH = np.eye(n) - K @ H
        P = IKH @ P_prior @ IKH.T + K @ R @ K.T  # Joseph form: symmetric and PSD
    else:
        S = np.zeros((0, 0))
        K = np.zeros((n, 0))
        P = P_prior.copy()
    P = 0.5 * (P + P.T)
    return SteadyState(P_prior, P, K, S, method)


def _dare_ok(X: np.ndarray, Phi: np.ndarray, Q: np.ndarray, H: np.ndarray, R: np.ndarray,
             tol: float = 1e-8) -> bool:
    if not np.all(np.isfinite(X)):
        return False
    S = H @ X @ H.T + R
    rhs = Phi @ X @ Phi.T - Phi @ X @ H.T @ np.linalg.solve(S, H @ X @ Phi.T) + Q
    scale = max(1.0, float(np.max(np.abs(X))))
    sym = 0.5 * (X + X.T)
    if np.min(np.linalg.eigvalsh(sym)) < -1e-9 * scale:
        return False
    return float(np.max(np.abs(rhs - X))) <= tol * scale


def steady_state_mode(Phi: Any, Qd: Any, H: Any, R: Any, mode: str,
                      failed_rows: Sequence[int] = (), gamma: Any = None,
                      scale: Any = None) -> SteadyState:
    """Steady state with the rows ``failed_rows`` failed, in mode ``kf2`` or ``af``.

    kf2: R + C Gamma C^T on all rows (``gamma``: one anomaly variance per row of z, or an m x m
    diagonal-free matrix whose failed block is used). af: the rows E z only.
    """
    H = np.atleast_2d(np.asarray(H, dtype=float))
    m = H.shape[0]
    R = np.asarray(R, dtype=float).reshape(m, m)
    failed = sorted(_rows(m, failed_rows))
    if mode == "af":
        keep = [i for i in range(m) if i not in failed]
        return steady_state(Phi, Qd, H[keep], R[np.ix_(keep, keep)], scale)
    if mode == "kf2":
        if failed:
            if gamma is None:
                raise CoreError("steady state kf2: the anomaly variances gamma are required")
            g = np.asarray(gamma, dtype=float)
            Gfull = np.diag(g.reshape(-1)) if g.ndim <= 1 else g
            if Gfull.shape != (m, m):
                raise CoreError(f"steady state kf2: gamma must give {m} variances (one per row)")
            C = anomaly_matrix(m, failed)
            R = R + C @ Gfull[np.ix_(failed, failed)] @ C.T
        return steady_state(Phi, Qd, H, R, scale)
    raise CoreError(f"unknown mode {mode!r}; choose one of {', '.join(MODES)}")


# --------------------------------------------------------------------------- criticality

@dataclass(frozen=True)
class FaultSetResult:
    """J in both modes for one set of failed sensors."""

    failed: tuple[int, ...]          # sensor indices (0-based)
    pattern: str                     # the seed's notation: 1 = working, 0 = failed, e.g. "10111"
    J: dict[str, float]              # mode -> tr(D P) (inf: no finite steady state)
    growth: dict[str, float]         # mode -> J / J_nominal - 1
    admissible: dict[str, bool]      # mode -> J <= bound
    reason: dict[str, str] = field(default_factory=dict)  # why J is infinite, per mode


@dataclass(frozen=True)
class CriticalityResult:
    model_name: str
    sensors: tuple[str, ...]
    bound: float
    vital_threshold: float
    J_nominal: float
    sets: tuple[FaultSetResult, ...]   # every enumerated set, by number failed then pattern
    #: mode -> sensor names whose single failure grows J by >= vital_threshold
    vital: dict[str, tuple[str, ...]]
    less_important: dict[str, tuple[str, ...]]

    def single(self, sensor: int) -> FaultSetResult:
        return next(s for s in self.sets if s.failed == (sensor,))

    def admissible_sets(self, mode: str) -> list[FaultSetResult]:
        return [s for s in self.sets if s.failed and s.admissible[mode]]

    def inadmissible_sets(self, mode: str) -> list[FaultSetResult]:
        return [s for s in self.sets if s.failed and not s.admissible[mode]]

    def kf2_never_worse(self, rtol: float = 1e-9) -> bool:
        """The seed's finding: J_KF2 <= J_AF for every fault set."""
        return all(s.J["kf2"] <= s.J["af"] * (1 + rtol) + 1e-300 for s in self.sets)

    def to_dict(self) -> dict[str, Any]:
        def num(x: float) -> float | str:
            return x if math.isfinite(x) else "inf"

        return {
            "model": self.model_name,
            "sensors": list(self.sensors),
            "bound": self.bound,
            "vital_threshold": self.vital_threshold,
            "J_nominal": self.J_nominal,
            "classes": {mode: {"vital": list(self.vital[mode]),
                               "less_important": list(self.less_important[mode])}
                        for mode in MODES},
            "sets": [{"failed": [self.sensors[k] for k in s.failed], "pattern": s.pattern,
                      "J": {m: num(v) for m, v in s.J.items()},
                      "growth": {m: num(v) for m, v in s.growth.items()},
                      "admissible": dict(s.admissible),
                      **({"reason": dict(s.reason)} if s.reason else {})}
                     for s in self.sets],
            "kf2_never_worse_than_af": self.kf2_never_worse(),
        }


def pattern_of(failed: Sequence[int], n_sensors: int) -> str:
    """The seed's set notation: '1' working, '0' failed, sensor 1 first (e.g. [10111])."""
    bad = set(failed)
    return "".join("0" if k in bad else "1" for k in range(n_sensors))


def criticality(model: LinearModel, spec: RedundancySpec,
                max_failed: int | None = None) -> CriticalityResult:
    """J = tr(D P) (steady state, a posteriori) for every set of failed sensors, KF2 and AF.

    Sets are enumerated up to ``max_failed`` failed sensors (default: the spec's, else all).
    A sensor is **vital** in a mode when its single failure grows J by at least
    ``spec.vital_threshold`` (relative), else **less important**; a fault set is **admissible**
    when J <= ``spec.bound``.
    """
    if spec.D.shape != (model.n, model.n):
        raise CoreError(f"criticality: D is {spec.D.shape}, the model has {model.n} states")
    for s in spec.sensors:
        if max(s.rows) >= model.m:
            raise CoreError(f"criticality: sensor {s.name} uses row {max(s.rows)}, the model "
                            f"has {model.m} measurement rows")
    Phi, Qd, _ = model.discretize(spec.dt)
    H, R = model.H, model.R
    gamma = spec.gamma_rows(model.m)
    ns = len(spec.sensors)
    limit = ns if max_failed is None and spec.max_failed is None else \
        (spec.max_failed if max_failed is None else max_failed)
    if not 0 <= limit <= ns:
        raise CoreError(f"criticality: max_failed must be in 0..{ns}, got {limit}")
    nominal = steady_state(Phi, Qd, H, R, model.scale)
    J0 = accuracy(spec.D, nominal.P)
    if not math.isfinite(J0):
        raise CoreError(f"criticality: the nominal filter has no steady state ({nominal.reason})")
    sets = []
    for r in range(0, limit + 1):
        for failed in itertools.combinations(range(ns), r):
            rows = spec.rows_of(failed)
            J, growth, adm, reason = {}, {}, {}, {}
            for mode in MODES:
                if not failed:
                    ss = nominal
                else:
                    ss = steady_state_mode(Phi, Qd, H, R, mode, rows, gamma, model.scale)
                j = accuracy(spec.D, ss.P)
                J[mode] = j
                growth[mode] = j / J0 - 1.0 if math.isfinite(j) else math.inf
                adm[mode] = bool(j <= spec.bound)
                if not ss.finite:
                    reason[mode] = ss.reason
            sets.append(FaultSetResult(tuple(failed), pattern_of(failed, ns), J, growth, adm,
                                       reason))
    vital, less = {}, {}
    for mode in MODES:
        if limit >= 1:
            singles = {s.failed[0]: s for s in sets if len(s.failed) == 1}
            vital[mode] = tuple(spec.sensors[k].name for k in range(ns)
                                if singles[k].growth[mode] >= spec.vital_threshold)
            less[mode] = tuple(spec.sensors[k].name for k in range(ns)
                               if singles[k].growth[mode] < spec.vital_threshold)
        else:
            vital[mode], less[mode] = (), ()
    return CriticalityResult(model.name, spec.names, spec.bound, spec.vital_threshold, J0,
                             tuple(sets), vital, less)
