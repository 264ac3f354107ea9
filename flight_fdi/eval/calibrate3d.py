"""GLR thresholds of an IMU grade calibrated on nominal simulated flights (docs/ins3d.md,
"Thresholds" and "Calibrating a grade file").

The flights are the simulator's (``sim.ins3d``: scale factors and misalignments that are not
states of the estimator's model, correlated GNSS noise with latency, a baro-damped INS) -- not
data the estimator's own model generated -- with the grade's own noise. Per flight the largest
GLR over the onsets and hypotheses of every kind (step, ramp, jump, outliers) is recorded
(:func:`nominal_flight`); each kind's threshold is then set from the distribution of those
maxima (:func:`calibrate`) so that a nominal flight exceeds *any* threshold with probability at
most the target (each kind gets a quarter: the union bound).

**Rule** (:func:`tail_threshold`). The largest GLR of a flight is a maximum of 2 ln LR
statistics, whose upper tail falls like a chi^2 tail, P(M > x) ~ exp(-x / beta) with beta ~ 2.
With n flights and a kind's share p of the target: when n p >= TAIL_POINTS the threshold is the
empirical (1 - p) quantile; otherwise it is extrapolated from the k = TAIL_POINTS largest
maxima (at least 10 % of the flights, at most half): x = q + beta ln((k / n) / p), q the
(k+1)-th largest maximum, beta the mean excess of the k largest over q, at least 2 (a fatter
tail than chi^2 -- model mismatch -- raises it; a thinner one is not trusted). The spread of
a calibration is the bootstrap standard deviation over the flights (:func:`bootstrap_spread`).

The thresholds are stated for a flight of ``glr3d.CALIBRATED_LENGTH_S`` (what a grade file
holds): flights of another length T are moved by ``glr3d.LENGTH_GROWTH`` x ln(1800 s / T).

**Per hypothesis** (:func:`calibrate_hypotheses`; what :func:`calibrate_grade` and ``flight-fdi
calibrate`` add by default): each of the 15 hypotheses of ``glr3d.PER_HYPOTHESIS`` gets
(1 - ``OUTLIER_SHARE``) x target / 15 of the budget, the outliers keep their kind's quarter
(union bound: at most the target in all); each hypothesis' maxima are moved to 30 min by its
own growth (``glr3d.growth_of``), the rule the analysis applies to longer flights.

**Seed method** (:func:`seed_statistic`, :func:`calibrate_seed`). When the GLR names nothing, the
seed method still declares (``glitch`` / ``failure`` / ``ambiguous``, no sensor named) a flight
whose strongest persistent J episode peaks above the chi^2(dof) quantile of
``DiagnosisConfig.episode_probability`` p. Per flight the calibration records x = -2 ln P(chi^2(dof)
> J_peak) of that peak (0 without a persistent episode): the flight is declared iff x > -2 ln p,
whatever p, and for a chi^2 peak x is chi^2(2)-like (tail exp(-x / 2)). The grade's
``seed_episode_probability`` is p = exp(-x* / 2), x* = :func:`tail_threshold` of the flights' x at
the seed target (a budget of its own, by default the false-isolation target: a seed-method
declaration names no sensor), and never above the default 1e-6 (a quiet grade keeps the presets'
rule; the calibration only makes the seed method stricter where the grade needs it).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace
from typing import Callable

import numpy as np

from flight_fdi.core.diagnosis import DiagnosisConfig, SeedDiagnosis
from flight_fdi.core.ins3d.glr3d import CALIBRATED_LENGTH_S, LENGTH_GROWTH
from flight_fdi.core.ins3d.grade_file import KINDS, at_length
from flight_fdi.core.ins3d.grades import ImuGrade

from .errors import EvalError

#: the flights' profiles by default: the presets were calibrated on them, in turn
PROFILES = ("cruise_turns", "random", "survey_grid")
#: fewest flights a calibration takes (the tail extrapolation needs TAIL_POINTS above its anchor)
MIN_FLIGHTS = 20
#: maxima above the anchor of the tail extrapolation
TAIL_POINTS = 10
#: the smallest tail scale beta (the chi^2 value: P(chi^2 > x) ~ exp(-x / 2))
TAIL_SCALE = 2.0
#: the seed method's episode probability without a calibration (the presets')
DEFAULT_EPISODE_PROBABILITY = DiagnosisConfig().episode_probability
#: the smallest tail probability of a J peak told apart (below: x = -2 ln of it)
_TINY = 1e-300


@dataclass(frozen=True)
class NominalFlight:
    """One calibration (or check) flight: its profile, length, grade and seed; ``checks``:
    named threshold sets (for a 30-min flight) whose isolation decision is also recorded."""

    profile: str
    duration_s: float
    grade: ImuGrade
    seed: int
    checks: tuple[tuple[str, tuple[tuple[str, float], ...]], ...] = ()


def plan(grade: ImuGrade, flights: int, seed: int, profiles: tuple[str, ...] = PROFILES,
         duration_s: float = CALIBRATED_LENGTH_S,
         checks: dict[str, dict[str, float]] | None = None) -> list[NominalFlight]:
    """Flight i: profile ``profiles[i mod P]``, seed ``seed + i`` (trajectory and sensors);
    ``checks``: named threshold sets (per kind, and per hypothesis where given) whose
    isolation each flight records."""
    from flight_fdi.sim.trajectory import PROFILES as ALL

    for p in profiles:
        if p not in ALL:
            raise EvalError(f"unknown profile {p!r}; choose from {', '.join(ALL)}")
    if not profiles:
        raise EvalError("calibration: no profile given")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise EvalError(f"seed must be an integer >= 0, got {seed!r}")
    if not isinstance(duration_s, (int, float)) or not 60.0 <= duration_s <= 10800.0:
        raise EvalError(f"flight length must be within 60..10800 s, got {duration_s!r}")
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS

    keys = (*KINDS, *PER_HYPOTHESIS)        # a check's per-hypothesis thresholds too
    chk = tuple((n, tuple((k, float(t[k])) for k in keys if k in t))
                for n, t in (checks or {}).items())
    return [NominalFlight(profiles[i % len(profiles)], float(duration_s), grade, int(seed) + i,
                          chk) for i in range(int(flights))]


def analyse_nominal(f: NominalFlight):
    """The ins3d analysis (``analyze_ins3d``) of one nominal flight, simulated from its seed."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    cfg = Sim3DConfig(TrajectoryConfig(profile=f.profile, duration_s=f.duration_s,
                                       rate_hz=100.0, seed=f.seed), grade=f.grade, seed=f.seed)
    inp = from_flight(simulate3d(cfg))
    return analyze_ins3d(inp.steps, inp.refs, grade=f.grade, with_observability=False,
                         **inp.vertical())   # the flight's own height loop, as the evaluation


