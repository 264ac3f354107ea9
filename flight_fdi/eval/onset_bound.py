"""The Cramer-Rao bound of a bias step's onset time in the post-flight linear-Gaussian setting
of the ins3d GLR (docs/ins3d_onset_bound.md).

The forward filter of the no-fault model turns the data into independent innovations
nu_j ~ N(0, S_j). A fault of size b along a direction tau of the fault vector that starts at tau0
adds b rho_j(tau0) to them (the Willsky-Jones signature through the time-varying filter,
``core.ins3d.signature``), so the log-likelihood of (tau0, b) is

    l(tau0, b) = -1/2 sum_j (nu_j - b rho_j(tau0))' S_j^-1 (nu_j - b rho_j(tau0)) + const

and its Fisher matrix on theta = (tau0, b), with rho' = d rho / d tau0 (a central difference of
the signatures at tau0 -+ delta: for a step the signature is continuous in tau0)::

    I_tt = b^2 sum rho'' S^-1 rho',   I_tb = b sum rho'' S^-1 rho,   I_bb = sum rho' S^-1 rho

(I_bb is the GLR's own information ``tau' I tau`` at that onset; b^2 I_bb is the expected
statistic). The onset's sd is at least 1 / sqrt(I_tt) with b known and
1 / sqrt(I_tt - I_tb^2 / I_bb) with b estimated too (the GLR's case).

:func:`onset_bound` computes both for one hypothesis of an analysed flight
(``core.ins3d.analysis.Ins3dAnalysis``); :func:`synthetic_onsets` draws innovations from the
model itself with the fault added and returns where the GLR puts the onset (the model's own
maximum-likelihood estimate: whether the bound is reached at the flight's signal-to-noise ratio).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from flight_fdi.core.diagnosis import DiagnosisConfig
from flight_fdi.core.ins3d.backward import ACC_A, GYR_A, REF
from flight_fdi.core.ins3d.postflight import (fused_forward, glr_curves, kernel_args,
                                             run_backward)
from flight_fdi.core.ins3d.signature import signature_series

from .errors import EvalError

#: the fault-vector column of a step of each IMU sensor's x axis
STEP_COLUMN = {"accelerometer": ACC_A, "gyro": GYR_A}
AXES = ("x", "y", "z")
#: onset shifts (s) of the Hammersley-Chapman-Robbins bound, each side
HCR_SHIFTS = (0.1, 0.2, 0.5, 1.0, 2.0, 5.0, 10.0, 20.0, 50.0, 100.0, 200.0, 500.0, 1000.0)


@dataclass(frozen=True)
class OnsetFisher:
    """The Fisher matrix of (onset, magnitude) and the bounds it gives (s)."""

    I_tt: float      # onset information (b known), 1/s^2
    I_tb: float      # cross term
    I_bb: float      # magnitude information per unit b^2 (the GLR's tau' I tau, SI)
    b: float         # the fault's size (SI)
    delta_s: float   # the central difference's half step

    @property
    def sd_known(self) -> float:
        """Cramer-Rao bound of the onset's sd with the magnitude known."""
        return 1.0 / math.sqrt(self.I_tt) if self.I_tt > 0 else math.inf

    @property
    def sd_joint(self) -> float:
        """Cramer-Rao bound of the onset's sd with the magnitude estimated too (the Schur
        complement of the 2x2 Fisher matrix)."""
        schur = self.I_tt - self.I_tb * self.I_tb / self.I_bb if self.I_bb > 0 else 0.0
        return 1.0 / math.sqrt(schur) if schur > 0 else math.inf

    @property
    def expected_glr(self) -> float:
        """b^2 I_bb: the GLR statistic's non-centrality at the true onset."""
        return self.b * self.b * self.I_bb

    def as_dict(self) -> dict:
        return {"I_tt": self.I_tt, "I_tb": self.I_tb, "I_bb": self.I_bb, "b": self.b,
                "delta_s": self.delta_s, "sd_known_s": self.sd_known,
                "sd_joint_s": self.sd_joint, "expected_glr": self.expected_glr}


def quad(u: np.ndarray, S_inv: np.ndarray, w: np.ndarray) -> float:
    """sum_j u_j' S_j^-1 w_j over (M, rows) series and (M, rows, rows) inverses."""
    return float(np.einsum("ji,jik,jk->", u, S_inv, w))


def fisher_onset(rho_lo: np.ndarray, rho: np.ndarray, rho_hi: np.ndarray, S_inv: np.ndarray,
                 delta_s: float, b: float) -> OnsetFisher:
    """The Fisher matrix of (onset, b) from the signatures per unit fault at onsets
    tau0 - delta, tau0, tau0 + delta ((M, rows) each) and the innovations' S^-1 (M, rows,
    rows); b the fault's size."""
    if not delta_s > 0:
        raise EvalError(f"fisher_onset: delta_s must be > 0, got {delta_s!r}")
    d = (rho_hi - rho_lo) / (2.0 * delta_s)
    return OnsetFisher(b * b * quad(d, S_inv, d), b * quad(d, S_inv, rho), quad(rho, S_inv, rho),
                       abs(float(b)), float(delta_s))


