"""Monte Carlo evaluation of the 3-D model ``ins3d`` (issue 15, item 5), with the single-axis
model on the same flights beside it.

A *study* (:func:`plan_study`) is a seeded list of simulated 3-D flights (``sim.ins3d``: turns,
climbs, speed changes; body-axis IMU errors; GNSS with white + Markov noise and latency): nominal
flights, and flights with one fault of a *scenario* (:data:`SCENARIOS`: body-axis accelerometer or
gyro bias steps and ramps on x/y/z, GNSS velocity jumps east/north) at a magnitude from the
scenario's levels, a random sign and a random onset (anywhere in the onset window: in turns too).
Every flight is simulated in memory and analysed

* by the 3-D model: ``core.ins3d.analysis.analyze_ins3d`` on the contract topics' content
  (``bagio.ins3d_input.from_flight``: what a bag of the flight would give), its ``post_flight``
  section (the single-axis result form: sensor, axis, kind, onset, magnitude, isolation);
* by the single-axis model (``core.analysis.run_analysis``, ``ins_channel``) on the flight's east
  and north INS / GNSS velocity channels -- what ``flight-fdi analyze`` does on the bag. The
  flight's single-axis result is the channel whose GLR statistic is the larger multiple of its
  threshold among the channels that declared a fault (:func:`combine_channels`).

Each flight leaves a small JSON-able record (:func:`run_case`); the metrics are in
:mod:`flight_fdi.eval.metrics3d`. The flights run on the campaign engine through
:func:`flight_fdi.eval.montecarlo.parallel_map` (this process, a local Dask cluster, or an
existing one); every case carries its own seeds, so the records do not depend on the worker count.
"""
from __future__ import annotations

import math
import time
from os import PathLike
from dataclasses import asdict, dataclass, field
from typing import Any, Callable, Mapping

import numpy as np

from flight_fdi.sim.faults import DEG_PER_HOUR, G0

from .errors import EvalError

#: scenario -> (simulator target, fault type, sensor named in results, kind, axes (result
#: names), level unit, SI value of one level unit)
SCENARIOS: dict[str, tuple] = {
    "accel_step": ("accel", "step", "accelerometer", "step", ("x", "y", "z"), "mg", 1e-3 * G0),
    "gyro_step": ("gyro", "step", "gyro", "step", ("x", "y", "z"), "deg/h", DEG_PER_HOUR),
    "accel_ramp": ("accel", "ramp", "accelerometer", "ramp", ("x", "y", "z"), "mg/h",
                   1e-3 * G0 / 3600.0),
    "gyro_ramp": ("gyro", "ramp", "gyro", "ramp", ("x", "y", "z"), "deg/h^2",
                  DEG_PER_HOUR / 3600.0),
    "ref_jump": ("ref", "jump", "reference", "jump", ("east", "north"), "m/s", 1.0),
}
#: the simulator's axis name of a result axis
SIM_AXIS = {"x": "x", "y": "y", "z": "z", "east": "x", "north": "y", "up": "z"}
#: levels of the default study (navigation grade): the issue's targets and above
DEFAULT_LEVELS = {"accel_step": (0.3, 0.5, 1.0), "gyro_step": (0.05, 0.1, 0.2),
                  "accel_ramp": (1.0, 2.0, 4.0), "gyro_ramp": (0.5, 1.0, 2.0),
                  "ref_jump": (0.3, 0.5, 1.0)}
PROFILES = ("random", "cruise_turns", "survey_grid")
GRADES = ("navigation", "tactical", "mems")
MODELS = ("ins3d", "single_axis")
DECLARED = ("failure", "glitch", "ambiguous")
#: |bank| above this at the onset: the fault started in a turn
TURN_BANK_DEG = 2.0


def _check_int(name: str, value: Any, low: int) -> None:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
        raise EvalError(f"Study3DConfig.{name} must be an integer >= {low}, got {value!r}")