def nominal_flight(f: NominalFlight) -> dict:
    """The largest GLR per hypothesis kind (and its hypothesis) and per hypothesis
    (``max_by_hypothesis``) of one nominal flight, its
    verdict, and per check the isolation its thresholds give (``glr3d.isolate``)."""
    from flight_fdi.core.ins3d.glr3d import isolate

    a = analyse_nominal(f)
    best = {k: max((c.statistic, n) for n, c in a.glr.items() if c.hypothesis.kind == k)
            for k in KINDS}
    checks = {}
    for name, thr in f.checks:
        iso = isolate(a.glr, at_length(dict(thr), f.duration_s))
        checks[name] = {"isolation": iso.isolation, "best": iso.best}
    return {"profile": f.profile, "seed": f.seed, "grade": f.grade.name,
            "duration_s": f.duration_s,
            "max": {k: float(v[0]) for k, v in best.items()},
            "argmax": {k: v[1] for k, v in best.items()},
            "max_by_hypothesis": {n: float(c.statistic) for n, c in a.glr.items()},
            "verdict": a.post_flight_dict()["verdict"], "checks": checks,
            "seed_x": seed_statistic(a.seed), "seed_verdict": a.seed.verdict}


def seed_statistic(seed: SeedDiagnosis) -> float:
    """x = -2 ln P(chi^2(dof) > J) of the peak of the flight's strongest persistent J episode
    (``diagnosis.diagnose``'s episodes whatever their peak; 0 without one): the seed method
    declares the flight iff x > -2 ln ``episode_probability`` (module docstring)."""
    from flight_fdi.core.diagnosis import strongest_episode, violation_mask
    from flight_fdi.core.special import chi2_sf

    full = int(seed.dof.max()) if seed.dof.size else 0
    if int(seed.valid.sum()) < seed.config.min_valid_steps or full < 1:
        return 0.0                      # insufficient data: no episode probability decides
    viol_k = violation_mask(seed.element_dof, seed.terms, seed.gammas, seed.valid)
    every = replace(seed.config, episode_probability=1.0 - 1e-15)   # every persistent one
    ep = strongest_episode(seed.t, seed.J, viol_k, full, every)
    if ep is None:
        return 0.0
    return float(-2.0 * math.log(max(chi2_sf(float(seed.J[ep[2]]), full), _TINY)))


