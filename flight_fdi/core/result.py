"""The post-flight result a person can act on: which sensor, which axis, what kind of fault,
when, how large (SI and the engineer's unit), how sure -- built in ONE place for every output
(``flight-fdi analyze --json``, ``run --json``, result.json, the smoother node).

:func:`post_flight` turns the two methods' outcomes into the ``post_flight`` part of the
result (schema: ``flight_fdi/schema/result-v1.schema.json``); :func:`headline` is its one-line
text ("accelerometer x: bias step of +1.47 mg (0.0147 m/s^2) at 499.5 s").

Isolation (GLR, :mod:`.glr`): ``single`` -> verdict ``failure`` (``glitch`` for outliers) and a
``fault``; ``ambiguous`` (two sensors within the margin) or ``unexplained`` (the best hypothesis
leaves a fault behind) -> verdict ``ambiguous``, ``fault`` null and the ``candidates`` named;
``none`` -> the seed method's verdict, ``fault`` null.
"""
from __future__ import annotations

import math
from typing import Any

from .glr import GlrResult, kind_of, rank_hypotheses, sensor_of

SCHEMA_ID = "flight-fdi/result/v1"

G0 = 9.80665
RAD_S_TO_DEG_H = 180.0 / math.pi * 3600.0
#: (sensor, kind) -> (engineering unit, factor from SI)
ENGINEERING = {
    ("accelerometer", "step"): ("mg", 1e3 / G0),
    ("accelerometer", "ramp"): ("mg/h", 3600.0 * 1e3 / G0),
    ("gyro", "step"): ("deg/h", RAD_S_TO_DEG_H),
    ("gyro", "ramp"): ("deg/h^2", 3600.0 * RAD_S_TO_DEG_H),
    ("reference", "jump"): ("m/s", 1.0),
    ("reference", "outliers"): ("m/s", 1.0),
}
_WHAT = {("accelerometer", "step"): "bias step", ("accelerometer", "ramp"): "bias ramp",
         ("gyro", "step"): "drift step", ("gyro", "ramp"): "drift ramp",
         ("reference", "jump"): "jump", ("reference", "outliers"): "outlier"}


def _num(x: Any) -> float | None:
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def fault_record(glr: GlrResult, hypothesis: str, t0: float, axis: str,
                 end_s: float | None = None, runner_up: str | None = None) -> dict:
    """``post_flight.fault`` (or one of ``candidates``) for one GLR hypothesis.

    magnitude: SI, signed as the *sensor's* error (a reference that jumps by +d reads +d,
    although GLR's offset of z = V_INS - V_ref is -d); magnitude_eng in unit_eng (mg, deg/h,
    mg/h, deg/h^2); magnitude_std its 1-sigma; onset_interval_s the profile-likelihood 95 %
    interval of the onset. end_s: the last outlier; null for a step, ramp or jump (the
    hypothesis: it lasts to the end of the record)."""
    h = glr.per_hypothesis[hypothesis]
    sensor, kind = sensor_of(hypothesis), kind_of(hypothesis)
    sign = -1.0 if sensor == "reference" else 1.0
    mag = None if h["magnitude"] is None else sign * float(h["magnitude"])
    unit_eng, factor = ENGINEERING.get((sensor, kind), (h["unit"], 1.0))
    onset = None if h["onset_t"] is None else h["onset_t"] - t0
    interval = h.get("onset_interval")
    if runner_up is None:
        # (ties -- same signature, statistics equal to rounding -- keep the declared order)
        runner_up = next((o for o in rank_hypotheses(glr.per_hypothesis) if o != hypothesis),
                         None)
    count = h.get("count")
    if kind == "outliers" and h.get("times"):  # first to last outlier above the threshold
        onset, end_s = min(h["times"]) - t0, max(h["times"]) - t0
    elif kind == "outliers":
        end_s = onset
    else:
        end_s = None
    return {
        "sensor": sensor, "axis": axis, "kind": kind, "hypothesis": hypothesis,
        "onset_s": _num(onset),
        "onset_interval_s": None if interval is None else [_num(interval[0] - t0),
                                                           _num(interval[1] - t0)],
        "end_s": _num(end_s), "count": count,
        "magnitude": _num(mag), "unit": h["unit"],
        "magnitude_eng": _num(None if mag is None else mag * factor), "unit_eng": unit_eng,
        "magnitude_std": _num(h["magnitude_std"]),
        "statistic": float(h["statistic"]), "threshold": float(glr.threshold),
        "runner_up": None if runner_up is None else {
            "hypothesis": runner_up,
            "statistic": float(glr.per_hypothesis[runner_up]["statistic"])},
    }


