"""Monte Carlo evaluation of the detectors and both isolation methods (SPEC section 6).

A *study* is a seeded list of simulated flights (:func:`plan_study`): nominal flights, and flights
with an accelerometer or a gyro bias step of a magnitude from a grid of levels and a random sign,
starting at a random onset time. Every flight is simulated in memory
(:func:`flight_fdi.sim.simulate`, no bag) and analysed with the same core as
``flight-fdi analyze`` (:func:`flight_fdi.core.analysis.run_analysis`). Each flight leaves a small
record (:func:`run_case`); :func:`summarize` turns the records into the metrics:

* false alarms of the in-flight gate: per sample (fraction of samples whose beta^2 exceeds the
  gate) and per flight (fraction of nominal flights with at least one M-of-N alarm);
* false alarms of the post-flight methods per flight, and of the seed chi-square J per sample;
* missed detections and the detection delay of the in-flight alarm (first alarm raised at or
  after the onset, minus the onset);
* the isolation confusion matrix of the seed method (chi-square J with UDU^T localization and
  the Fisher test) and of GLR;
* onset-time error (both methods; over the flights where the method isolated the fault, and over
  those where it declared any fault) and magnitude error (GLR; the seed method gives none);
* type I and type II error rates (seed 003, table 4.1): the hypothesis under test is "the
  system is healthy". Type I: a healthy flight is declared faulty (rejected although true) --
  the per-flight false-alarm rate. Type II: a faulty flight is declared healthy (accepted
  although false) -- the missed-detection rate;
* per magnitude level: detection and isolation rates, and the smallest level from which each
  method isolates the fault in at least 95 % of the runs.

Detectors and methods
---------------------
``in_flight``: the M-of-N beta^2 alarm of the forward filter. ``seed``: a fault is declared when
the seed method's verdict is ``glitch``, ``failure`` or ``ambiguous``; its isolated class is the
element it names. ``glr``: a fault is declared when GLR's statistic exceeds its threshold; its
class is the hypothesis' element (``accel_bias_step`` -> ``accel_bias``, ``gyro_drift_step`` ->
``gyro_drift``; reference hypotheses keep their own names; a flight GLR reports as ambiguous or
unexplained has the class ``ambiguous``). A fault is *isolated* when it is declared and the
class equals the true element; GLR *names* it when it is isolated or among the candidates of
an ambiguous result (:func:`onset_errors` reports onset errors over the named faults).

Everything here is pure (numpy, no rclpy); :func:`run_study` runs the flights on the campaign
engine (:func:`flight_fdi.eval.parallel.parallel_map`: this process, a local Dask cluster or an
existing one) and resumes a study from its records file (:mod:`flight_fdi.eval.records`). The
result depends only on the study's configuration and seed, never on where it ran or whether it
was interrupted. The decisions are in :mod:`.decisions`, the metrics in :mod:`.study_metrics`,
their text in :mod:`.study_report` (all re-exported here).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Iterable, Mapping

import numpy as np

from flight_fdi.core.analysis import AnalysisConfig, run_analysis
from flight_fdi.sim import FaultSpec, SimConfig, simulate

from .decisions import (AMBIGUOUS, DETECTORS, FAULT_KINDS, ISOLATION_LEVEL,  # noqa: F401
                        KINDS, LEVEL_UNITS, METHODS, SEED_DECLARED, TRUE_ELEMENT, fmt_num, fmt_pct,
                        stats_of, declared, glr_class, isolated, predicted_class)
from .errors import EvalError
from .parallel import parallel_map
from .records import recorded_flights
from .study_metrics import (by_level, confusion_matrix, error_rates,  # noqa: F401
                            smallest_isolated, summarize, type_errors)
from .study_report import format_metrics  # noqa: F401

#: magnitude levels of the default study (display units); they bracket where GLR starts to
#: isolate (~0.2 mg, ~0.3 deg/h on a 600-s flight) and reach where the in-flight gate alarms
DEFAULT_ACCEL_LEVELS_MG = (0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0)
DEFAULT_GYRO_LEVELS_DEG_H = (0.05, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0)


def _positive(name: str, value: Any, integer: bool = False, allow_zero: bool = False) -> None:
    ok_type = (isinstance(value, (int, np.integer)) if integer
               else isinstance(value, (int, float, np.integer, np.floating)))
    if isinstance(value, bool) or not ok_type or not math.isfinite(float(value)) \
            or (value < 0 if allow_zero else value <= 0):
        kind = "an integer" if integer else "a number"
        bound = ">= 0" if allow_zero else "> 0"
        raise EvalError(f"StudyConfig.{name} must be {kind} {bound}, got {value!r}")


@dataclass(frozen=True)
class StudyConfig:
    """What a Monte Carlo study simulates and how it analyses each flight.

    nominal: number of flights without a fault.
    per_fault: number of flights per fault kind (accelerometer, gyro); they are spread evenly
        over the magnitude levels (flight j of a kind gets level j mod L).
    accel_levels_mg, gyro_levels_deg_h: step magnitudes (absolute; the sign is random).
    duration_s, ins_rate_hz, ref_rate_hz, channel: the simulated flights (see SimConfig).
    onset_window: the onset is uniform in [a, b] x duration_s.
    seed: the one seed of the study (onsets, signs and every flight's simulator seed).
    analysis: the analysis of each flight (gate, seed method, GLR).
    """

    nominal: int = 200
    per_fault: int = 200
    accel_levels_mg: tuple = DEFAULT_ACCEL_LEVELS_MG
    gyro_levels_deg_h: tuple = DEFAULT_GYRO_LEVELS_DEG_H
    duration_s: float = 600.0
    onset_window: tuple = (0.1, 0.8)
    seed: int = 0
    ins_rate_hz: float = 50.0
    ref_rate_hz: float = 10.0
    channel: str = "x"
    analysis: AnalysisConfig = field(default_factory=AnalysisConfig)

    def __post_init__(self) -> None:
        _positive("nominal", self.nominal, integer=True, allow_zero=True)
        _positive("per_fault", self.per_fault, integer=True, allow_zero=True)
        if self.nominal + self.per_fault == 0:
            raise EvalError("StudyConfig: the study has no flights (nominal = per_fault = 0)")
        for name in ("accel_levels_mg", "gyro_levels_deg_h"):
            levels = getattr(self, name)
            if isinstance(levels, (str, bytes)) or not isinstance(levels, Iterable):
                raise EvalError(f"StudyConfig.{name} must be a list of numbers > 0")
            levels = tuple(float(v) for v in levels)
            if self.per_fault and not levels:
                raise EvalError(f"StudyConfig.{name} is empty but per_fault = {self.per_fault}")
            for v in levels:
                _positive(name, v)
            if len(set(levels)) != len(levels):
                raise EvalError(f"StudyConfig.{name} has duplicate levels: {levels}")
            object.__setattr__(self, name, tuple(sorted(levels)))
        for name in ("duration_s", "ins_rate_hz", "ref_rate_hz"):
            _positive(name, getattr(self, name))
        _positive("seed", self.seed, integer=True, allow_zero=True)
        try:
            a, b = (float(v) for v in self.onset_window)
        except (TypeError, ValueError):
            raise EvalError(f"StudyConfig.onset_window must be two fractions (a, b), got "
                            f"{self.onset_window!r}") from None
        if not (0.0 < a <= b < 1.0):
            raise EvalError(f"StudyConfig.onset_window must satisfy 0 < a <= b < 1 (fractions of "
                            f"the flight), got ({a:g}, {b:g})")
        object.__setattr__(self, "onset_window", (a, b))
        if self.channel not in ("x", "y"):
            raise EvalError(f"StudyConfig.channel must be x or y, got {self.channel!r}")
        if not isinstance(self.analysis, AnalysisConfig):
            raise EvalError("StudyConfig.analysis must be an AnalysisConfig")

    def levels(self, kind: str) -> tuple:
        return {"accel": self.accel_levels_mg, "gyro": self.gyro_levels_deg_h}[kind]

    def describe(self) -> dict:
        """Plain data (JSON) of the study's settings."""
        d = {k: v for k, v in asdict(self).items() if k != "analysis"}
        d["onset_window"] = list(self.onset_window)
        a = self.analysis
        d["analysis"] = {"gate": asdict(a.gate), "fisher_window": a.fisher_window,
                         "persistence_s": a.persistence_s,
                         "episode_probability": a.episode_probability,
                         "glr_p_false_alarm": a.glr_p_false_alarm,
                         "glr_hypotheses": list(a.glr_hypotheses)}
        return d


@dataclass(frozen=True)
class FlightCase:
    """One flight of a study. ``level`` is the absolute magnitude in display units (mg, deg/h),
    ``magnitude`` the signed step in SI units (m/s^2, rad/s); both None for a nominal flight."""

    index: int
    kind: str
    sim_seed: int
    duration_s: float
    level: float | None = None
    magnitude: float | None = None
    onset_s: float | None = None

    @property
    def true_element(self) -> str:
        return TRUE_ELEMENT[self.kind]

    def fault(self) -> FaultSpec | None:
        if self.kind == "nominal":
            return None
        return FaultSpec(target=self.kind, type="step", start_s=float(self.onset_s),
                         magnitude=float(self.magnitude))


def plan_study(config: StudyConfig) -> list[FlightCase]:
    """The study's flights: nominal first, then the accelerometer and the gyro faults.

    Onsets are rounded to the reference interval so that a fault starts at a reference sample.
    """
    rng = np.random.default_rng(np.random.SeedSequence(config.seed))
    cases: list[FlightCase] = []
    lo, hi = config.onset_window
    step = 1.0 / config.ref_rate_hz

    def sim_seed() -> int:
        return int(rng.integers(0, 2**31 - 1))

    for _ in range(config.nominal):
        cases.append(FlightCase(len(cases), "nominal", sim_seed(), config.duration_s))
    for kind in FAULT_KINDS:
        levels = config.levels(kind)
        unit = LEVEL_UNITS[kind][1]
        for j in range(config.per_fault):
            level = levels[j % len(levels)]
            sign = 1.0 if rng.random() < 0.5 else -1.0
            onset = round(float(rng.uniform(lo, hi)) * config.duration_s / step) * step
            cases.append(FlightCase(len(cases), kind, sim_seed(), config.duration_s,
                                    level=float(level), magnitude=sign * level * unit,
                                    onset_s=float(onset)))
    return cases


# --------------------------------------------------------------------------- one flight

def run_case(case: FlightCase, config: StudyConfig) -> dict:
    """Simulate and analyse one flight; a small JSON-able record (times in s from the start)."""
    fault = case.fault()
    sim = SimConfig(duration_s=case.duration_s, ins_rate_hz=config.ins_rate_hz,
                    ref_rate_hz=config.ref_rate_hz, truth_rate_hz=config.ref_rate_hz,
                    seed=case.sim_seed, channel=config.channel,
                    faults=() if fault is None else (fault,))
    flight = simulate(sim)
    a = 0 if config.channel == "x" else 1
    res = run_analysis(flight.model, flight.t, flight.v_ins[:, a], flight.t_ref,
                       flight.v_ref[:, a], config=config.analysis, channel=config.channel,
                       t0=0.0)
    summary = res.summary
    alarms = [float(al["start_s"]) for al in summary["in_flight"]["alarms"]]
    onset = case.onset_s
    after = [s for s in alarms if onset is not None and s >= onset]
    before = [s for s in alarms if onset is None or s < onset]
    seed = res.seed
    valid = np.asarray(seed.valid, dtype=bool)
    with np.errstate(invalid="ignore"):
        j_exceed = int(np.count_nonzero(valid & (seed.J > seed.gamma2)))
    post = summary["post_flight"]
    glr = post["glr"]
    candidates = [{"hypothesis": c["hypothesis"], "onset_s": c["onset_s"],
                   "magnitude": c["magnitude"]} for c in post["candidates"]]
    return {
        "index": case.index, "kind": case.kind, "sim_seed": case.sim_seed,
        "level": case.level, "magnitude": case.magnitude, "onset_s": onset,
        "true_element": case.true_element,
        "samples": int(len(res.fwd.t)),
        "exceeded": int(np.count_nonzero(res.fwd.exceeded)),
        "alarms": alarms,
        "false_alarms": len(before),
        "first_alarm_after_onset_s": after[0] if after else None,
        "seed": {"verdict": seed.verdict, "element": seed.element,
                 "onset_s": None if seed.onset_t is None else float(seed.onset_t) - res.t0,
                 "J_exceeded": j_exceed, "J_valid": int(valid.sum())},
        "glr": {"hypothesis": glr["hypothesis"], "onset_s": glr["onset_s"],
                "magnitude": glr["magnitude"], "statistic": glr["statistic"],
                "threshold": glr["threshold"], "isolation": glr["isolation"],
                "candidates": candidates},
        "verdict": post["verdict"], "element": post["element"],
    }


def _run_indexed(args: tuple[FlightCase, StudyConfig]) -> dict:
    return run_case(*args)


# --------------------------------------------------------------------------- a study

@dataclass
class StudyResult:
    config: StudyConfig
    records: list[dict]
    metrics: dict
    elapsed_s: float
    jobs: int  # workers the flights ran on
    engine: str = ""  # where they ran (campaign engine)
    resumed: int = 0  # records taken from an earlier, interrupted run (not run again)

    def to_dict(self, with_records: bool = True) -> dict:
        d = {"config": self.config.describe(), "jobs": self.jobs, "engine": self.engine,
             "elapsed_s": self.elapsed_s, "resumed": self.resumed, "metrics": self.metrics}
        if with_records:
            d["flights"] = self.records
        return d


def run_study(config: StudyConfig, jobs: int = 1, progress: bool = False,
              on_record: Callable[[dict], None] | None = None,
              scheduler: str | None = None, done: Mapping[int, dict] | None = None) -> StudyResult:
    """Run every flight of the study on the campaign engine (:func:`parallel_map`: ``jobs``
    local worker processes, or the Dask cluster at ``scheduler``) and summarise.

    progress: show a tqdm progress bar on stderr. on_record: called with each new record as it
    arrives (any order; e.g. to stream the records to disk). done: records of this study
    already made, by flight index (a resumed study, :class:`~flight_fdi.eval.records.RecordsFile`):
    those flights are not run again. The records are returned in flight order.
    """
    if not isinstance(config, StudyConfig):
        raise EvalError(f"run_study: config must be a StudyConfig, got {type(config).__name__}")
    cases = plan_study(config)
    kept = _recorded(cases, done or {})
    start = time.perf_counter()
    info: dict = {}
    todo = [(c, config) for c in cases if c.index not in kept]
    records = parallel_map(_run_indexed, todo, jobs, progress, on_result=on_record,
                           scheduler=scheduler, info=info, warm=_warm_worker)
    records = sorted(records + list(kept.values()), key=lambda r: r["index"])
    return StudyResult(config=config, records=records, metrics=summarize(records),
                       elapsed_s=time.perf_counter() - start, jobs=info["workers"],
                       engine=info["engine"], resumed=len(kept))


def _warm_worker() -> None:
    from flight_fdi.campaign.worker import warm_analysis

    warm_analysis()


def _recorded(cases: list[FlightCase], done: Mapping[int, dict]) -> dict[int, dict]:
    """The records of ``done`` that belong to this study's flights (same index, kind and
    simulator seed); anything else means the records are of another study."""
    return recorded_flights(done, {c.index: {"sim_seed": c.sim_seed, "kind": c.kind}
                                   for c in cases})
