"""The onset mixture as a detection statistic of the ins3d GLR's hypotheses, the size unknown
(docs/ins3d_eval.md, "Seventh evaluation"; an evaluation, not a change of ``glr3d.isolate``).

Per hypothesis and onset theta the GLR curve gives e(theta) and d(theta)
(``power_bound.onset_terms``: d the information per SI unit of the size, e = b^ d, the GLR
e^2 / d). With a Gaussian prior
N(0, s^2) on the size b, the Bayes factor of "this hypothesis from theta" against "no fault" is

    BF(theta) = integral exp(b e - b^2 d / 2) N(b; 0, s^2) db
              = (1 + s^2 d)^(-1/2) exp(0.5 s^2 e^2 / (1 + s^2 d)),

and the statistic is M = 2 ln mean_theta BF(theta) over the onsets the GLR searches (uniform
prior on the onset; onsets without information, where the curve has no magnitude, left out, as
``power_bound.log_mixture_lr`` does). Unlike the maximum of e^2 / d, an onset with almost no
information (s^2 d << 1) has BF ~ 1 whatever its GLR: it neither raises nor lowers M.

Prior rule (``prior_sd``, fixed before any evaluation flight was looked at): s is the smallest
level of the hypothesis' scenario in the default study (``montecarlo3d.DEFAULT_LEVELS``), the
issue's targets for the steps: gyro steps 0.05 deg/h, accelerometer steps 0.3 mg, gyro ramps
0.5 deg/h^2, accelerometer ramps 1 mg/h, GNSS velocity jumps 0.3 m/s.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.special import logsumexp

from flight_fdi.core.ins3d.glr3d import GlrCurve, Hypothesis

from .errors import EvalError
from .power_bound import main_curves, onset_terms


def prior_sd(h: Hypothesis) -> float:
    """The prior sd s (SI) of the size of hypothesis ``h`` (module docstring, "Prior rule")."""
    from .montecarlo3d import DEFAULT_LEVELS, SCENARIOS

    for name, spec in SCENARIOS.items():
        if (spec[2], spec[3]) == (h.sensor, h.kind):
            return float(min(DEFAULT_LEVELS[name]) * spec[6])
    raise EvalError(f"prior_sd: no scenario for {h.sensor} {h.kind} ({h.name})")


def log_bayes_factors(e: np.ndarray, d: np.ndarray, s: float) -> np.ndarray:
    """ln BF(theta) per onset for the size prior N(0, s^2) (module docstring)."""
    if not s > 0:
        raise EvalError(f"log_bayes_factors: the prior sd must be > 0, got {s!r}")
    v = s * s * np.asarray(d, dtype=float)
    return -0.5 * np.log1p(v) + 0.5 * s * s * np.asarray(e, dtype=float) ** 2 / (1.0 + v)


def mixture_statistic(c: GlrCurve, s: float | None = None,
                      window: tuple[float, float] | None = None) -> float:
    """M = 2 ln mean over the curve's onsets (in ``window``; None: all it searches) of BF(theta),
    the size prior N(0, s^2) (None: :func:`prior_sd`), by log-sum-exp."""
    e, d = onset_terms(c, window)
    x = log_bayes_factors(e, d, prior_sd(c.hypothesis) if s is None else s)
    return float(2.0 * (logsumexp(x) - math.log(x.size)))


def mixture_statistics(cv: dict[str, GlrCurve]) -> dict[str, float]:
    """M of every step / ramp / jump curve (``power_bound.main_curves``), each with its own
    prior sd; a curve without any informative onset gets 0 (BF = 1)."""
    out = {}
    for name, c in main_curves(cv).items():
        try:
            out[name] = mixture_statistic(c)
        except EvalError:
            out[name] = 0.0
    return out


def nominal_mixture(f) -> dict:
    """One nominal flight (``calibrate3d.NominalFlight``): M and the GLR's maximum per
    hypothesis."""
    from .calibrate3d import analyse_nominal

    a = analyse_nominal(f)
    return {"profile": f.profile, "seed": f.seed, "duration_s": f.duration_s,
            "M": mixture_statistics(a.glr),
            "glr": {n: float(c.statistic) for n, c in main_curves(a.glr).items()}}


def fault_mixture(item: tuple) -> dict:
    """One fault flight of a study, item = (case, config): the isolator's decision
    (``montecarlo3d.decision``), M and the GLR's maximum per hypothesis."""
    from .montecarlo3d import SCENARIOS, decision
    from .onset_bound import analyse_case

    case, config = item
    _, an = analyse_case(case, config)
    dec = decision(an.post_flight_dict())
    return {"index": case.index, "scenario": case.scenario, "sensor": SCENARIOS[case.scenario][2],
            "axis": case.axis, "level": case.level, "magnitude": case.magnitude,
            "onset_s": case.onset_s, "sim_seed": case.sim_seed,
            "ins3d": {k: dec.get(k) for k in ("verdict", "isolation", "sensor", "axis")},
            "M": mixture_statistics(an.glr),
            "glr": {n: float(c.statistic) for n, c in main_curves(an.glr).items()}}


def tail_thresholds(rows: list[dict], p: float, key: str = "M") -> dict[str, float]:
    """Per hypothesis the x its nominal flights' ``key`` ("M" or "glr") exceeds with
    probability ``p`` (``calibrate3d.tail_threshold``, the one tail rule), from rows of
    :func:`nominal_mixture` of one flight length."""
    from .calibrate3d import tail_threshold

    if len({r["duration_s"] for r in rows}) > 1:
        raise EvalError("tail_thresholds: the rows mix flight lengths")
    return {h: tail_threshold(np.array([r[key][h] for r in rows]), p) for h in rows[0][key]}


def procedure_thresholds(short: list[dict], long: list[dict], key: str = "M",
                         target: float = 0.01) -> dict[str, float]:
    """Per hypothesis the threshold for a flight of the ``long`` rows' length by the grade's
    own procedure (``calibrate3d.hypothesis_growth`` on the two lengths' medians, then
    ``calibrate_hypotheses``: pooled, an equal share of ``target`` each), applied to ``key``
    ("M" or "glr") of rows of :func:`nominal_mixture`."""
    from .calibrate3d import CALIBRATED_LENGTH_S, calibrate_hypotheses, hypothesis_growth

    def conv(rows: list[dict]) -> list[dict]:
        return [{"duration_s": r["duration_s"], "max_by_hypothesis": r[key]} for r in rows]

    s, lo = conv(short), conv(long)
    growth = hypothesis_growth(s, lo)
    thr = calibrate_hypotheses(s + lo, target, growth)
    stretch = math.log(long[0]["duration_s"] / CALIBRATED_LENGTH_S)
    return {h: thr[h] + growth[h] * stretch for h in thr}


__all__ = ["fault_mixture", "log_bayes_factors", "mixture_statistic", "mixture_statistics",
           "nominal_mixture", "prior_sd", "procedure_thresholds", "tail_thresholds"]
