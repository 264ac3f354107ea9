"""The metrics of a Monte Carlo study from its per-flight records (the records of
:func:`flight_fdi.eval.montecarlo.run_case`; the metrics are described in that module's
docstring): type I / II errors, confusion matrices, statistics of delays and errors, rates per
magnitude level. Pure functions of the records."""
from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from .decisions import (AMBIGUOUS, DETECTORS, FAULT_KINDS, ISOLATION_LEVEL, KINDS, LEVEL_UNITS,
                        METHODS, declared, diff_or_none, isolated, predicted_class, rate_of,
                        stats_of)
from .onset import onset_errors


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
            row[f"{det}_detected"] = rate_of(sum(declared(r, det) for r in rs), n)
        for m in METHODS:
            row[f"{m}_isolated"] = rate_of(sum(isolated(r, m) for r in rs), n)
        delays = [r["first_alarm_after_onset_s"] - r["onset_s"] for r in rs
                  if r["first_alarm_after_onset_s"] is not None]
        row["delay_median_s"] = stats_of(delays)["median"]
        ok = [r for r in rs if isolated(r, "glr")]
        row["glr_onset_error_median_s"] = stats_of(
            abs(r["glr"]["onset_s"] - r["onset_s"]) for r in ok)["median"]
        row["glr_magnitude_error_median"] = stats_of(
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
                "per_sample_exceed_rate": rate_of(sum(r["exceeded"] for r in nominal), n_samples),
                "per_flight_rate": rate_of(sum(bool(r["alarms"]) for r in nominal), len(nominal)),
                "flights_with_alarm": sum(bool(r["alarms"]) for r in nominal),
                "faulty_flights_alarm_before_onset": sum(r["false_alarms"] > 0 for r in faulty),
            },
            "seed": {
                "per_sample_J_exceed_rate": rate_of(sum(r["seed"]["J_exceeded"] for r in nominal),
                                                  n_valid),
                "per_flight_rate": rate_of(sum(declared(r, "seed") for r in nominal),
                                         len(nominal)),
            },
            "glr": {"per_flight_rate": rate_of(sum(declared(r, "glr") for r in nominal),
                                             len(nominal))},
        },
        "error_rates": {det: error_rates(records, det) for det in DETECTORS},
        "missed_detections": {det: {k: sum(not declared(r, det) for r in faulty
                                           if r["kind"] == k) for k in kinds}
                              for det in DETECTORS},
        "detection_delay_s": {k: stats_of(r["first_alarm_after_onset_s"] - r["onset_s"]
                                        for r in faulty if r["kind"] == k
                                        and r["first_alarm_after_onset_s"] is not None)
                              for k in kinds},
        "confusion": {m: confusion_matrix(records, m) for m in METHODS},
        "onset_error_s": {m: {k: stats_of(diff_or_none(r[m]["onset_s"], r["onset_s"])
                                          for r in faulty if r["kind"] == k and isolated(r, m))
                              for k in kinds} for m in METHODS},
        "onset_error_detected_s": {m: {k: stats_of(diff_or_none(r[m]["onset_s"], r["onset_s"])
                                                 for r in faulty
                                                 if r["kind"] == k and declared(r, m))
                                       for k in kinds} for m in METHODS},
        "magnitude_error_relative": {"glr": {k: stats_of(r["glr"]["magnitude"] / r["magnitude"]
                                                       - 1.0 for r in faulty
                                                       if r["kind"] == k and isolated(r, "glr"))
                                             for k in kinds}},
        "by_level": {k: by_level(records, k) for k in kinds},
        "onset_error_glr": onset_errors(records),
    }
    out["smallest_isolated_95"] = {
        m: {k: {"level": smallest_isolated(out["by_level"][k], m), "unit": LEVEL_UNITS[k][0]}
            for k in kinds} for m in METHODS}
    return out