@dataclass(frozen=True)
class Study3DConfig:
    """What a 3-D study simulates and analyses.

    nominal: flights without a fault. per_scenario: flights per fault scenario, spread evenly
    over its axes and levels (flight j: axis j mod A, level (j // A) mod L).
    scenarios: names from :data:`SCENARIOS`; levels: per scenario, absolute magnitudes in the
    scenario's unit (mg, deg/h, mg/h, deg/h^2, m/s; the sign is random).
    duration_s: flight length; profile: the trajectory (``random``: a seeded trajectory per
    flight); grade: the IMU grade the flights are simulated with and analysed for (a preset
    name, a YAML grade file or an ImuGrade: :func:`study_grade`).
    onset_window: onset uniform in [a, b] x duration_s. gnss_latency_s: the receiver's latency
    (default the simulator's 20 ms; Markov noise as the simulator's defaults).
    single_axis: also run the single-axis model on the east and north channels.
    axes: run only the fault flights on these axes (empty: all); the plan and every flight's
    seeds are those of the whole study (a subset of it, re-run).
    """

    nominal: int = 200
    per_scenario: int = 30
    scenarios: tuple = tuple(SCENARIOS)
    levels: dict = field(default_factory=lambda: dict(DEFAULT_LEVELS))
    duration_s: float = 900.0
    profile: str = "random"
    grade: Any = "navigation"   # a preset name, or an ImuGrade / YAML grade file (study_grade)
    onset_window: tuple = (0.1, 0.8)
    gnss_latency_s: float = 0.02
    rows: int = 3
    seed: int = 0
    single_axis: bool = True
    analysis: Any = None     # core.analysis.AnalysisConfig of the single-axis model (None:
                             # its defaults); its gate is also the 3-D forward filter's
    axes: tuple = ()

    def __post_init__(self) -> None:
        _check_int("nominal", self.nominal, 0)
        _check_int("per_scenario", self.per_scenario, 0)
        _check_int("seed", self.seed, 0)
        scen = tuple(self.scenarios)
        for s in scen:
            if s not in SCENARIOS:
                raise EvalError(f"unknown scenario {s!r}; choose from {', '.join(SCENARIOS)}")
        object.__setattr__(self, "scenarios", scen)
        if self.nominal + self.per_scenario * len(scen) == 0:
            raise EvalError("Study3DConfig: the study has no flights")
        levels = {**DEFAULT_LEVELS, **dict(self.levels)}
        for s in scen:
            vals = tuple(sorted(float(v) for v in levels[s]))
            if not vals or any(not math.isfinite(v) or v <= 0 for v in vals):
                raise EvalError(f"Study3DConfig.levels[{s!r}] must be numbers > 0, got {vals}")
            levels[s] = vals
        object.__setattr__(self, "levels", {s: levels[s] for s in scen})
        d = self.duration_s
        if isinstance(d, bool) or not isinstance(d, (int, float)) or not 60.0 <= d <= 10800.0:
            raise EvalError(f"Study3DConfig.duration_s must be within 60..10800 s, got {d!r}")
        if self.profile not in PROFILES:
            raise EvalError(f"unknown profile {self.profile!r}; choose from {', '.join(PROFILES)}")
        object.__setattr__(self, "grade", study_grade(self.grade))
        try:
            a, b = (float(v) for v in self.onset_window)
        except (TypeError, ValueError):
            raise EvalError("Study3DConfig.onset_window must be two fractions (a, b)") from None
        if not 0.0 < a <= b < 1.0:
            raise EvalError(f"Study3DConfig.onset_window must satisfy 0 < a <= b < 1, got "
                            f"({a:g}, {b:g})")
        object.__setattr__(self, "onset_window", (a, b))
        lat = self.gnss_latency_s
        if not isinstance(lat, (int, float)) or not 0.0 <= lat <= 0.5:
            raise EvalError(f"Study3DConfig.gnss_latency_s must be within 0..0.5 s, got {lat!r}")
        from flight_fdi.core.analysis import AnalysisConfig

        if self.analysis is None:
            object.__setattr__(self, "analysis", AnalysisConfig())
        if not isinstance(self.analysis, AnalysisConfig):
            raise EvalError("Study3DConfig.analysis must be an AnalysisConfig")
        object.__setattr__(self, "axes", tuple(self.axes))
        known = {a for s in scen for a in SCENARIOS[s][4]}
        if any(a not in known for a in self.axes):
            raise EvalError(f"Study3DConfig.axes must be axes of the scenarios "
                            f"({', '.join(sorted(known))}), got {self.axes}")
        if self.rows not in (2, 3):
            raise EvalError(f"Study3DConfig.rows must be 2 or 3, got {self.rows!r}")

    @property
    def grade_name(self) -> str:
        return grade_name(self.grade)

    def describe(self) -> dict:
        d = asdict(self)
        d["grade"] = self.grade_name
        if not isinstance(self.grade, str):      # a grade file's: its numbers (SI)
            d["grade_values"] = self.grade.to_dict()
        a = self.analysis
        d["analysis"] = {"gate": asdict(a.gate), "glr_p_false_alarm": a.glr_p_false_alarm}
        d["scenarios"] = list(self.scenarios)
        d["levels"] = {k: list(v) for k, v in self.levels.items()}
        d["onset_window"] = list(self.onset_window)
        d["units"] = {s: SCENARIOS[s][5] for s in self.scenarios}
        return d


