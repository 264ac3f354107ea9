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
engine (:mod:`flight_fdi.campaign.engine`: this process, a local Dask cluster or an existing
one). The result depends only on the study's configuration and seed, never on where it ran.
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Iterable, Sequence

import numpy as np

from flight_fdi.core.analysis import AnalysisConfig, run_analysis
from flight_fdi.core.models import DEG_PER_HOUR, G0
from flight_fdi.sim import FaultSpec, SimConfig, simulate

from .errors import EvalError

KINDS = ("nominal", "accel", "gyro")
FAULT_KINDS = ("accel", "gyro")
#: the model state each fault kind acts on (the true class of the confusion matrices)
TRUE_ELEMENT = {"nominal": "none", "accel": "accel_bias", "gyro": "gyro_drift"}
#: display unit of the levels: name and SI value of one unit
LEVEL_UNITS = {"accel": ("mg", 1e-3 * G0), "gyro": ("deg/h", DEG_PER_HOUR)}
DETECTORS = ("in_flight", "seed", "glr")
METHODS = ("seed", "glr")
SEED_DECLARED = ("glitch", "failure", "ambiguous")
#: magnitude levels of the default study (display units); they bracket where GLR starts to
#: isolate (~0.2 mg, ~0.3 deg/h on a 600-s flight) and reach where the in-flight gate alarms
DEFAULT_ACCEL_LEVELS_MG = (0.05, 0.1, 0.15, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0)
DEFAULT_GYRO_LEVELS_DEG_H = (0.05, 0.1, 0.2, 0.3, 0.5, 1.0, 2.0, 5.0, 10.0, 30.0)
ISOLATION_LEVEL = 0.95


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

def glr_class(hypothesis: str) -> str:
    """The class a GLR hypothesis isolates: the stepped state for ``<state>_step`` /
    ``step:<state>``, the hypothesis name itself otherwise (``none``, ``accel_bias_ramp``,
    ``reference_jump``...)."""
    if hypothesis.startswith("step:"):
        return hypothesis[5:]
    if hypothesis.endswith("_step"):
        return hypothesis[:-5]
    return hypothesis


#: the class GLR gives a flight whose best hypothesis is not a confident single explanation
AMBIGUOUS = "ambiguous"


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


# --------------------------------------------------------------------------- decisions

def declared(record: dict, detector: str) -> bool:
    """Whether ``detector`` declared a fault on this flight. For ``in_flight`` on a faulty flight
    only an alarm raised at or after the onset counts (an earlier one is a false alarm)."""
    if detector == "in_flight":
        if record["onset_s"] is None:
            return bool(record["alarms"])
        return record["first_alarm_after_onset_s"] is not None
    if detector == "seed":
        return record["seed"]["verdict"] in SEED_DECLARED
    if detector == "glr":
        return record["glr"]["hypothesis"] != "none"
    raise EvalError(f"unknown detector {detector!r}; choose one of {', '.join(DETECTORS)}")


def predicted_class(record: dict, method: str) -> str:
    """The class ``method`` isolated on this flight ("none" when it declared no fault)."""
    if not declared(record, method):
        return "none"
    if method == "seed":
        return record["seed"]["element"] or "none"
    if method == "glr":
        if record["glr"].get("isolation", "single") != "single":
            return AMBIGUOUS
        return glr_class(record["glr"]["hypothesis"])
    raise EvalError(f"unknown isolation method {method!r}; choose one of {', '.join(METHODS)}")


def isolated(record: dict, method: str) -> bool:
    """Declared a fault and named the true element (faulty flights only)."""
    return record["kind"] != "nominal" and predicted_class(record, method) == record["true_element"]


# --------------------------------------------------------------------------- metrics

def type_errors(nominal_declared: Sequence[bool], faulty_declared: Sequence[bool]) -> dict:
    """Type I and type II error rates of a detector from its decisions (seed 003, table 4.1):
    H0 = "healthy". Type I: H0 true but rejected (a fault declared on a nominal flight);
    type II: H0 false but accepted (no fault declared on a faulty flight). A rate is None when
    there are no flights of its kind."""
    nom = [bool(d) for d in nominal_declared]
    fau = [bool(d) for d in faulty_declared]
    fa = sum(nom)
    missed = sum(not d for d in fau)
    return {"nominal": len(nom), "false_alarms": fa, "type_I": fa / len(nom) if nom else None,
            "faulty": len(fau), "missed": missed,
            "type_II": missed / len(fau) if fau else None}