class Signatures:
    """Step signatures of one analysed flight (``analyze_ins3d`` with its post-flight part,
    whose forward pass keeps its priors and gains), per SI unit of the fault."""

    def __init__(self, an):
        if an.steps is None or an.forward.Ks is None:
            raise EvalError("Signatures: the analysis must keep its grid and forward priors")
        self.an = an
        self.fwd = fused_forward(an.model, an.steps, an.refs, an.forward)
        self.args = kernel_args(an.model, an.steps, an.refs)
        self.t = an.steps.t
        self.rows = an.model.rows

    def column(self, sensor: str, axis: str) -> int:
        if sensor not in STEP_COLUMN or axis not in AXES:
            raise EvalError(f"Signatures: no step hypothesis for {sensor!r} axis {axis!r}")
        return STEP_COLUMN[sensor] + AXES.index(axis)

    def rho(self, sensor: str, axis: str, k0: int) -> np.ndarray:
        """(M, rows) innovation signature (m/s per SI unit) of a step starting at boundary k0."""
        col = self.column(sensor, axis)
        sB = self.args[10]
        tau = np.zeros(REF + self.rows)
        tau[col] = 1.0
        m = self.an.refs.t.size
        e, d, out = np.empty(m), np.empty(m), np.empty((m, self.rows))
        m_ = self.an.model
        signature_series(*self.args, np.ascontiguousarray(self.an.refs.a), *m_.row_args(),
                         self.fwd.Ks, self.fwd.S_inv, self.fwd.nu, int(k0), tau, e, d, out)
        return out / sB[col]

    def boundary(self, t_s: float) -> int:
        """The step boundary at (or just after) time t_s (flight time, as ``steps.t``)."""
        return int(np.searchsorted(self.t, t_s - 1e-9))

    def fisher(self, sensor: str, axis: str, onset_s: float, b: float,
               deltas: tuple[int, ...] = (1,)) -> list[OnsetFisher]:
        """The Fisher matrix at onset ``onset_s`` (flight time) for each central-difference
        half step of ``deltas`` boundaries."""
        k0 = self.boundary(onset_s)
        if not 0 < k0 < self.t.size - 1:
            raise EvalError(f"onset {onset_s!r} s is not inside the flight")
        mid = self.rho(sensor, axis, k0)
        out = []
        for m in deltas:
            lo, hi = max(k0 - m, 0), min(k0 + m, self.t.size - 1)
            out.append(fisher_onset(self.rho(sensor, axis, lo), mid, self.rho(sensor, axis, hi),
                                    self.fwd.S_inv, 0.5 * float(self.t[hi] - self.t[lo]), b))
        return out

    def shifted(self, sensor: str, axis: str, onset_s: float,
                shifts: tuple[float, ...] = HCR_SHIFTS) -> tuple[np.ndarray, dict]:
        """(the signature at ``onset_s``, {h: the signature at the onset + h}) for the shifts
        -+``shifts`` that stay inside the flight (h on the boundary grid)."""
        k0 = self.boundary(onset_s)
        sh = {}
        for h in shifts:
            for sgn in (-1.0, 1.0):
                k = self.boundary(float(self.t[k0]) + sgn * h)
                if 0 < k < self.t.size - 1 and k != k0:
                    sh[float(self.t[k] - self.t[k0])] = self.rho(sensor, axis, k)
        return self.rho(sensor, axis, k0), sh

    def hcr(self, sensor: str, axis: str, onset_s: float, b: float) -> dict[str, float]:
        """:func:`hcr_bound` at ``onset_s`` (shifts: :meth:`shifted`)."""
        rho, sh = self.shifted(sensor, axis, onset_s)
        return hcr_bound(rho, sh, self.fwd.S_inv, b)