def study_grade(grade: Any) -> Any:
    """A study's grade: a preset name (:data:`GRADES`), or the ImuGrade of a YAML grade file
    (``core.ins3d.grade_file``) or given as one; EvalError otherwise."""
    from flight_fdi.core.errors import CoreError
    from flight_fdi.core.ins3d.grade_file import is_grade_file, load_grade
    from flight_fdi.core.ins3d.grades import ImuGrade

    if isinstance(grade, ImuGrade) or grade in GRADES:
        return grade
    if isinstance(grade, (str, PathLike)) and is_grade_file(str(grade)):
        try:
            return load_grade(grade)
        except CoreError as exc:
            raise EvalError(str(exc)) from None
    raise EvalError(f"unknown grade {grade!r}; choose from {', '.join(GRADES)} or give a YAML "
                    "grade file")


def grade_name(grade: Any) -> str:
    """The name of a preset name or an ImuGrade."""
    return grade if isinstance(grade, str) else grade.name


@dataclass(frozen=True)
class Case3D:
    """One flight: ``scenario`` 'nominal' or a key of :data:`SCENARIOS`; ``axis`` a result axis
    name; ``level`` absolute in the scenario's unit; ``magnitude`` signed SI (per second for a
    ramp); ``onset_s`` from the start."""

    index: int
    scenario: str
    sim_seed: int
    traj_seed: int
    axis: str | None = None
    level: float | None = None
    magnitude: float | None = None
    onset_s: float | None = None
    grade: Any = None            # None: the study's grade; else a preset name or an ImuGrade

    @property
    def sensor(self) -> str | None:
        return None if self.scenario == "nominal" else SCENARIOS[self.scenario][2]

    @property
    def kind(self) -> str | None:
        return None if self.scenario == "nominal" else SCENARIOS[self.scenario][3]

    def fault(self):
        from flight_fdi.sim.faults import FaultSpec3D

        if self.scenario == "nominal":
            return None
        target, ftype = SCENARIOS[self.scenario][:2]
        return FaultSpec3D(target=target, type=ftype, start_s=float(self.onset_s),
                           magnitude=float(self.magnitude), axis=SIM_AXIS[self.axis])


def _seed(rng: np.random.Generator) -> int:
    return int(rng.integers(0, 2**31 - 1))


def fault_case(index: int, scenario: str, axis: str, level: float, rng: np.random.Generator,
               config: Study3DConfig, grade: Any = None) -> Case3D:
    """A fault flight with a random sign, onset (on a 0.1-s grid) and seeds from ``rng``."""
    lo, hi = config.onset_window
    sign = 1.0 if rng.random() < 0.5 else -1.0
    onset = round(float(rng.uniform(lo, hi)) * config.duration_s, 1)
    unit = SCENARIOS[scenario][6]
    return Case3D(index, scenario, _seed(rng), _seed(rng), axis=axis, level=float(level),
                  magnitude=sign * float(level) * unit, onset_s=onset, grade=grade)