def error_rates(records: Sequence[dict], detector: str) -> dict:
    """Type I and type II errors of ``detector`` (seed 003, table 4.1; H0 = healthy).

    type_I = false alarms / nominal flights (H0 true, rejected);
    type_II = missed / faulty flights (H0 false, accepted). A rate is None without flights.
    ``wrong_isolation`` (methods only): declared on a faulty flight and confidently named
    another element; ``ambiguous`` (GLR): declared but reported as ambiguous / unexplained.
    """
    nominal = [r for r in records if r["kind"] == "nominal"]
    faulty = [r for r in records if r["kind"] != "nominal"]
    out = type_errors([declared(r, detector) for r in nominal],
                      [declared(r, detector) for r in faulty])
    if detector in METHODS:
        amb = [declared(r, detector) and predicted_class(r, detector) == AMBIGUOUS
               for r in faulty]
        wrong = sum(declared(r, detector) and not isolated(r, detector) and not a
                    for r, a in zip(faulty, amb))
        out["wrong_isolation"] = wrong
        out["wrong_isolation_rate"] = wrong / len(faulty) if faulty else None
        out["ambiguous"] = sum(amb)
        out["ambiguous_rate"] = sum(amb) / len(faulty) if faulty else None
    return out


def confusion_matrix(records: Sequence[dict], method: str) -> dict:
    """Counts of (true class, isolated class) for ``method``.

    Rows: the true classes present (none, accel_bias, gyro_drift); columns: "none", the true
    classes, then any other class the method produced (e.g. velocity_error, tilt,
    reference_jump), in first-seen order.
    """
    rows = [c for c in ("none", "accel_bias", "gyro_drift")
            if any(r["true_element"] == c for r in records)]
    cols = ["none"] + [c for c in ("accel_bias", "gyro_drift") if c in rows]
    pred = [predicted_class(r, method) for r in records]
    for p in pred:
        if p not in cols:
            cols.append(p)
    counts = np.zeros((len(rows), len(cols)), dtype=int)
    for r, p in zip(records, pred):
        counts[rows.index(r["true_element"]), cols.index(p)] += 1
    return {"true": rows, "predicted": cols, "counts": counts.tolist()}


def _stats(values: Iterable[float]) -> dict:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return {"n": 0, "mean": None, "std": None, "median": None, "p05": None, "p95": None,
                "min": None, "max": None}
    return {"n": int(v.size), "mean": float(v.mean()), "std": float(v.std()),
            "median": float(np.median(v)), "p05": float(np.percentile(v, 5)),
            "p95": float(np.percentile(v, 95)), "min": float(v.min()), "max": float(v.max())}