def hcr_bound(rho: np.ndarray, shifted: dict[float, np.ndarray], S_inv: np.ndarray,
              b: float) -> dict[str, float]:
    """Hammersley-Chapman-Robbins bounds of the onset's sd from the signatures at the onset
    (``rho``) and at onsets shifted by h (``shifted``: h -> signature): sup_h |h| /
    sqrt(exp(D(h)) - 1), D the divergence b^2 |rho_h - rho|^2 (b known) or, b profiled out,
    min over b' of |b' rho_h - b rho|^2 = b^2 (|rho|^2 - <rho_h, rho>^2 / |rho_h|^2)
    (norms in S^-1). Unlike the Cramer-Rao bound (its limit h -> 0) it does not need a
    signature smooth in the onset on the scale of the errors (an accelerometer step's velocity
    signature rises within the filter's time constant). Also the h of each sup."""
    n0 = quad(rho, S_inv, rho)
    best = {"known": (0.0, 0.0), "profiled": (0.0, 0.0)}
    for h, r in shifted.items():
        dr = r - rho
        nh, c = quad(r, S_inv, r), quad(r, S_inv, rho)
        div = {"known": b * b * quad(dr, S_inv, dr),
               "profiled": b * b * max(n0 - c * c / nh, 0.0) if nh > 0 else 0.0}
        for k, dv in div.items():
            v = abs(h) / math.sqrt(math.expm1(dv)) if 0 < dv < 700 else (math.inf if dv == 0
                                                                          else 0.0)
            if v > best[k][0]:
                best[k] = (v, h)
    return {"sd_known_s": best["known"][0], "h_known_s": best["known"][1],
            "sd_profiled_s": best["profiled"][0], "h_profiled_s": best["profiled"][1]}


def window_mass(t: np.ndarray, logp: np.ndarray, w: float) -> float:
    """The largest posterior mass in any interval of width 2 w of the grid ``t`` (sorted)
    with log-weights ``logp``: the probability that the best estimator's error is <= w given
    the data (its estimate: the interval's centre)."""
    p = np.exp(logp - logp.max())
    cs = np.concatenate(([0.0], np.cumsum(p)))
    j = np.searchsorted(t, t + 2.0 * w, side="right")
    return float(np.max(cs[j] - cs[:-1]) / cs[-1])


def synthetic_onsets(sig: Signatures, sensor: str, axis: str, onset_s: float, b: float,
                     reps: int, rng: np.random.Generator, window: tuple[float, float],
                     w: float = 5.0) -> dict[str, np.ndarray]:
    """``reps`` sets of innovations drawn from the model itself with the fault added
    (nu_j = chol(S_j) w_j + b rho_j(onset), b signed), each through the post-flight sweep:

    * ``mle``: the GLR's onset (argmax over every onset of the step hypothesis, b estimated):
      the model's own maximum-likelihood estimate;
    * ``p_known``, ``p_marginal``: the posterior probability that the *best* estimator's onset
      is within ``w`` s, for a uniform prior of the onset over ``window`` (s, the study's onset
      window) -- with b known (log-likelihood b e - b^2 d / 2: more than any estimator has)
      and with b marginalised (flat prior: GLR / 2 + ln sd(b^)). Averaged over flights whose
      onsets are drawn from that prior, it bounds P(|error| <= w) of any estimator."""
    an, fwd = sig.an, sig.fwd
    k0 = sig.boundary(onset_s)
    mean = b * sig.rho(sensor, axis, k0)
    L = np.linalg.cholesky(fwd.S)
    name = f"{sensor}_{axis}_step"
    rank_tol = DiagnosisConfig().rank_tol
    out = {k: np.empty(reps) for k in ("mle", "p_known", "p_marginal")}
    for r in range(reps):
        nu = np.einsum("jik,jk->ji", L, rng.standard_normal(mean.shape)) + mean
        bwd = run_backward(an.model, an.steps, an.refs, replace(fwd, nu=nu), rank_tol)
        c = glr_curves(an.model, an.steps, bwd)[name]
        out["mle"][r] = float(c.t[c.best])
        on = (c.t >= window[0]) & (c.t <= window[1]) & np.isfinite(c.sd)
        t, info = c.t[on], 1.0 / c.sd[on] ** 2          # d (SI)
        out["p_known"][r] = window_mass(t, b * c.mag[on] * info - 0.5 * b * b * info, w)
        out["p_marginal"][r] = window_mass(t, 0.5 * c.stat[on] + np.log(c.sd[on]), w)
    return out


def observed_sd(c, drop: float = 4.0) -> float | None:
    """The onset sd the GLR curve ``c`` (``glr3d.GlrCurve``) itself shows: 1 / sqrt(a) of the
    least-squares parabola stat_max - a (theta - theta^)^2 over the contiguous onsets within
    ``drop`` of its peak (the profile likelihood's curvature; None: fewer than 3 onsets or not
    curved)."""
    k = c.best
    if k < 0:
        return None
    ok = c.stat >= c.stat[k] - drop
    a, b = k, k
    while a > 0 and ok[a - 1]:
        a -= 1
    while b < ok.size - 1 and ok[b + 1]:
        b += 1
    if b - a < 2:
        return None
    u = (c.t[a:b + 1] - c.t[k]) ** 2
    y = c.stat[k] - c.stat[a:b + 1]
    curv = float(u @ y / (u @ u))
    return 1.0 / math.sqrt(curv) if curv > 0 else None


