"""Monte Carlo of the attitude-axis actuator monitor (seed 003): type I / II errors and the
detection delay of the zero-control disturbance rule against thruster leaks.

Each flight is :func:`flight_fdi.sim.attitude.simulate_attitude` (three axes under on/off thruster
control) analysed on the faulty axis with :func:`flight_fdi.core.actuator.run_attitude`. A nominal
flight has no leak; a faulty one a leak of a magnitude from ``levels`` (random sign) starting at
a random time. The monitor *declares* a fault on a faulty flight when its event comes at or after
the onset (an earlier event is a false alarm).
"""
from __future__ import annotations

import math
import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from flight_fdi.core.actuator import ActuatorConfig, run_attitude
from flight_fdi.sim.attitude import ActuatorFault, AttitudeSimConfig, simulate_attitude

from .errors import EvalError
from .decisions import stats_of
from .montecarlo import parallel_map, type_errors

DEFAULT_LEAK_LEVELS = (5e-6, 1e-5, 1.5e-5, 2e-5, 5e-5)


@dataclass(frozen=True)
class AttitudeStudyConfig:
    """nominal / faulty: numbers of flights; levels: leak magnitudes (rad/s^2, spread evenly
    over the faulty flights); onset_window: onset uniform in [a, b] x duration_s."""

    nominal: int = 50
    faulty: int = 50
    levels: tuple = DEFAULT_LEAK_LEVELS
    duration_s: float = 1200.0
    onset_window: tuple = (0.25, 0.75)
    axis: str = "x"
    measure: str = "angle"
    seed: int = 0
    monitor: ActuatorConfig = field(default_factory=ActuatorConfig)

    def __post_init__(self) -> None:
        for name in ("nominal", "faulty", "seed"):
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, int) or v < 0:
                raise EvalError(f"AttitudeStudyConfig.{name} must be an integer >= 0, got {v!r}")
        levels = tuple(float(v) for v in self.levels)
        if self.faulty and (not levels or any(not math.isfinite(v) or v <= 0 for v in levels)):
            raise EvalError("AttitudeStudyConfig.levels must be positive leak torques (rad/s^2)")
        object.__setattr__(self, "levels", tuple(sorted(levels)))
        a, b = (float(v) for v in self.onset_window)
        if not 0.0 < a <= b < 1.0:
            raise EvalError("AttitudeStudyConfig.onset_window must satisfy 0 < a <= b < 1")
        object.__setattr__(self, "onset_window", (a, b))


def plan_attitude_study(config: AttitudeStudyConfig) -> list[dict]:
    rng = np.random.default_rng(np.random.SeedSequence(config.seed))
    cases = []
    for i in range(config.nominal + config.faulty):
        case = {"index": i, "sim_seed": int(rng.integers(0, 2**31 - 1)), "kind": "nominal",
                "level": None, "magnitude": None, "onset_s": None}
        if i >= config.nominal:
            level = config.levels[(i - config.nominal) % len(config.levels)]
            sign = 1.0 if rng.random() < 0.5 else -1.0
            lo, hi = config.onset_window
            case.update(kind="leak", level=level, magnitude=sign * level,
                        onset_s=round(float(rng.uniform(lo, hi)) * config.duration_s, 1))
        cases.append(case)
    return cases


def run_attitude_case(args: tuple[dict, AttitudeStudyConfig]) -> dict:
    case, config = args
    fault = None if case["kind"] == "nominal" else ActuatorFault(
        start_s=case["onset_s"], magnitude=case["magnitude"], axis=config.axis)
    flight = simulate_attitude(AttitudeSimConfig(duration_s=config.duration_s,
                                                 seed=case["sim_seed"], measure=config.measure,
                                                 fault=fault))
    t, z, u = flight.axis_data(config.axis)
    _, mon = run_attitude(flight.model, t, z, u, config=config.monitor, axis=config.axis)
    event_t = mon.events[0].t if mon.events else None
    onset = case["onset_s"]
    return {**case, "event_t": event_t,
            "declared": event_t is not None and (onset is None or event_t >= onset),
            "false_alarm": event_t is not None and (onset is None or event_t < onset),
            "delay_s": None if event_t is None or onset is None or event_t < onset
            else event_t - onset,
            "max_abs_mean": mon.summary()["max_abs_mean"]}


def summarize_attitude(records: list[dict]) -> dict:
    nominal = [r for r in records if r["kind"] == "nominal"]
    faulty = [r for r in records if r["kind"] != "nominal"]
    levels = sorted({r["level"] for r in faulty})
    return {
        "errors": type_errors([r["declared"] for r in nominal], [r["declared"] for r in faulty]),
        "nominal_max_abs_mean": stats_of(r["max_abs_mean"] for r in nominal),
        "delay_s": stats_of(r["delay_s"] for r in faulty),
        "by_level": [{"level": lv, "n": sum(r["level"] == lv for r in faulty),
                      "detected": float(np.mean([r["declared"] for r in faulty
                                                 if r["level"] == lv])),
                      "delay_median_s": stats_of(r["delay_s"] for r in faulty
                                                 if r["level"] == lv)["median"]}
                     for lv in levels],
    }


def run_attitude_study(config: AttitudeStudyConfig, jobs: int = 1,
                       progress: bool = False) -> dict:
    """Run the study; returns {"config", "elapsed_s", "metrics", "flights"}."""
    cases = plan_attitude_study(config)
    start = time.perf_counter()
    records = parallel_map(run_attitude_case, [(c, config) for c in cases], jobs, progress,
                           desc="attitude")
    records.sort(key=lambda r: r["index"])
    cfg: dict[str, Any] = asdict(config)
    cfg["onset_window"] = list(config.onset_window)
    return {"config": cfg, "elapsed_s": time.perf_counter() - start,
            "metrics": summarize_attitude(records), "flights": records}