def _diff(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def _rate(num: int, den: int) -> float | None:
    return num / den if den else None


def by_level(records: Sequence[dict], kind: str) -> list[dict]:
    """Per magnitude level of ``kind``: detection and isolation rates, delays, errors."""
    unit = LEVEL_UNITS[kind][0]
    out = []
    levels = sorted({r["level"] for r in records if r["kind"] == kind})
    for level in levels:
        rs = [r for r in records if r["kind"] == kind and r["level"] == level]
        n = len(rs)
        row: dict[str, Any] = {"level": level, "unit": unit, "n": n}
        for det in DETECTORS:
            row[f"{det}_detected"] = _rate(sum(declared(r, det) for r in rs), n)
        for m in METHODS:
            row[f"{m}_isolated"] = _rate(sum(isolated(r, m) for r in rs), n)
        delays = [r["first_alarm_after_onset_s"] - r["onset_s"] for r in rs
                  if r["first_alarm_after_onset_s"] is not None]
        row["delay_median_s"] = _stats(delays)["median"]
        ok = [r for r in rs if isolated(r, "glr")]
        row["glr_onset_error_median_s"] = _stats(
            abs(r["glr"]["onset_s"] - r["onset_s"]) for r in ok)["median"]
        row["glr_magnitude_error_median"] = _stats(
            abs(r["glr"]["magnitude"] / r["magnitude"] - 1.0) for r in ok)["median"]
        out.append(row)
    return out


def smallest_isolated(rows: Sequence[dict], method: str,
                      level: float = ISOLATION_LEVEL) -> float | None:
    """The smallest magnitude level from which ``method`` isolates the fault in at least
    ``level`` of the runs at that level *and at every larger level* (None: no such level)."""
    best = None
    for row in sorted(rows, key=lambda r: r["level"], reverse=True):
        rate = row[f"{method}_isolated"]
        if rate is None or rate < level:
            break
        best = row["level"]
    return best


def _onset_errors(records: Sequence[dict]) -> dict:
    from .onset import onset_errors  # (that module builds on this one)

    return onset_errors(records)


def _format_onset_errors(table: dict) -> str:
    from .onset import format_onset_errors

    return format_onset_errors(table)


def summarize(records: Sequence[dict]) -> dict:
    """All metrics of a study from its per-flight records (see the module docstring)."""
    records = sorted(records, key=lambda r: r["index"])
    nominal = [r for r in records if r["kind"] == "nominal"]
    faulty = [r for r in records if r["kind"] != "nominal"]
    kinds = [k for k in FAULT_KINDS if any(r["kind"] == k for r in records)]
    n_samples = sum(r["samples"] for r in nominal)
    n_valid = sum(r["seed"]["J_valid"] for r in nominal)
    out: dict[str, Any] = {
        "flights": {k: sum(r["kind"] == k for r in records) for k in KINDS},
        "false_alarms": {
            "in_flight": {
                "per_sample_exceed_rate": _rate(sum(r["exceeded"] for r in nominal), n_samples),
                "per_flight_rate": _rate(sum(bool(r["alarms"]) for r in nominal), len(nominal)),
                "flights_with_alarm": sum(bool(r["alarms"]) for r in nominal),
                "faulty_flights_alarm_before_onset": sum(r["false_alarms"] > 0 for r in faulty),
            },
            "seed": {
                "per_sample_J_exceed_rate": _rate(sum(r["seed"]["J_exceeded"] for r in nominal),
                                                  n_valid),
                "per_flight_rate": _rate(sum(declared(r, "seed") for r in nominal),
                                         len(nominal)),
            },
            "glr": {"per_flight_rate": _rate(sum(declared(r, "glr") for r in nominal),
                                             len(nominal))},
        },
        "error_rates": {det: error_rates(records, det) for det in DETECTORS},
        "missed_detections": {det: {k: sum(not declared(r, det) for r in faulty
                                           if r["kind"] == k) for k in kinds}
                              for det in DETECTORS},
        "detection_delay_s": {k: _stats(r["first_alarm_after_onset_s"] - r["onset_s"]
                                        for r in faulty if r["kind"] == k
                                        and r["first_alarm_after_onset_s"] is not None)
                              for k in kinds},
        "confusion": {m: confusion_matrix(records, m) for m in METHODS},
        "onset_error_s": {m: {k: _stats(_diff(r[m]["onset_s"], r["onset_s"]) for r in faulty
                                        if r["kind"] == k and isolated(r, m))
                              for k in kinds} for m in METHODS},
        "onset_error_detected_s": {m: {k: _stats(_diff(r[m]["onset_s"], r["onset_s"])
                                                 for r in faulty
                                                 if r["kind"] == k and declared(r, m))
                                       for k in kinds} for m in METHODS},
        "magnitude_error_relative": {"glr": {k: _stats(r["glr"]["magnitude"] / r["magnitude"]
                                                       - 1.0 for r in faulty
                                                       if r["kind"] == k and isolated(r, "glr"))
                                             for k in kinds}},
        "by_level": {k: by_level(records, k) for k in kinds},
        "onset_error_glr": _onset_errors(records),
    }
    out["smallest_isolated_95"] = {
        m: {k: {"level": smallest_isolated(out["by_level"][k], m), "unit": LEVEL_UNITS[k][0]}
            for k in kinds} for m in METHODS}
    return out


# --------------------------------------------------------------------------- a study

@dataclass
class StudyResult:
    config: StudyConfig
    records: list[dict]
    metrics: dict
    elapsed_s: float
    jobs: int  # workers the flights ran on
    engine: str = ""  # where they ran (campaign engine)

    def to_dict(self, with_records: bool = True) -> dict:
        d = {"config": self.config.describe(), "jobs": self.jobs, "engine": self.engine,
             "elapsed_s": self.elapsed_s, "metrics": self.metrics}
        if with_records:
            d["flights"] = self.records
        return d


def parallel_map(fn: Callable[[Any], dict], items: Sequence[Any], jobs: int = 1,
                 progress: bool = False, desc: str = "montecarlo",
                 on_result: Callable[[dict], None] | None = None, scheduler: str | None = None,
                 info: dict | None = None) -> list[dict]:
    """``[fn(item) for item in items]`` on the campaign engine (results in completion order),
    with an optional tqdm progress bar on stderr: in this process when ``jobs`` is 1, else on a
    local Dask cluster of ``jobs`` worker processes, or on the existing cluster at
    ``scheduler`` (tcp://HOST:PORT). ``fn`` must be a module-level function and each item carry
    its own seed: the results do not depend on where they ran. The first item that raises stops
    the map (the others are cancelled) and its exception is raised here. ``info``, when given,
    receives ``engine`` (where it ran) and ``workers``."""
    if isinstance(jobs, bool) or not isinstance(jobs, (int, np.integer)) or jobs < 1:
        raise EvalError(f"jobs must be an integer >= 1, got {jobs!r}")
    from flight_fdi.campaign.engine import Engine, EngineError, EngineSpec

    try:
        spec = EngineSpec(workers=max(1, min(int(jobs), len(items))), scheduler=scheduler)
    except EngineError as exc:
        raise EvalError(str(exc)) from None
    out: list[dict] = []

    def arrived(_i: int, rec: dict, err: BaseException | None) -> None:
        if err is not None:
            raise err
        out.append(rec)
        if on_result is not None:
            on_result(rec)

    with Engine(spec) as engine:
        if scheduler is not None:
            engine.wait_for_workers(1)
        if info is not None:
            info.update(engine=engine.describe(), workers=engine.worker_count())
        engine.run(fn, items, progress=progress, desc=desc, unit="flight", on_outcome=arrived)
    return out


def run_study(config: StudyConfig, jobs: int = 1, progress: bool = False,
              on_record: Callable[[dict], None] | None = None,
              scheduler: str | None = None) -> StudyResult:
    """Run every flight of the study on the campaign engine (:func:`parallel_map`: ``jobs``
    local worker processes, or the Dask cluster at ``scheduler``) and summarise.

    progress: show a tqdm progress bar on stderr. on_record: called with each record as it
    arrives (any order; e.g. to stream the records to disk). The records are returned in
    flight order.
    """
    if not isinstance(config, StudyConfig):
        raise EvalError(f"run_study: config must be a StudyConfig, got {type(config).__name__}")
    cases = plan_study(config)
    start = time.perf_counter()
    info: dict = {}
    records = parallel_map(_run_indexed, [(c, config) for c in cases], jobs, progress,
                           on_result=on_record, scheduler=scheduler, info=info)
    records.sort(key=lambda r: r["index"])
    return StudyResult(config=config, records=records, metrics=summarize(records),
                       elapsed_s=time.perf_counter() - start, jobs=info["workers"],
                       engine=info["engine"])


# --------------------------------------------------------------------------- text output

def _pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}%"