def plan_study(config: Study3DConfig) -> list[Case3D]:
    """The study's flights: nominal first, then each scenario in order."""
    rng = np.random.default_rng(np.random.SeedSequence(config.seed))
    cases: list[Case3D] = []
    for _ in range(config.nominal):
        cases.append(Case3D(len(cases), "nominal", _seed(rng), _seed(rng)))
    index = len(cases)
    for s in config.scenarios:
        axes, levels = SCENARIOS[s][4], config.levels[s]
        for j in range(config.per_scenario):
            axis = axes[j % len(axes)]
            level = levels[(j // len(axes)) % len(levels)]
            case = fault_case(index, s, axis, level, rng, config)
            index += 1
            if not config.axes or axis in config.axes:     # (config.axes: a subset, re-run)
                cases.append(case)
    return cases


# --------------------------------------------------------------------------- one flight

def simulate_case(case: Case3D, config: Study3DConfig):
    """The case's simulated flight (sim.ins3d.Flight3D)."""
    from flight_fdi.sim.gnss import GnssConfig
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    fault = case.fault()
    cfg = Sim3DConfig(trajectory=TrajectoryConfig(profile=config.profile,
                                                  duration_s=float(config.duration_s),
                                                  seed=case.traj_seed),
                      grade=case.grade or config.grade,
                      gnss=GnssConfig(latency_s=float(config.gnss_latency_s)),
                      faults=() if fault is None else (fault,), seed=case.sim_seed)
    return simulate3d(cfg)


def decision(post: dict) -> dict:
    """The compact record of a ``post_flight`` section: verdict, isolation, the isolated fault's
    sensor / axis / kind / onset / magnitude (SI) and the candidates of an ambiguous result."""
    def brief(f: dict) -> dict:
        return {k: f.get(k) for k in ("sensor", "axis", "kind", "onset_s", "magnitude")}

    fault = post.get("fault")
    out = {"verdict": post["verdict"], "isolation": post.get("isolation", "none"),
           "ambiguity_resolved_s": post.get("ambiguity_resolved_s"),
           "element": post.get("element"),
           "sensor": None, "axis": None, "kind": None, "onset_s": None, "magnitude": None,
           "statistic": None, "threshold": None,
           "candidates": [brief(c) for c in post.get("candidates") or []]}
    if fault:
        out.update(brief(fault))
        out["onset_interval_s"] = fault.get("onset_interval_s")
        out["statistic"], out["threshold"] = fault.get("statistic"), fault.get("threshold")
    glr = post.get("glr") or {}
    if out["statistic"] is None and "statistic" in glr:
        out["statistic"], out["threshold"] = glr.get("statistic"), glr.get("threshold")
    out["glr_max"] = glr_max_by_kind(glr.get("statistics") or {})
    return out


def glr_max_by_kind(statistics: Mapping[str, float]) -> dict[str, float]:
    """The largest GLR statistic per hypothesis kind (the name's last part: ``gyro_x_step`` ->
    step) -- what a nominal flight's maxima are compared with (the thresholds, per kind)."""
    out: dict[str, float] = {}
    for name, st in statistics.items():
        kind = name.rsplit("_", 1)[-1]
        out[kind] = max(out.get(kind, -math.inf), float(st))
    return out


def ins3d_post_flight(flight, config: Study3DConfig, grade: Any) -> tuple[dict, dict]:
    """(post_flight section, in-flight alarm count) of the 3-D analysis of one flight."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d

    inp = from_flight(flight)
    an = analyze_ins3d(inp.steps, inp.refs, grade=grade, rows=config.rows,
                       gate=config.analysis.gate, with_observability=False, **inp.vertical())
    return an.post_flight_dict(), {"alarms": len(an.summary()["alarms_raised_s"])}


def single_axis_channels(flight, config: Study3DConfig) -> dict[str, dict]:
    """The single-axis analysis (``ins_channel``, the defaults of ``flight-fdi analyze``) of the
    flight's east and north channels: INS velocity at the bag's 20 Hz, GNSS velocity with its
    published variance. Channel name -> ``post_flight`` section."""
    from flight_fdi.core.analysis import run_analysis
    from flight_fdi.core.models import get_model

    model = get_model("ins_channel")
    t = flight.t
    every = max(1, int(round(flight.config.trajectory.rate_hz / 20.0)))
    iv = np.arange(0, t.size, every)
    g = flight.gnss
    var = np.broadcast_to(g.vel_var, g.v.shape)
    out = {}
    for a, name in enumerate(("east", "north")):
        res = run_analysis(model, t[iv], flight.ins.v[iv, a], g.t, g.v[:, a], var[:, a],
                           config=config.analysis, channel=name, t0=0.0)
        out[name] = res.summary["post_flight"]
    return out


def combine_channels(per_channel: dict[str, dict]) -> dict:
    """One flight result from per-channel decisions: no fault when no channel declared one,
    else the declaring channel whose GLR statistic is the largest multiple of its threshold."""
    best, score = None, -math.inf
    for name, d in per_channel.items():
        if d["verdict"] not in DECLARED:
            continue
        st, thr = d.get("statistic"), d.get("threshold")
        s = (st / thr) if st is not None and thr else 0.0
        if s > score:
            best, score = name, s
    if best is None:
        first = next(iter(per_channel.values()))
        return {**first, "channel": None}
    return {**per_channel[best], "channel": best}


def turn_facts(flight, t_s: float | None) -> tuple[bool | None, float | None]:
    """(the aircraft is banked more than TURN_BANK_DEG at ``t_s``, the time of the first turn
    entry after ``t_s`` or None) from the simulator's truth."""
    if t_s is None:
        return None, None
    tr = flight.truth
    banked = np.abs(np.degrees(tr.controls["bank"])) > TURN_BANK_DEG
    k = min(int(round(t_s / tr.dt)), tr.t.size - 1)
    entries = np.flatnonzero(~banked[k:-1] & banked[k + 1:])
    nxt = None if entries.size == 0 else float(tr.t[k + 1 + entries[0]])
    return bool(banked[k]), nxt


def run_case(case: Case3D, config: Study3DConfig) -> dict:
    """Simulate and analyse one flight; a small JSON-able record."""
    flight = simulate_case(case, config)
    grade = case.grade or config.grade
    post, extra = ins3d_post_flight(flight, config, grade)
    in_turn, next_turn = turn_facts(flight, case.onset_s)
    rec = {"index": case.index, "scenario": case.scenario, "grade": grade_name(grade),
           "sim_seed": case.sim_seed, "traj_seed": case.traj_seed,
           "sensor": case.sensor, "axis": case.axis, "kind": case.kind, "level": case.level,
           "unit": None if case.sensor is None else SCENARIOS[case.scenario][5],
           "magnitude": case.magnitude, "onset_s": case.onset_s,
           "onset_in_turn": in_turn, "next_turn_s": next_turn,
           "ins3d": {**decision(post), **extra,   # every hypothesis' largest GLR (re-deciding)
                     "glr_statistics": dict((post.get("glr") or {}).get("statistics") or {})}}
    if config.single_axis:
        chans = {k: decision(v) for k, v in single_axis_channels(flight, config).items()}
        rec["single_axis"] = {**combine_channels(chans), "channels": chans}
    return rec


def _run_pair(args: tuple[Case3D, Study3DConfig]) -> dict:
    return run_case(*args)


# --------------------------------------------------------------------------- a study

@dataclass
class Study3DResult:
    config: Study3DConfig
    records: list[dict]
    metrics: dict
    elapsed_s: float
    jobs: int
    engine: str = ""
    ladder: dict | None = None
    resumed: int = 0  # records taken from an earlier, interrupted run (not run again)

    def to_dict(self, with_records: bool = True) -> dict:
        d = {"model": "ins3d", "config": self.config.describe(), "jobs": self.jobs,
             "engine": self.engine, "elapsed_s": self.elapsed_s, "resumed": self.resumed,
             "metrics": self.metrics}
        if self.ladder is not None:
            d["ladder"] = self.ladder
        if with_records:
            d["flights"] = self.records
        return d


def run_cases(cases: list[Case3D], config: Study3DConfig, jobs: int = 1, progress: bool = False,
              on_record: Callable[[dict], None] | None = None, scheduler: str | None = None,
              info: dict | None = None, desc: str = "montecarlo ins3d") -> list[dict]:
    """Records of ``cases`` in case order, run on the campaign engine."""
    from .montecarlo import parallel_map

    if not cases:
        return []
    recs = parallel_map(_run_pair, [(c, config) for c in cases], jobs, progress, desc=desc,
                        on_result=on_record, scheduler=scheduler, info=info)
    return sorted(recs, key=lambda r: r["index"])


def study_settings(config: Study3DConfig) -> dict:
    """The settings a records file of this study holds in its header (``--records``): the
    model, then :meth:`Study3DConfig.describe`."""
    return {"model": "ins3d", **config.describe()}


def run_study(config: Study3DConfig, jobs: int = 1, progress: bool = False,
              on_record: Callable[[dict], None] | None = None,
              scheduler: str | None = None,
              done: Mapping[int, dict] | None = None) -> Study3DResult:
    """Every flight of the study on the campaign engine, then the metrics. ``on_record``: called
    with each new record as it arrives (e.g. to stream it to disk); ``done``: records of this
    study already made, by flight index (a resumed study,
    :class:`~flight_fdi.eval.records.RecordsFile`): those flights are not run again."""
    from .metrics3d import summarize
    from .records import recorded_flights

    if not isinstance(config, Study3DConfig):
        raise EvalError(f"run_study: config must be a Study3DConfig, got {type(config).__name__}")
    start = time.perf_counter()
    cases = plan_study(config)
    kept = recorded_flights(done or {}, {
        c.index: {"scenario": c.scenario, "sim_seed": c.sim_seed, "traj_seed": c.traj_seed}
        for c in cases})
    info: dict = {}
    records = run_cases([c for c in cases if c.index not in kept], config, jobs, progress,
                        on_record, scheduler, info)
    records = sorted(records + list(kept.values()), key=lambda r: r["index"])
    return Study3DResult(config, records, summarize(records), time.perf_counter() - start,
                         info.get("workers", 1), info.get("engine", ""), resumed=len(kept))


__all__ = ["Case3D", "DEFAULT_LEVELS", "SCENARIOS", "Study3DConfig", "Study3DResult",
           "combine_channels", "decision", "glr_max_by_kind", "plan_study", "run_case",
           "grade_name", "run_cases", "run_study", "study_grade", "study_settings"]