def _fmt_mag(x: float | None, unit: str) -> str:
    return "?" if x is None else f"{x:+.3g} {unit}"


def describe(fault: dict) -> str:
    """"accelerometer x: bias step of +1.47 mg (0.0147 m/s^2) at 499.5 s"."""
    what = _WHAT.get((fault["sensor"], fault["kind"]), f"{fault['kind']}")
    mag = _fmt_mag(fault["magnitude_eng"], fault["unit_eng"])
    if fault["unit_eng"] != fault["unit"] and fault["magnitude"] is not None:
        mag += f" ({fault['magnitude']:.3g} {fault['unit']})"
    when = "from" if fault["kind"] == "ramp" else "at"
    onset = "?" if fault["onset_s"] is None else f"{fault['onset_s']:.1f}"
    if fault["kind"] == "outliers" and (fault.get("count") or 0) > 1:
        return (f"{fault['sensor']} {fault['axis']}: {fault['count']} outliers from "
                f"{onset} s to {fault['end_s']:.1f} s, largest {mag}")
    return f"{fault['sensor']} {fault['axis']}: {what} of {mag} {when} {onset} s"


def post_flight(seed: Any, glr: GlrResult, t0: float, axis: str, seed_element_glr: str | None,
                end_s: float | None) -> dict:
    """The decision part of ``post_flight`` (verdict, fault, candidates, isolation, headline,
    disagreement); the caller adds the methods' details (``seed_method``, ``glr``)."""
    if seed.verdict == "insufficient_data":
        return {"verdict": "insufficient_data", "fault": None, "candidates": [],
                "isolation": "none", "headline": "insufficient data for the analysis",
                "disagreement": None}
    iso = glr.isolation if glr.detected else "none"
    fault, candidates = None, []
    if iso == "single":
        fault = fault_record(glr, glr.hypothesis, t0, axis, end_s)
        verdict = "glitch" if fault["kind"] == "outliers" else "failure"
        head = describe(fault)
    elif iso == "ambiguous":
        verdict = "ambiguous"
        candidates = [fault_record(glr, glr.hypothesis, t0, axis, end_s, glr.runner_up),
                      fault_record(glr, glr.runner_up, t0, axis, end_s, glr.hypothesis)]
        a, b = (c["statistic"] for c in candidates)
        why = ("identical velocity signatures: on one velocity channel a gyro drift step w and "
               "an accelerometer bias ramp of -g w make the same error" if abs(a - b) <= 1e-6 * a
               else f"statistics {a:.4g} and {b:.4g}, within the margin")
        head = "ambiguous: " + " or ".join(describe(c) for c in candidates) + f" ({why})"
    elif iso == "unexplained":
        verdict = "ambiguous"
        candidates = [fault_record(glr, glr.hypothesis, t0, axis, end_s)]
        r = glr.residual or {}
        at = "" if r.get("onset_t") is None else f" at {r['onset_t'] - t0:.1f} s"
        head = (f"unexplained: the best single fault, {describe(candidates[0])}, leaves a "
                f"{r.get('hypothesis')}{at} (statistic {r.get('statistic', 0.0):.4g} > "
                f"{glr.threshold:.4g}) unexplained: more than one fault, or one the "
                "hypotheses do not describe")
    else:
        verdict = seed.verdict
        head = ("no fault" if verdict == "no_fault" else
                f"{verdict} in the seed method (element {seed.element}); GLR finds no fault "
                f"above its threshold, so no sensor is named")
    return {"verdict": verdict, "fault": fault, "candidates": candidates, "isolation": iso,
            "headline": head,
            "disagreement": disagreement(seed, glr, seed_element_glr, iso)}


def disagreement(seed: Any, glr: GlrResult, glr_element: str | None, iso: str) -> str | None:
    """One line on why the seed method's element differs from GLR's, or None when they agree."""
    if seed.element == glr_element:
        return None
    if seed.element is None:
        return (f"the seed method finds no lasting chi-square episode (J within its bound), "
                f"GLR's {glr.hypothesis} is above its threshold: GLR tests the fault's shape "
                "and is the more sensitive of the two")
    if glr_element is None:
        return (f"the seed method flags {seed.element}, GLR finds no fault above its threshold "
                f"({glr.statistic:.4g} <= {glr.threshold:.4g}): a short or unmodelled "
                "disturbance, not a sensor fault GLR can name")
    return (f"the seed method's UDU^T split names {seed.element}, the first element of its "
            f"order whose term exceeds the bound (velocity, tilt and accelerometer bias are "
            f"barely separable from velocity alone); GLR compares the fault shapes and names "
            f"{glr_element}")