def _num(x: float | None, spec: str = ".3g") -> str:
    return "-" if x is None else format(x, spec)


def format_metrics(metrics: dict) -> str:
    """A human-readable report of :func:`summarize`'s metrics (plain text / Markdown tables)."""
    fl = metrics["flights"]
    fa = metrics["false_alarms"]
    lines = [f"flights: {fl['nominal']} nominal, {fl['accel']} accelerometer, {fl['gyro']} gyro",
             "",
             "false alarms on nominal flights:",
             "  in-flight gate: per sample "
             f"{_num(fa['in_flight']['per_sample_exceed_rate'], '.2e')}"
             f" (beta^2 > gate), per flight {_pct(fa['in_flight']['per_flight_rate'])} "
             f"(M-of-N alarm)",
             f"  seed method: per sample {_num(fa['seed']['per_sample_J_exceed_rate'], '.2e')}"
             f" (J > gamma^2), per flight {_pct(fa['seed']['per_flight_rate'])}",
             f"  GLR: per flight {_pct(fa['glr']['per_flight_rate'])}",
             "",
             "| detector | type I (false alarm) | type II (missed) | confidently wrong element "
             "| ambiguous |",
             "|---|---|---|---|---|"]
    for det, e in metrics["error_rates"].items():
        wrong = _pct(e.get("wrong_isolation_rate")) if "wrong_isolation_rate" in e else "n/a"
        amb = _pct(e.get("ambiguous_rate")) if "ambiguous_rate" in e else "n/a"
        lines.append(f"| {det} | {_pct(e['type_I'])} ({e['false_alarms']}/{e['nominal']}) | "
                     f"{_pct(e['type_II'])} ({e['missed']}/{e['faulty']}) | {wrong} | {amb} |")
    for m, cm in metrics["confusion"].items():
        lines += ["", f"confusion matrix, {m} (rows: true, columns: isolated)",
                  "| true \\ isolated | " + " | ".join(cm["predicted"]) + " |",
                  "|---" * (len(cm["predicted"]) + 1) + "|"]
        for name, row in zip(cm["true"], cm["counts"]):
            lines.append(f"| {name} | " + " | ".join(str(c) for c in row) + " |")
    for kind, d in metrics["detection_delay_s"].items():
        lines += ["", f"in-flight detection delay, {kind}: n {d['n']}, median "
                  f"{_num(d['median'], '.1f')} s, 5-95% {_num(d['p05'], '.1f')} .. "
                  f"{_num(d['p95'], '.1f')} s"]
    lines.append("")
    for m in METHODS:
        for which, label in (("onset_error_s", "isolated"), ("onset_error_detected_s",
                                                             "detected")):
            for kind, d in metrics[which][m].items():
                lines.append(f"onset error {m}, {kind} ({label}): n {d['n']}, median "
                             f"{_num(d['median'], '.2f')} s, 5-95% {_num(d['p05'], '.2f')} .. "
                             f"{_num(d['p95'], '.2f')} s")
    for kind, d in metrics["magnitude_error_relative"]["glr"].items():
        lines.append(f"magnitude error glr, {kind} (relative, isolated): n {d['n']}, median "
                     f"{_pct(d['median'])}, 5-95% {_pct(d['p05'])} .. {_pct(d['p95'])}")
    for kind, rows in metrics["by_level"].items():
        lines += ["", f"{kind} faults by magnitude:",
                  "| level | n | in-flight detected | median delay s | seed detected | "
                  "seed isolated | GLR detected | GLR isolated | GLR onset err s | "
                  "GLR magnitude err |", "|---" * 10 + "|"]
        for r in rows:
            lines.append(
                f"| {r['level']:g} {r['unit']} | {r['n']} | {_pct(r['in_flight_detected'])} | "
                f"{_num(r['delay_median_s'], '.1f')} | {_pct(r['seed_detected'])} | "
                f"{_pct(r['seed_isolated'])} | {_pct(r['glr_detected'])} | "
                f"{_pct(r['glr_isolated'])} | {_num(r['glr_onset_error_median_s'], '.1f')} | "
                f"{_pct(r['glr_magnitude_error_median'])} |")
    lines += ["", f"smallest fault isolated in >= {100 * ISOLATION_LEVEL:.0f}% of runs "
              "(at that level and every larger one):"]
    for m, per in metrics["smallest_isolated_95"].items():
        parts = [f"{k}: " + ("not reached" if v["level"] is None else f"{v['level']:g} {v['unit']}")
                 for k, v in per.items()]
        lines.append(f"  {m}: " + ", ".join(parts))
    if metrics.get("onset_error_glr"):
        lines += ["", "GLR onset error where GLR names the true fault (isolated, or among the "
                      "candidates of an ambiguous result):", "",
                  _format_onset_errors(metrics["onset_error_glr"])]
    return "\n".join(lines)