def seed_declared(rows: list[dict], p: float) -> int:
    """Flights the seed method declares with episode probability ``p`` (whatever the GLR)."""
    return sum(r["seed_x"] > -2.0 * math.log(p) for r in rows)


def calibrate_seed(rows: list[dict], target: float) -> float:
    """The grade's seed-method episode probability (module docstring, "Seed method"): at most
    ``DEFAULT_EPISODE_PROBABILITY``, 3 significant digits."""
    if not 0.0 < target < 1.0:
        raise EvalError(f"seed-method target must be within (0, 1), got {target!r}")
    x = tail_threshold(np.array([r["seed_x"] for r in rows]), target)
    p = math.exp(-0.5 * x)
    return float(f"{min(p, DEFAULT_EPISODE_PROBABILITY):.2e}") if p > 0 else _TINY


def run_flights(flights: list[NominalFlight], jobs: int = 1, progress: bool = False,
                on_result: Callable[[dict], None] | None = None,
                scheduler: str | None = None, info: dict | None = None) -> list[dict]:
    """:func:`nominal_flight` of every flight on the campaign engine, in seed order."""
    from .parallel import parallel_map

    rows = parallel_map(nominal_flight, flights, jobs, progress, desc="calibrate ins3d",
                        on_result=on_result, scheduler=scheduler, info=info)
    return sorted(rows, key=lambda r: r["seed"])


