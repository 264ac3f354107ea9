"""Post-flight diagnosis by the seed method (SPEC section 3; seed 000, formulas 7.12-7.20).

* :func:`udu` -- P = U diag(D) U^T with U unit upper triangular (7.15).
* :func:`localize` -- the decomposition of J into element terms and the first element whose
  cumulative bound J(i/k) <= gamma_k^2 = k + 3 sqrt(2k) is violated (7.16, 7.17), from the
  difference covariance dP (seed form) or from its information W = dP^-1 (information form).
* :func:`fisher` / :func:`fisher_threshold` -- the sliding-window variance ratio (7.18-7.20).
* :func:`diagnose` -- all of it over a record: per step, per element, and a verdict.

Information form (used over a flight, where the backward information Y is often singular):
W = L Lam L^T with L = dU^-T unit lower triangular and Lam = dD^-1 (top-down LDL^T). With
q = L^-1 (W v) = Lam L^T v = Lam v~, the k-th term is v~_k^2 / dD_kk = q_k^2 / Lam_k. A pivot
Lam_k that is zero (no backward information on element k given elements 1..k-1) contributes 0
and one degree of freedom fewer. Pivots are judged relative to the same pivot of the forward
information P_f^-1 (which bounds W from above, so the ratio lies in [0, 1]); a ratio at or below
``rank_tol`` counts as zero.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.special import chdtri

from .errors import CoreError
from .kalman import ForwardResult, scaled_model
from .models import LinearModel
from .smoother import DEFAULT_RANK_TOL, BackwardResult, seed_threshold

VERDICTS = ("no_fault", "glitch", "failure", "ambiguous", "insufficient_data")


# --------------------------------------------------------------------------- decompositions

def _square(P: Any, what: str) -> np.ndarray:
    arr = np.asarray(P, dtype=float)
    if arr.ndim < 2 or arr.shape[-1] != arr.shape[-2]:
        raise CoreError(f"{what}: expected square matrices, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise CoreError(f"{what}: contains NaN or Inf")
    sym = np.abs(arr - np.swapaxes(arr, -1, -2))
    if np.any(sym > 1e-9 * np.maximum(np.abs(arr), np.abs(np.swapaxes(arr, -1, -2))) + 1e-300):
        raise CoreError(f"{what}: not symmetric")
    return arr


def udu(P: Any, *, check: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """U, D with P = U diag(D) U^T, U unit upper triangular (bottom-up). Works on stacks
    (..., n, n). P must be symmetric positive definite (CoreError otherwise; ``check=False``
    skips the finiteness / symmetry checks for arrays the core computed itself)."""
    A = _square(P, "udu") if check else P
    n = A.shape[-1]
    U = np.zeros(A.shape)
    D = np.zeros(A.shape[:-1])
    idx = np.arange(n)
    U[..., idx, idx] = 1.0
    for j in range(n - 1, -1, -1):
        UD = U[..., j, j + 1:] * D[..., j + 1:]                     # U_jk D_k, k > j
        D[..., j] = A[..., j, j] - np.sum(UD * U[..., j, j + 1:], axis=-1)
        if np.any(~(D[..., j] > 0)):
            raise CoreError("udu: matrix is not positive definite "
                            f"(pivot {j} = {np.min(D[..., j]):.3g})")
        # U_ij = (P_ij - sum_k>j U_ik U_jk D_k) / D_j, i < j
        U[..., :j, j] = (A[..., :j, j] - np.einsum("...ik,...k->...i", U[..., :j, j + 1:], UD)) \
            / D[..., j][..., None]
    return U, D


def ldl(W: Any, ref: Any = None, rank_tol: float = DEFAULT_RANK_TOL, *, check: bool = True
        ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """L, Lam, informative with W = L diag(Lam) L^T, L unit lower triangular (top-down), for
    symmetric positive *semi*definite W (stacks allowed). Pivot k counts as zero when
    Lam_k <= rank_tol * ref_k (``ref``: reference pivots, default the diagonal of W); its
    column of L is then left as that of the identity."""
    A = _square(W, "ldl") if check else W
    n = A.shape[-1]
    refs = np.abs(A[..., np.arange(n), np.arange(n)]) if ref is None else np.asarray(ref, float)
    L = np.zeros(A.shape)
    Lam = np.zeros(A.shape[:-1])
    informative = np.zeros(A.shape[:-1], dtype=bool)
    idx = np.arange(n)
    L[..., idx, idx] = 1.0
    for j in range(n):
        LD = L[..., j, :j] * Lam[..., :j]                              # L_jk Lam_k, k < j
        piv = A[..., j, j] - np.sum(LD * L[..., j, :j], axis=-1)
        ok = piv > rank_tol * refs[..., j]
        informative[..., j] = ok
        Lam[..., j] = np.where(ok, piv, 0.0)
        col = (A[..., j + 1:, j] - np.einsum("...ik,...k->...i", L[..., j + 1:, :j], LD))
        with np.errstate(divide="ignore", invalid="ignore"):
            col = col / np.where(ok, piv, 1.0)[..., None]
        L[..., j + 1:, j] = np.where(ok[..., None], col, 0.0)
    return L, Lam, informative


def _solve_unit_upper(U: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = b.shape[-1]
    x = np.array(b, dtype=float)
    for i in range(n - 2, -1, -1):
        x[..., i] -= np.einsum("...k,...k->...", U[..., i, i + 1:], x[..., i + 1:])
    return x


def _solve_unit_lower(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    n = b.shape[-1]
    x = np.array(b, dtype=float)
    for i in range(1, n):
        x[..., i] -= np.einsum("...k,...k->...", L[..., i, :i], x[..., :i])
    return x


# --------------------------------------------------------------------------- localization

@dataclass
class Localization:
    """The decomposition of J into element terms (7.16, 7.17); arrays over elements k.

    v_tilde: dU^-1 v (NaN where an element carries no information); d: dD (inf there);
    terms: cumulative J(i/k); J: the total; gammas: gamma^2 for the cumulative effective degrees
    of freedom ``dof`` (NaN while 0); element: index of the first k with J(i/k) > gamma_k^2, or
    None. For stacks of steps, ``element`` is an integer array with -1 for none.
    """

    v_tilde: np.ndarray
    d: np.ndarray
    terms: np.ndarray
    J: Any
    gammas: np.ndarray
    element: Any
    dof: np.ndarray
    normalized: np.ndarray = field(default_factory=lambda: np.zeros(0))  # v~_k / sqrt(d_k)


def _first_violation(terms: np.ndarray, dof: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    gammas = seed_threshold(dof)
    with np.errstate(invalid="ignore"):
        viol = (dof > 0) & (terms > gammas)
    first = np.where(viol.any(axis=-1), np.argmax(viol, axis=-1), -1)
    return gammas, first


def localize(v: Any = None, dP: Any = None, W: Any = None, Wv: Any = None, ref: Any = None,
             rank_tol: float = DEFAULT_RANK_TOL, *, check: bool = True) -> Localization:
    """Localize a violation to a state element.

    Seed form: ``localize(v, dP=dP)`` -- dP = U D U^T, v~ = U^-1 v, term_k = v~_k^2 / D_k.
    Information form: ``localize(v, W=W)`` or ``localize(Wv=Wv, W=W)`` (W v is defined even
    where v is not) -- W = L Lam L^T, q = L^-1 (W v), term_k = q_k^2 / Lam_k, 0 where Lam_k is
    zero (see :func:`ldl`; ``ref`` are the reference pivots, e.g. 1 / udu(P_f)[1]).
    Works on one vector (n,) or stacks (..., n). ``check=False`` skips the input checks (for
    arrays the core computed itself).
    """
    if (dP is None) == (W is None):
        raise CoreError("localize: give exactly one of dP (seed form) and W (information form)")
    if dP is not None:
        if v is None:
            raise CoreError("localize: the seed form needs v")
        vv = np.asarray(v, dtype=float)
        if not np.all(np.isfinite(vv)):
            raise CoreError("localize: v contains NaN or Inf")
        U, D = udu(dP)
        if vv.shape != D.shape:
            raise CoreError(f"localize: v has shape {vv.shape}, dP {np.shape(dP)}")
        vt = _solve_unit_upper(U, vv)
        single = vt * vt / D
        informative = np.ones(D.shape, dtype=bool)
        d = D
    else:
        Wm = np.asarray(W, dtype=float)
        if Wv is None:
            if v is None:
                raise CoreError("localize: the information form needs v or Wv")
            vv = np.asarray(v, dtype=float)
            if not np.all(np.isfinite(vv)):
                raise CoreError("localize: v contains NaN or Inf")
            Wvv = np.einsum("...ij,...j->...i", Wm, vv)
        else:
            Wvv = np.asarray(Wv, dtype=float)
        if check and not np.all(np.isfinite(Wvv)):
            raise CoreError("localize: W v contains NaN or Inf")
        L, Lam, informative = ldl(Wm, ref, rank_tol, check=check)
        if Wvv.shape != Lam.shape:
            raise CoreError(f"localize: W v has shape {Wvv.shape}, W {Wm.shape}")
        q = _solve_unit_lower(L, Wvv)
        safe = np.where(informative, Lam, 1.0)
        single = np.where(informative, q * q / safe, 0.0)
        vt = np.where(informative, q / safe, np.nan)
        d = np.where(informative, 1.0 / safe, np.inf)
    terms = np.cumsum(single, axis=-1)
    dof = np.cumsum(informative, axis=-1)
    gammas, first = _first_violation(terms, dof)
    with np.errstate(invalid="ignore"):
        normalized = np.where(informative, vt / np.sqrt(np.where(informative, d, 1.0)), np.nan)
    if terms.ndim == 1:
        element: Any = None if first < 0 else int(first)
        J: Any = float(terms[-1])
    else:
        element, J = first, terms[..., -1]
    return Localization(v_tilde=vt, d=d, terms=terms, J=J, gammas=gammas, element=element,
                        dof=dof, normalized=normalized)


# --------------------------------------------------------------------------- Fisher test

def fisher_threshold(window: int) -> tuple[float, float, float]:
    """(a, b, eta^2) for a window of N samples: a = N/(N-2), b = 4N(N-1)/((N-2)^2 (N-4)),
    eta^2 = a + 3 sqrt(b) (7.19, 7.20). Needs N > 4."""
    if isinstance(window, bool) or not isinstance(window, (int, np.integer)) or window <= 4:
        raise CoreError(f"fisher window must be an integer > 4, got {window!r}")
    N = float(window)
    a = N / (N - 2.0)
    b = 4.0 * N * (N - 1.0) / ((N - 2.0) ** 2 * (N - 4.0))
    return a, b, a + 3.0 * np.sqrt(b)


def fisher(normalized: Any, window: int) -> np.ndarray:
    """F(i) = sample variance (N-1 denominator, mean removed) of the normalized residual over the
    window of ``window`` samples ending at i (7.18; the predicted variance is 1 after
    normalization). Series (T,) or (T, k); NaN until the window is full or where it holds NaN."""
    fisher_threshold(window)
    x = np.asarray(normalized, dtype=float)
    one = x.ndim == 1
    if one:
        x = x[:, None]
    T = x.shape[0]
    F = np.full(x.shape, np.nan)
    if T < window:
        return F[:, 0] if one else F
    valid = np.isfinite(x)
    centre = np.array([np.median(c[f]) if f.any() else 0.0 for c, f in zip(x.T, valid.T)])
    xc = np.where(valid, x - centre, 0.0)
    zero = np.zeros((1, x.shape[1]))
    c1 = np.concatenate([zero, np.cumsum(xc, axis=0)])
    c2 = np.concatenate([zero, np.cumsum(xc * xc, axis=0)])
    cn = np.concatenate([zero, np.cumsum(valid, axis=0)])
    s1 = c1[window:] - c1[:-window]
    s2 = c2[window:] - c2[:-window]
    cnt = cn[window:] - cn[:-window]
    var = np.maximum(s2 - s1 * s1 / window, 0.0) / (window - 1)
    F[window - 1:] = np.where(cnt == window, var, np.nan)
    return F[:, 0] if one else F


# --------------------------------------------------------------------------- over a record

@dataclass(frozen=True)
class DiagnosisConfig:
    """Rules of :func:`diagnose` (see its docstring for how they are used).

    fisher_window: samples in the Fisher window (> 4).
    persistence_s: a J violation episode must last at least this long.
    episode_probability: ... and its peak J must exceed the chi-square(dof) quantile of this
        upper-tail probability (beyond the seed: J is strongly correlated in time, so on healthy
        flights the seed bound gamma^2 is exceeded for tens of seconds at a time; only the size of
        the peak separates a fault from that).
    min_valid_steps: fewer valid steps than this -> ``insufficient_data``.
    rank_tol: information-fraction tolerance for the effective degrees of freedom.
    """

    fisher_window: int = 50
    persistence_s: float = 1.0
    episode_probability: float = 1e-6
    min_valid_steps: int = 100
    rank_tol: float = DEFAULT_RANK_TOL

    def __post_init__(self) -> None:
        fisher_threshold(self.fisher_window)
        val = self.persistence_s
        if isinstance(val, bool) or not isinstance(val, (int, float)) or not np.isfinite(val) \
                or val < 0:
            raise CoreError(f"DiagnosisConfig.persistence_s must be a number >= 0, got {val!r}")
        p = self.episode_probability
        if isinstance(p, bool) or not isinstance(p, (int, float)) or not 0 < p < 1:
            raise CoreError(f"DiagnosisConfig.episode_probability must be in (0, 1), got {p!r}")
        if isinstance(self.min_valid_steps, bool) or not isinstance(self.min_valid_steps, int) \
                or self.min_valid_steps < 1:
            raise CoreError(f"DiagnosisConfig.min_valid_steps must be an integer >= 1, got "
                            f"{self.min_valid_steps!r}")
        r = self.rank_tol
        if isinstance(r, bool) or not isinstance(r, (int, float)) or not 0 < r < 1:
            raise CoreError(f"DiagnosisConfig.rank_tol must be in (0, 1), got {r!r}")


@dataclass
class ElementReport:
    name: str
    J_peak: float           # peak of the cumulative J(i/k) over the valid steps
    gamma2: float           # its threshold at that step (for the effective dof there)
    F_peak: float           # peak Fisher statistic over the valid steps (NaN: no information)
    eta2: float             # its threshold
    exceed_fraction: float  # fraction of valid steps with J(i/k) > gamma_k^2
    dof: int                # effective cumulative degrees of freedom at the J peak
    F_violated: bool = False  # a persistent Fisher violation around the J episode

    def as_dict(self) -> dict:
        return {"name": self.name, "J_peak": self.J_peak, "gamma2": self.gamma2,
                "F_peak": self.F_peak, "eta2": self.eta2,
                "exceed_fraction": self.exceed_fraction, "dof": self.dof}


@dataclass
class SeedDiagnosis:
    """Result of :func:`diagnose` (arrays over N steps and n elements)."""

    t: np.ndarray
    valid: np.ndarray           # (N,) steps used for the verdict
    J: np.ndarray               # (N,) total J
    dof: np.ndarray             # (N,) total effective dof
    gamma2: np.ndarray          # (N,) seed threshold of the total (NaN where dof = 0)
    terms: np.ndarray           # (N, n) cumulative J(i/k)
    gammas: np.ndarray          # (N, n) seed thresholds of J(i/k)
    element_dof: np.ndarray     # (N, n) cumulative effective dof
    first_element: np.ndarray   # (N,) first violating element, -1 for none
    normalized: np.ndarray      # (N, n) v~_k / sqrt(dD_kk) (NaN where not informative)
    v_tilde: np.ndarray         # (N, n) v~ = dU^-1 v, physical units (NaN: not informative)
    delta_d: np.ndarray         # (N, n) dD, physical units (inf: not informative)
    F: np.ndarray               # (N, n) Fisher statistics
    eta2: float
    elements: list[ElementReport]
    verdict: str
    element: str | None
    onset_t: float | None       # time of the peak J of the episode
    end_t: float | None         # last step of the episode (None: lasts to the end)
    episode: tuple[float, float] | None  # first and last time of the J episode
    config: DiagnosisConfig

    def summary(self) -> dict:
        return {"verdict": self.verdict, "element": self.element,
                "elements": [e.as_dict() for e in self.elements]}


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[start, end] index pairs (inclusive) of the runs of True in ``mask``."""
    m = np.concatenate([[False], np.asarray(mask, dtype=bool), [False]])
    d = np.diff(m.astype(np.int8))
    starts = np.flatnonzero(d == 1)
    ends = np.flatnonzero(d == -1) - 1
    return list(zip(starts.tolist(), ends.tolist()))


