"""Post-flight diagnosis by the seed method (SPEC section 3; seed 000, formulas 7.12-7.20).

* :func:`udu`, :func:`ldl`, :func:`localize` -- the decompositions and the element terms of J
  (7.15-7.17), in :mod:`flight_fdi.core.ldl` (re-exported here).
* :func:`fisher` / :func:`fisher_threshold` -- the sliding-window variance ratio (7.18-7.20).
* :func:`diagnose` -- all of it over a record: per step, per element, and a verdict.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from .errors import CoreError
from .ldl import DEFAULT_RANK_TOL, Localization, ldl, localize, seed_threshold, udu
from .models import LinearModel
from .records import ForwardResult
from .scaled import scaled_model
from .smoother import BackwardResult
from .special import chi2_isf

__all__ = ["VERDICTS", "DiagnosisConfig", "ElementReport", "Localization", "SeedDiagnosis",
           "diagnose", "fisher", "fisher_threshold", "ldl", "localize", "strongest_episode", "udu",
           "violation_mask"]

VERDICTS = ("no_fault", "glitch", "failure", "ambiguous", "insufficient_data")


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


def _element_reports(model: LinearModel, valid: np.ndarray, terms: np.ndarray,
                     gammas: np.ndarray, edof: np.ndarray, F: np.ndarray, viol_k: np.ndarray,
                     eta2: float) -> list[ElementReport]:
    """Per element: its J peak over the valid steps, the Fisher peak, the exceed fraction."""
    n_valid = int(valid.sum())
    reports = []
    for k in range(model.n):
        jk = np.where(valid, terms[:, k], -np.inf)
        ip = int(np.argmax(jk))
        Fk = F[valid, k]
        Fk = Fk[np.isfinite(Fk)]
        reports.append(ElementReport(
            name=model.state_names[k],
            J_peak=float(terms[ip, k]) if n_valid else float("nan"),
            gamma2=float(gammas[ip, k]) if n_valid else float("nan"),
            F_peak=float(Fk.max()) if Fk.size else float("nan"),
            eta2=eta2,
            exceed_fraction=float(viol_k[:, k].sum() / n_valid) if n_valid else 0.0,
            dof=int(edof[ip, k]) if n_valid else 0))
    return reports


def _localization(model: LinearModel, fwd: ForwardResult, bwd: BackwardResult,
                  rank_tol: float) -> tuple:
    """(Localization, v~, dD in physical units): the backward pass's own, or recomputed in
    information form for another ``rank_tol``."""
    if rank_tol == bwd.rank_tol:
        loc = bwd.localization  # computed by the backward pass (v~, dD in physical units)
        return loc, loc.v_tilde, loc.d
    # information form in scaled coordinates; reference pivots of the forward information
    sm = scaled_model(model)
    _, Df = udu(fwd.P / sm.SS)
    loc = localize(W=bwd.W * sm.SS, Wv=bwd.Wv * sm.s, ref=1.0 / Df, rank_tol=rank_tol)
    return loc, loc.v_tilde * sm.s, loc.d * sm.SS.diagonal()


def violation_mask(element_dof: np.ndarray, terms: np.ndarray, gammas: np.ndarray,
                   valid: np.ndarray) -> np.ndarray:
    """(N, n) the seed bound's violations: element k's term above its gamma at a valid step."""
    with np.errstate(invalid="ignore"):
        return (element_dof > 0) & (terms > gammas) & valid[:, None]


def strongest_episode(t: np.ndarray, J: np.ndarray, viol_k: np.ndarray, full: int,
                       config: DiagnosisConfig) -> tuple[int, int, int] | None:
    """(start, end, peak) of the J episode with the largest peak among those lasting
    ``persistence_s`` whose peak exceeds the chi2(full) quantile; None when there is none."""
    if full < 1:
        return None
    strong = chi2_isf(config.episode_probability, full)
    min_run = _min_steps(t, config.persistence_s)
    episodes = []
    for s0, e0 in _runs(viol_k.any(axis=1)):
        peak = s0 + int(np.argmax(J[s0:e0 + 1]))
        if e0 - s0 + 1 >= min_run and J[peak] > strong:
            episodes.append((s0, e0, peak))
    return max(episodes, key=lambda ep: float(J[ep[2]])) if episodes else None


def _diagnosis_config(config: DiagnosisConfig | None, settings: dict) -> DiagnosisConfig:
    """``config``, or a DiagnosisConfig of the keyword ``settings`` (CoreError when invalid)."""
    if config is None:
        try:
            config = DiagnosisConfig(**settings)
        except TypeError as exc:
            raise CoreError(f"diagnose: {exc}") from None
    elif settings:
        raise CoreError("diagnose: give either config or keyword settings, not both")
    if not isinstance(config, DiagnosisConfig):
        raise CoreError(f"diagnose: config must be a DiagnosisConfig, got {type(config).__name__}")
    return config


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
    config = _diagnosis_config(config, settings)
    if len(bwd.t) != len(fwd.t):
        raise CoreError(f"diagnose: forward has {len(fwd.t)} steps, backward {len(bwd.t)}")
    stats, viol_k = _statistics(model, fwd, bwd, config)
    return SeedDiagnosis(**stats, **_verdict(model, stats, viol_k, config))


def _statistics(model: LinearModel, fwd: ForwardResult, bwd: BackwardResult,
                config: DiagnosisConfig) -> tuple[dict[str, Any], np.ndarray]:
    """:func:`diagnose`'s statistics over the record: the SeedDiagnosis fields but the verdict's
    (J, its element terms and seed bounds, the Fisher statistics, the valid steps, the element
    reports without their Fisher violations), and the (N, n) ``violation_mask``."""
    t = np.asarray(fwd.t, dtype=float)
    loc, v_tilde, delta_d = _localization(model, fwd, bwd, config.rank_tol)
    terms, gammas, edof = loc.terms, loc.gammas, loc.dof
    dof = edof[:, -1]
    _, _, eta2 = fisher_threshold(config.fisher_window)
    F = fisher(loc.normalized, config.fisher_window)
    full = int(dof.max()) if len(t) else 0
    valid = (dof == full) & (full > 0)
    viol_k = violation_mask(edof, terms, gammas, valid)
    reports = _element_reports(model, valid, terms, gammas, edof, F, viol_k, float(eta2))
    return {"t": t, "valid": valid, "J": terms[:, -1], "dof": dof, "gamma2": seed_threshold(dof),
            "terms": terms, "gammas": gammas, "element_dof": edof, "first_element": loc.element,
            "normalized": loc.normalized, "v_tilde": v_tilde, "delta_d": delta_d, "F": F,
            "eta2": float(eta2), "elements": reports, "config": config}, viol_k


def _verdict(model: LinearModel, stats: dict[str, Any], viol_k: np.ndarray,
             config: DiagnosisConfig) -> dict[str, Any]:
    """:func:`diagnose`'s verdict from its ``_statistics`` (the rules in its docstring): the
    SeedDiagnosis fields verdict, element, onset_t, end_t, episode; marks the element reports'
    Fisher violations around the episode."""
    t, valid, J, reports = stats["t"], stats["valid"], stats["J"], stats["elements"]
    none = {"element": None, "onset_t": None, "end_t": None, "episode": None}
    if int(valid.sum()) < config.min_valid_steps:
        return {"verdict": "insufficient_data", **none}
    full = int(stats["dof"].max())
    episode_idx = strongest_episode(t, J, viol_k, full, config)
    if episode_idx is None:
        return {"verdict": "no_fault", **none}
    s0, e0, peak = episode_idx
    with np.errstate(invalid="ignore"):
        F_viol = (stats["F"] > stats["eta2"]) & valid[:, None]
    lo = max(0, s0 - config.fisher_window)
    for k in range(model.n):
        runs = _runs(F_viol[lo:e0 + 1, k])
        reports[k].F_violated = any(e - s + 1 > config.fisher_window for s, e in runs)
    k0 = int(stats["first_element"][peak])
    if reports[k0].F_violated:
        verdict = "failure"
    elif any(r.F_violated for r in reports):
        verdict = "ambiguous"
    else:
        verdict = "glitch"
    last_valid = int(np.flatnonzero(valid)[-1])
    return {"verdict": verdict, "element": model.state_names[k0], "onset_t": float(t[peak]),
            "end_t": None if e0 >= last_valid else float(t[e0]),
            "episode": (float(t[s0]), float(t[e0]))}