def summary(rows: list[dict], per_hypothesis: bool = False) -> dict[str, dict[str, float]]:
    """Per kind (``per_hypothesis``: per hypothesis of ``glr3d.PER_HYPOTHESIS``) the largest,
    median and 90 % quantile of the flights' maxima (at the flights' own length)."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS

    out = {}
    for k in PER_HYPOTHESIS if per_hypothesis else KINDS:
        m = np.array([r["max_by_hypothesis" if per_hypothesis else "max"][k] for r in rows])
        out[k] = {"max": float(m.max()), "median": float(np.median(m)),
                  "q90": float(np.quantile(m, 0.9))}
    return out


def tail_threshold(maxima: np.ndarray, p: float) -> float:
    """The x a flight's maximum exceeds with probability ``p`` (module docstring, "Rule")."""
    m = np.sort(np.asarray(maxima, dtype=float))[::-1]
    n = m.size
    if n < MIN_FLIGHTS:
        raise EvalError(f"calibration needs at least {MIN_FLIGHTS} flights, got {n}")
    if n * p >= TAIL_POINTS:
        return float(np.quantile(m, 1.0 - p))
    k = min(max(TAIL_POINTS, int(math.ceil(0.1 * n))), n // 2)
    q = m[k]
    beta = max(TAIL_SCALE, float(np.mean(m[:k] - q)))
    return float(q + beta * math.log((k / n) / p))


def length_shift(duration_s: float) -> dict[str, float]:
    """What moves a kind's threshold from flights of ``duration_s`` to the stated length
    (``CALIBRATED_LENGTH_S``): - c ln(T / 1800 s), c = ``LENGTH_GROWTH`` (both ways)."""
    return {k: -c * math.log(duration_s / CALIBRATED_LENGTH_S) for k, c in LENGTH_GROWTH.items()}


def calibrate(rows: list[dict], target: float) -> dict[str, float]:
    """Per kind the threshold (for a flight of ``CALIBRATED_LENGTH_S``) that a nominal flight
    of the rows' kind exceeds with probability ``target / len(KINDS)``."""
    if not 0.0 < target < 1.0:
        raise EvalError(f"false-isolation target must be within (0, 1), got {target!r}")
    lengths = {r["duration_s"] for r in rows}
    if len(lengths) != 1:
        raise EvalError("calibration: the flights must all have one length")
    shift = length_shift(lengths.pop())
    p = target / len(KINDS)
    return {k: round(tail_threshold(np.array([r["max"][k] for r in rows]), p) + shift[k], 2)
            for k in KINDS}


#: the share of the false-isolation target the outliers keep (their kind's threshold, as the
#: per-kind calibration gives it); the rest is split equally over ``glr3d.PER_HYPOTHESIS``
OUTLIER_SHARE = 0.25


def hypothesis_share(target: float) -> float:
    """Each hypothesis' share of the false-isolation ``target`` when calibrated per hypothesis:
    (1 - ``OUTLIER_SHARE``) x target, split equally over ``glr3d.PER_HYPOTHESIS``."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS

    return (1.0 - OUTLIER_SHARE) * target / len(PER_HYPOTHESIS)


def hypothesis_growth(short: list[dict], long: list[dict]) -> dict[str, float]:
    """Per hypothesis of ``glr3d.PER_HYPOTHESIS`` the growth c of its nominal maximum with the
    flight length, measured: (median over the long flights - median over the short ones) /
    ln(T_long / T_short), at least 0 (a threshold is never lowered for a longer flight). Rows
    of ``nominal_flight`` (``max_by_hypothesis``), each set of one length."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS

    ts, tl = (_one_length(r) for r in (short, long))
    if not tl > ts:
        raise EvalError("hypothesis growth: the long flights must be longer than the short ones")
    out = {}
    for h in PER_HYPOTHESIS:
        med = [float(np.median([r["max_by_hypothesis"][h] for r in rows]))
               for rows in (short, long)]
        out[h] = max(0.0, (med[1] - med[0]) / math.log(tl / ts))
    return out


def _one_length(rows: list[dict]) -> float:
    lengths = {r["duration_s"] for r in rows}
    if len(lengths) != 1:
        raise EvalError("calibration: the flights of a set must all have one length")
    return float(lengths.pop())


def calibrate_hypotheses(rows: list[dict], target: float,
                         growth: dict[str, float] | None = None) -> dict[str, float]:
    """Per hypothesis of ``glr3d.PER_HYPOTHESIS`` the threshold (for a flight of
    ``CALIBRATED_LENGTH_S``) its nominal maximum exceeds with probability
    (1 - ``OUTLIER_SHARE``) x ``target`` / (number of hypotheses): an equal share of the
    isolator's budget per hypothesis (the union bound; the outliers keep their kind's share).
    ``rows`` may mix flight lengths: each flight's maxima are first moved to the stated length
    by - c ln(T / 1800 s), c = ``growth[h]`` (default ``glr3d.growth_of``), then pooled and cut
    with :func:`tail_threshold`."""
    from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS, growth_of

    if not 0.0 < target < 1.0:
        raise EvalError(f"false-isolation target must be within (0, 1), got {target!r}")
    p = hypothesis_share(target)
    out = {}
    for h in PER_HYPOTHESIS:
        c = growth_of(h) if growth is None or h not in growth else growth[h]
        m = np.array([r["max_by_hypothesis"][h]
                      - c * math.log(r["duration_s"] / CALIBRATED_LENGTH_S) for r in rows])
        out[h] = round(tail_threshold(m, p), 2)
    return out


def exceeded_hypotheses(rows: list[dict], thresholds: dict[str, float]) -> int:
    """Flights whose maximum of some hypothesis exceeds its threshold (``glr3d.threshold_of``
    of ``thresholds`` -- per kind and per hypothesis, for a 30-min flight -- raised for the
    flight's length as the analysis does): an upper bound of the flights' false isolations."""
    from flight_fdi.core.ins3d.glr3d import hypotheses, threshold_of

    hyps = {h.name: h for h in hypotheses(3)}
    n = 0
    for r in rows:
        thr = at_length(thresholds, r["duration_s"])
        n += any(v > threshold_of(thr, hyps[k]) for k, v in r["max_by_hypothesis"].items())
    return n


def calibrate_grade(rows: list[dict], target: float,
                    per_hypothesis: bool = True) -> dict[str, float]:
    """The thresholds a grade file gets (for a flight of ``CALIBRATED_LENGTH_S``): per kind
    (:func:`calibrate`: a quarter of ``target`` each) and, with ``per_hypothesis``, per
    hypothesis (:func:`calibrate_hypotheses`: the isolator then uses these -- the outliers
    keep their kind's quarter, the other three quarters go in equal shares to the 15
    hypotheses; the kinds' step / ramp / jump stay as the fall-back of a hypothesis without
    its own, ``glr3d.threshold_of``)."""
    thr = calibrate(rows, target)
    if per_hypothesis:
        thr.update(calibrate_hypotheses(rows, target))
    return thr


def bootstrap_spread(rows: list[dict], target: float, draws: int = 200,
                     seed: int = 0, per_hypothesis: bool = False) -> dict[str, float]:
    """Per kind (and per hypothesis with ``per_hypothesis``) the standard deviation of
    :func:`calibrate_grade` over ``draws`` resamples of the flights (with replacement): the
    sampling spread of a calibration on this many flights."""
    rng = np.random.default_rng(seed)
    thr = [calibrate_grade([rows[i] for i in rng.integers(0, len(rows), len(rows))], target,
                           per_hypothesis) for _ in range(draws)]
    return {k: float(np.std([t[k] for t in thr], ddof=1)) for k in thr[0]}


def exceeded(rows: list[dict], thresholds: dict[str, float]) -> int:
    """Flights whose maximum of some kind exceeds its threshold (given for a 30-min flight,
    raised for the flight's length as the analysis does): the flights on which the analysis
    declares something -- an upper bound of its false isolations."""
    return sum(any(r["max"][k] > t for k, t in at_length(thresholds, r["duration_s"]).items())
               for r in rows)


def rate(k: int, n: int) -> dict:
    """k of n as a rate with its exact 95 % interval (``metrics3d.binomial_interval``)."""
    from .metrics3d import binomial_interval

    lo, hi = binomial_interval(k, n)
    return {"k": int(k), "n": int(n), "rate": k / n, "interval95": [lo, hi]}


def check_rates(rows: list[dict]) -> dict[str, dict]:
    """Per check (``NominalFlight.checks``): false isolations (the decision names one sensor:
    ``isolation`` single, a glitch included, as ``metrics3d``) and declarations (any)."""
    names = rows[0]["checks"] if rows else {}
    out = {}
    for name in names:
        iso = [r["checks"][name]["isolation"] for r in rows]
        out[name] = {"false_isolation": rate(iso.count("single"), len(rows)),
                     "declared": rate(sum(i != "none" for i in iso), len(rows))}
    return out


@dataclass
class Calibration:
    """What :func:`run_calibration` found: thresholds, their spread, the achieved rate."""

    grade: ImuGrade
    target: float
    rows: list[dict]
    thresholds: dict[str, float]
    spread: dict[str, float]
    achieved: dict
    elapsed_s: float
    profiles: tuple[str, ...]
    engine: str = ""
    episode_probability: float = DEFAULT_EPISODE_PROBABILITY   # the seed method's
    seed_target: float = 0.01
    seed_achieved: dict = field(default_factory=dict)          # declared with it (``rate``)
    per_hypothesis: bool = False   # thresholds per hypothesis too (:func:`calibrate_grade`)

    def metadata(self) -> dict:
        """The ``calibration`` record a grade file carries (``grade_file.with_thresholds``)."""
        seeds = [r["seed"] for r in self.rows]
        a = self.achieved
        return {"date": time.strftime("%Y-%m-%d", time.gmtime()), "tool": "flight-fdi calibrate",
                "flights": len(self.rows), "seeds": [min(seeds), max(seeds)],
                "duration_s": self.rows[0]["duration_s"], "profiles": list(self.profiles),
                "target": self.target, "exceeded": a["k"],
                "rate": round(a["rate"], 4),
                "interval95": [round(v, 4) for v in a["interval95"]],
                "spread": {k: round(v, 2) for k, v in self.spread.items()},
                **self.rule(),
                "seed": {"target": self.seed_target,
                         "episode_probability": self.episode_probability,
                         "declared": self.seed_achieved["k"],
                         "rate": round(self.seed_achieved["rate"], 4),
                         "interval95": [round(v, 4) for v in self.seed_achieved["interval95"]],
                         "default": DEFAULT_EPISODE_PROBABILITY,
                         "declared_default": seed_declared(self.rows,
                                                           DEFAULT_EPISODE_PROBABILITY)}}

    def rule(self) -> dict:
        """How the budget was split (``rule``, ``shares``: each threshold's share of the
        target) and, per hypothesis, the growth c that moved the flights' maxima from their
        length to ``CALIBRATED_LENGTH_S`` (``glr3d.growth_of``; the analysis raises the
        thresholds by the same c for longer flights)."""
        from flight_fdi.core.ins3d.glr3d import PER_HYPOTHESIS, growth_of

        def r(x: float) -> float:
            return float(f"{x:.6g}")

        if not self.per_hypothesis:
            return {"rule": "per_kind", "shares": {k: r(self.target / len(KINDS)) for k in KINDS}}
        return {"rule": "per_hypothesis",
                "shares": {"outliers": r(OUTLIER_SHARE * self.target),
                           "hypothesis": r(hypothesis_share(self.target))},
                "growth": {h: growth_of(h) for h in PER_HYPOTHESIS}}


def run_calibration(grade: ImuGrade, flights: int, seed: int, target: float,
                    profiles: tuple[str, ...] = PROFILES,
                    duration_s: float = CALIBRATED_LENGTH_S, jobs: int = 1,
                    progress: bool = False, on_result: Callable[[dict], None] | None = None,
                    scheduler: str | None = None, seed_target: float | None = None,
                    per_hypothesis: bool = True) -> Calibration:
    """Simulate and analyse ``flights`` nominal flights of ``grade``; calibrate its thresholds
    (:func:`calibrate_grade`: per kind and, with ``per_hypothesis``, per hypothesis) and its
    seed-method episode probability (for ``seed_target``, default ``target``)."""
    if isinstance(flights, bool) or not isinstance(flights, int) or flights < MIN_FLIGHTS:
        raise EvalError(f"calibration needs at least {MIN_FLIGHTS} flights, got {flights!r}")
    if not 0.0 < target < 1.0:
        raise EvalError(f"false-isolation target must be within (0, 1), got {target!r}")
    seed_target = target if seed_target is None else seed_target
    if not 0.0 < seed_target < 1.0:
        raise EvalError(f"seed-method target must be within (0, 1), got {seed_target!r}")
    plan_ = plan(grade, flights, seed, tuple(profiles), duration_s)
    start, info = time.perf_counter(), {}
    rows = run_flights(plan_, jobs, progress, on_result, scheduler, info)
    thr, p = calibrate_grade(rows, target, per_hypothesis), calibrate_seed(rows, seed_target)
    above = exceeded_hypotheses(rows, thr) if per_hypothesis else exceeded(rows, thr)
    return Calibration(grade, target, rows, thr,
                       bootstrap_spread(rows, target, per_hypothesis=per_hypothesis),
                       rate(above, len(rows)), time.perf_counter() - start,
                       tuple(profiles), str(info.get("engine", "")), p, seed_target,
                       rate(seed_declared(rows, p), len(rows)), per_hypothesis)


__all__ = ["Calibration", "DEFAULT_EPISODE_PROBABILITY", "MIN_FLIGHTS", "NominalFlight",
           "OUTLIER_SHARE", "PROFILES", "bootstrap_spread", "calibrate",
           "calibrate_grade", "calibrate_hypotheses", "calibrate_seed", "check_rates", "exceeded",
           "exceeded_hypotheses", "hypothesis_growth", "hypothesis_share", "length_shift",
           "nominal_flight", "plan",
           "rate", "run_calibration", "run_flights", "seed_declared", "seed_statistic", "summary",
           "tail_threshold"]