def _min_steps(t: np.ndarray, seconds: float) -> int:
    if len(t) < 2:
        return 1
    dt = float(np.median(np.diff(t)))
    return max(1, int(np.ceil(seconds / dt - 1e-9))) if dt > 0 else 1


def diagnose(model: LinearModel, fwd: ForwardResult, bwd: BackwardResult,
             config: DiagnosisConfig | None = None, **settings: Any) -> SeedDiagnosis:
    """The seed method over a record: J, its element terms, the Fisher statistics, a verdict.

    ``config`` (default :class:`DiagnosisConfig`) or its fields as keywords, e.g.
    ``diagnose(model, fwd, bwd, fisher_window=100)``.

    Per step i the information form of :func:`localize` gives the cumulative terms J(i/k), their
    seed bounds gamma^2 for the effective dof, the first violating element and the normalized
    residuals v~_k / sqrt(dD_kk), whose Fisher statistics F_k use a window of
    ``fisher_window`` samples. The verdict follows these rules (choices beyond the seed are
    marked):

    * valid steps: those where the backward filter has reached its full effective dof (the
      maximum over the record) -- the last few steps, where it has seen only a handful of
      measurements, are left out. Fewer than ``min_valid_steps`` -> ``insufficient_data``.
    * J episode (beyond): a run of consecutive valid steps with J > gamma^2(dof) lasting at
      least ``persistence_s`` whose peak J exceeds the chi-square(dof) quantile of
      ``episode_probability``. On healthy flights J exceeds gamma^2 on about 1.6 % of the steps
      (for 3 dof) in runs of up to a minute, because J is strongly correlated in time; what
      separates a fault is the size of the peak. No episode -> ``no_fault``. Of several
      episodes the one with the largest peak is reported.
    * element: the first element k whose cumulative J(i/k) violates gamma_k^2 at the peak step
      (7.17). onset: the time of the peak (the two-filter residual is inconsistent on *both*
      sides of a step fault, so the episode itself starts long before the fault; its peak marks
      the change). end: the last step of the episode, None when it lasts to the last valid step.
    * Fisher (beyond: persistence): element k's test is violated when F_k > eta^2 for more than
      ``fisher_window`` consecutive valid steps between one window before the episode and its
      end. A lone outlier stays in the window for exactly ``fisher_window`` steps, so it cannot
      count; a failure keeps the residual varying for longer.
    * verdict: Fisher violated on the episode's element -> ``failure`` (J and F together);
      only on other elements -> ``ambiguous``; on none -> ``glitch`` (J alone).
    """
    if config is None:
        try:
            config = DiagnosisConfig(**settings)
        except TypeError as exc:
            raise CoreError(f"diagnose: {exc}") from None
    elif settings:
        raise CoreError("diagnose: give either config or keyword settings, not both")
    if not isinstance(config, DiagnosisConfig):
        raise CoreError(f"diagnose: config must be a DiagnosisConfig, got {type(config).__name__}")
    sm = scaled_model(model)
    n = model.n
    N = len(fwd.t)
    if len(bwd.t) != N:
        raise CoreError(f"diagnose: forward has {N} steps, backward {len(bwd.t)}")
    t = np.asarray(fwd.t, dtype=float)
    if config.rank_tol == bwd.rank_tol:
        loc = bwd.localization  # computed by the backward pass (v~, dD in physical units)
        v_tilde, delta_d = loc.v_tilde, loc.d
    else:  # information form in scaled coordinates; reference pivots of the forward information
        _, Df = udu(fwd.P / sm.SS)
        loc = localize(W=bwd.W * sm.SS, Wv=bwd.Wv * sm.s, ref=1.0 / Df,
                       rank_tol=config.rank_tol)
        v_tilde, delta_d = loc.v_tilde * sm.s, loc.d * sm.SS.diagonal()
    terms, gammas, edof, first = loc.terms, loc.gammas, loc.dof, loc.element
    J = terms[:, -1]
    dof = edof[:, -1]
    gamma2 = seed_threshold(dof)
    _, _, eta2 = fisher_threshold(config.fisher_window)
    F = fisher(loc.normalized, config.fisher_window)

    full = int(dof.max()) if N else 0
    valid = (dof == full) & (full > 0)
    with np.errstate(invalid="ignore"):
        viol_k = (edof > 0) & (terms > gammas) & valid[:, None]
        F_viol = (F > eta2) & valid[:, None]
    n_valid = int(valid.sum())

    reports: list[ElementReport] = []
    for k in range(n):
        jk = np.where(valid, terms[:, k], -np.inf)
        ip = int(np.argmax(jk))
        Fk = F[valid, k]
        Fk = Fk[np.isfinite(Fk)]
        reports.append(ElementReport(
            name=model.state_names[k],
            J_peak=float(terms[ip, k]) if n_valid else float("nan"),
            gamma2=float(gammas[ip, k]) if n_valid else float("nan"),
            F_peak=float(Fk.max()) if Fk.size else float("nan"),
            eta2=float(eta2),
            exceed_fraction=float(viol_k[:, k].sum() / n_valid) if n_valid else 0.0,
            dof=int(edof[ip, k]) if n_valid else 0))

    def result(verdict: str, element: str | None = None, onset: float | None = None,
               end: float | None = None, episode: tuple | None = None) -> SeedDiagnosis:
        return SeedDiagnosis(t=t, valid=valid, J=J, dof=dof, gamma2=gamma2, terms=terms,
                             gammas=gammas, element_dof=edof, first_element=first,
                             normalized=loc.normalized, v_tilde=v_tilde, delta_d=delta_d, F=F,
                             eta2=float(eta2), elements=reports,
                             verdict=verdict, element=element, onset_t=onset, end_t=end,
                             episode=episode, config=config)

    if n_valid < config.min_valid_steps:
        return result("insufficient_data")
    strong = float(chdtri(full, config.episode_probability))
    min_run = _min_steps(t, config.persistence_s)
    episodes = []
    for s0, e0 in _runs(viol_k.any(axis=1)):
        peak = s0 + int(np.argmax(J[s0:e0 + 1]))
        if e0 - s0 + 1 >= min_run and J[peak] > strong:
            episodes.append((s0, e0, peak))
    if not episodes:
        return result("no_fault")
    s0, e0, peak = max(episodes, key=lambda ep: float(J[ep[2]]))
    k0 = int(first[peak])
    lo = max(0, s0 - config.fisher_window)
    for k in range(n):
        runs = _runs(F_viol[lo:e0 + 1, k])
        reports[k].F_violated = any(e - s + 1 > config.fisher_window for s, e in runs)
    last_valid = int(np.flatnonzero(valid)[-1])
    episode = (float(t[s0]), float(t[e0]))
    end = None if e0 >= last_valid else float(t[e0])
    name = model.state_names[k0]
    if reports[k0].F_violated:
        return result("failure", name, float(t[peak]), end, episode)
    if any(r.F_violated for r in reports):
        return result("ambiguous", name, float(t[peak]), end, episode)
    return result("glitch", name, float(t[peak]), end, episode)