def analyse_case(case, config):
    """(flight, analysis) of one evaluation flight (``eval.montecarlo3d``: the same simulator
    options and ``analyze_ins3d`` arguments as the studies' flights)."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d

    from .montecarlo3d import simulate_case

    flight = simulate_case(case, config)
    inp = from_flight(flight)
    an = analyze_ins3d(inp.steps, inp.refs, grade=case.grade or config.grade, rows=config.rows,
                       gate=config.analysis.gate, with_observability=False, **inp.vertical())
    return flight, an


def study_record(item: tuple) -> dict:
    """One fault flight of a study, item = (case, config, reps, deltas): the isolator's result
    (``montecarlo3d.decision``), the true hypothesis' GLR curve (its onset, statistic and the
    curvature's sd), the bound at the true onset and size for each central-difference half step
    of ``deltas`` (boundaries), and ``reps`` onsets from innovations drawn from the model
    (:func:`synthetic_onsets`, seeded by the flight)."""
    from .montecarlo3d import SCENARIOS, decision, turn_facts

    case, config, reps, deltas = item
    flight, an = analyse_case(case, config)
    dec = decision(an.post_flight_dict())
    sensor = SCENARIOS[case.scenario][2]
    sig = Signatures(an)
    b = abs(float(case.magnitude))
    fis = sig.fisher(sensor, case.axis, case.onset_s, b, tuple(deltas))
    cv = an.glr[f"{sensor}_{case.axis}_step"]
    rng = np.random.default_rng([case.sim_seed, 15])
    lo, hi = (f * config.duration_s for f in config.onset_window)
    syn = synthetic_onsets(sig, sensor, case.axis, case.onset_s, float(case.magnitude), reps,
                           rng, (lo, hi)) if reps else {}
    in_turn, next_turn = turn_facts(flight, case.onset_s)
    keep = ("verdict", "isolation", "sensor", "axis", "kind", "onset_s", "magnitude",
            "onset_interval_s", "statistic")
    return {"key": f"{case.scenario}:{case.index}", "index": case.index,
            "scenario": case.scenario, "sensor": sensor,
            "axis": case.axis, "kind": "step", "level": case.level, "unit":
            SCENARIOS[case.scenario][5], "magnitude": case.magnitude, "onset_s": case.onset_s,
            "sim_seed": case.sim_seed, "traj_seed": case.traj_seed,
            "onset_in_turn": in_turn, "next_turn_s": next_turn,
            "ins3d": {k: dec.get(k) for k in keep},
            "true_hypothesis": {"onset_s": float(cv.t[cv.best]),
                                "statistic": float(cv.statistic), "sd_observed_s":
                                observed_sd(cv)},
            "bounds": [f.as_dict() for f in fis],
            "hcr": sig.hcr(sensor, case.axis, case.onset_s, b),
            "synthetic": {k: [float(x) for x in v] for k, v in syn.items()}}


def grid_record(item: tuple) -> dict:
    """One nominal flight, item = (case, config, onset fractions, {scenario: levels}): the bound per
    (sensor, axis, onset) for a step of one level unit (mg, deg/h: ``montecarlo3d.SCENARIOS``):
    the Cramer-Rao bounds (for a step of L units divided by L: the Fisher matrix scales with
    b^2) and the Hammersley-Chapman-Robbins bounds per level (``hcr``, by level)."""
    from .montecarlo3d import SCENARIOS

    case, config, fractions, levels = item
    _, an = analyse_case(case, config)
    sig = Signatures(an)
    t0, dur = float(an.steps.t[0]), float(an.steps.t[-1] - an.steps.t[0])
    rows = []
    for scen, levs in levels.items():
        sensor, unit, si = SCENARIOS[scen][2], SCENARIOS[scen][5], SCENARIOS[scen][6]
        for axis in AXES:
            for f in fractions:
                fi = sig.fisher(sensor, axis, t0 + f * dur, si)[0]
                rho, sh = sig.shifted(sensor, axis, t0 + f * dur)
                rows.append({"scenario": scen, "sensor": sensor, "axis": axis, "unit": unit,
                             "fraction": f, "onset_s": f * dur, **fi.as_dict(),
                             "hcr": {str(lev): hcr_bound(rho, sh, sig.fwd.S_inv, lev * si)
                                     for lev in levs}})
    return {"key": case.index, "index": case.index, "sim_seed": case.sim_seed,
            "traj_seed": case.traj_seed, "rows": rows}


__all__ = ["AXES", "HCR_SHIFTS", "OnsetFisher", "STEP_COLUMN", "Signatures", "analyse_case",
           "fisher_onset", "grid_record", "hcr_bound", "observed_sd", "quad",
           "study_record", "synthetic_onsets", "window_mass"]
