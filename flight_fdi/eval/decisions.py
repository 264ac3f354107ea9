"""What each detector and isolation method decided on one flight of a Monte Carlo study (a record
of :func:`flight_fdi.eval.montecarlo.run_case`), the study's classes and units, and the small
statistics and number formats its metrics and reports share."""
from __future__ import annotations

from typing import Iterable

import numpy as np

from flight_fdi.core.models import DEG_PER_HOUR, G0

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
ISOLATION_LEVEL = 0.95
#: the class GLR gives a flight whose best hypothesis is not a confident single explanation
AMBIGUOUS = "ambiguous"


def glr_class(hypothesis: str) -> str:
    """The class a GLR hypothesis isolates: the stepped state for ``<state>_step`` /
    ``step:<state>``, the hypothesis name itself otherwise (``none``, ``accel_bias_ramp``,
    ``reference_jump``...)."""
    if hypothesis.startswith("step:"):
        return hypothesis[5:]
    if hypothesis.endswith("_step"):
        return hypothesis[:-5]
    return hypothesis


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


# --------------------------------------------------------------------------- statistics

def stats_of(values: Iterable[float]) -> dict:
    v = np.asarray([x for x in values if x is not None], dtype=float)
    if v.size == 0:
        return {"n": 0, "mean": None, "std": None, "median": None, "p05": None, "p95": None,
                "min": None, "max": None}
    return {"n": int(v.size), "mean": float(v.mean()), "std": float(v.std()),
            "median": float(np.median(v)), "p05": float(np.percentile(v, 5)),
            "p95": float(np.percentile(v, 95)), "min": float(v.min()), "max": float(v.max())}


def diff_or_none(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def rate_of(num: int, den: int) -> float | None:
    return num / den if den else None


def fmt_pct(x: float | None) -> str:
    return "-" if x is None else f"{100 * x:.1f}%"


def fmt_num(x: float | None, spec: str = ".3g") -> str:
    return "-" if x is None else format(x, spec)
