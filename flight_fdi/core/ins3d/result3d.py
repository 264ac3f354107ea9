"""The ``post_flight`` section of the result (``flight_fdi/schema/result-v1.schema.json``) for the
ins3d model, in the single-axis form (``core.result``: the same fault record, engineering units
and headline), plus ``ambiguity_resolved_s``.

Verdict: a single step / ramp / jump -> ``failure`` with ``fault``; outliers only -> ``glitch``;
ambiguous -> ``ambiguous`` with both ``candidates`` and ``fault`` null; no GLR detection -> the
seed method's verdict (as the single-axis analysis), no sensor named.

Turn-on biases (``turn_on``: a bias step best at the flight's first update, not an in-flight
event) are the added ``turn_on_bias`` list and part of the headline; the verdict, ``fault`` and
``glr`` are then the in-flight decision given them (``glr.given_turn_on``). A turn-on bias alone
keeps the seed method's verdict (normally ``no_fault``: "no in-flight fault; accelerometer y
turn-on bias of ...").
"""
from __future__ import annotations

from ..diagnosis import SeedDiagnosis
from ..result import ENGINEERING, _num, describe
from .glr3d import GlrCurve, Isolation, threshold_of
from .turn_on import describe_turn_on


def _rel(x: float | None, t0: float) -> float | None:
    return None if x is None else _num(x - t0)


#: likelihood drop of the onset interval per sensor and kind (the profile likelihood's chi^2(1)
#: 95 % value 3.84, widened where the Monte Carlo showed it too narrow); per reported
#: hypothesis the smallest drop of (3.84, 6, 8, 10, 12, 15, ...) whose interval (kind profiled
#: out: ``onset_interval``) covered the true onset in >= 95 % of the right isolations of each
#: fault type reported as it. tools/ins3d_onset_calibrate.py (docs/ins3d_eval.md, "Onset
#: intervals"): 1200-s cruise_turns, seed 7 (45 flights per scenario) and seed 33 (60
#: accelerometer steps, 60 gyro ramps); 7200-s random, seed 9 (72 gyro ramps). Accelerometer
#: step reports 6.0 (step faults 44/45 + 59/60 + 30/30 of the first calibration = 133/135;
#: ramp faults 6/7), accelerometer ramp reports 10.0 (24/26 at 6, 26/26 at 10), gyro step
#: reports 6.0 (step faults 23/24 at 3.84, 24/24 at 6; ramp faults 11/13 + 11/15 at 3.84,
#: 13/13 + 14/15 at 6), gyro ramp reports 15.0 (pooled 74/77 = 96 %: 2-h 61/64, 20-min 6/6 +
#: 7/7; at 12: 72/77 = 94 %; the first value, 3.84 from 27 reports, covered 23/30 on the 2-h
#: evaluation flights); GNSS jumps: onset exact. First calibration (steps only, without the
#: kind profiled out): accelerometer 6.0, gyro 3.84.
ONSET_DROP: dict = {"accelerometer": 6.0, "gyro": 6.0, "reference": 3.84,
                    ("accelerometer", "step"): 6.0, ("accelerometer", "ramp"): 10.0,
                    ("gyro", "step"): 6.0, ("gyro", "ramp"): 15.0}


def onset_drop(sensor: str, kind: str) -> float:
    """The calibrated drop of a hypothesis: ``ONSET_DROP[(sensor, kind)]``, else the sensor's,
    else 3.84."""
    return ONSET_DROP.get((sensor, kind), ONSET_DROP.get(sensor, 3.84))


def _region(c: GlrCurve, level: float) -> tuple[float, float] | None:
    """The onsets around the curve's peak whose GLR is >= ``level`` (None: its peak is below)."""
    k = c.best
    if k < 0 or c.stat[k] < level:
        return None
    ok = c.stat >= level
    a, b = k, k
    while a > 0 and ok[a - 1]:
        a -= 1
    while b < ok.size - 1 and ok[b + 1]:
        b += 1
    return float(c.t[a]), float(c.t[b])


def onset_interval(c: GlrCurve, cv: dict[str, GlrCurve] | None = None,
                   drop: float | None = None) -> tuple[float, float] | None:
    """The onset interval of a curve: the onsets whose GLR is within ``drop`` (default the
    calibrated ``ONSET_DROP``) of its peak. With the curves ``cv``, a step or ramp's interval
    also takes in the onsets where the *other* kind of the same sensor and axis is within the
    drop of that peak (profile likelihood over the onset with the kind profiled out: a ramp
    fitted as a step puts the step's onset late, and the ramp's onsets are then nearly as
    likely -- tools/ins3d_onset_calibrate.py)."""
    h = c.hypothesis
    d = onset_drop(h.sensor, h.kind) if drop is None else drop
    iv = _region(c, c.statistic - d)
    if iv is None or cv is None or h.kind not in ("step", "ramp"):
        return iv
    for o in cv.values():
        g = o.hypothesis
        if g.kind in ("step", "ramp") and g.kind != h.kind and (g.sensor, g.axis) == (
                h.sensor, h.axis):
            w = _region(o, c.statistic - d)
            if w is not None:
                iv = (min(iv[0], w[0]), max(iv[1], w[1]))
    return iv


def fault_record(cv: dict[str, GlrCurve], name: str, thresholds: dict[str, float], t0: float,
                 runner_up: str | None, outliers: int = 0, exact=None) -> dict:
    """One fault (``$defs/fault``): magnitude signed as the sensor's error (a reference jumping
    by +d reads +d, although the offset of z = v_INS - v_ref is -d). ``exact``: the hypothesis'
    ``nonlinear.Fit`` (onset and magnitude from it, no onset interval)."""
    c = cv[name]
    h = c.hypothesis
    k = c.best
    sign = -1.0 if h.sensor == "reference" else 1.0
    mag = sign * float(c.mag[k])
    unit_eng, factor = ENGINEERING.get((h.sensor, h.kind), (h.unit, 1.0))
    onset, end, count = float(c.t[k]), None, None
    interval = onset_interval(c, cv)
    if exact is not None:
        onset, mag, interval = exact.onset, exact.magnitude, None
    if h.kind == "outliers":
        above = c.t[c.stat > thresholds["outliers"]]
        count = max(int(above.size), 1)
        if above.size:
            onset, end = float(above.min()), float(above.max())
        else:
            end = onset
        interval = None
    return {
        "sensor": h.sensor, "axis": h.axis, "kind": h.kind, "hypothesis": name,
        "onset_s": _rel(onset, t0),
        "onset_interval_s": None if interval is None else [_rel(interval[0], t0),
                                                           _rel(interval[1], t0)],
        "end_s": _rel(end, t0), "count": count if h.kind == "outliers" else None,
        "magnitude": _num(mag), "unit": h.unit,
        "magnitude_eng": _num(mag * factor), "unit_eng": unit_eng,
        "magnitude_std": _num(c.sd[k]),
        "statistic": float(c.statistic), "threshold": threshold_of(thresholds, h),
        "runner_up": None if runner_up is None else {
            "hypothesis": runner_up, "statistic": float(cv[runner_up].statistic)},
    }


def _top(cv: dict[str, GlrCurve], iso: Isolation) -> str:
    if iso.best is not None:
        return iso.best
    return max((c for c in cv.values() if c.hypothesis.kind != "outliers"),
               key=lambda c: c.statistic).hypothesis.name


def _decision(cv, iso: Isolation, seed: SeedDiagnosis, thresholds, t0, check=None) -> dict:
    if seed.verdict == "insufficient_data":
        return {"verdict": "insufficient_data", "fault": None, "candidates": [],
                "headline": "insufficient data for the analysis", "element": None,
                "onset_s": None, "magnitude": None}
    if iso.isolation == "single":
        f = fault_record(cv, iso.best, thresholds, t0, iso.rival, iso.outliers,
                         check and check.fit_of(iso.best))
        head = describe(f)
        if iso.reason == "nonlinear":
            head += (" (beyond the small-angle model: removed exactly, it explains the flight "
                     "best)")
        if iso.ambiguity_resolved_s is not None and iso.rival is not None:
            head += (f" (told from {cv[iso.rival].hypothesis.sensor} "
                     f"{cv[iso.rival].hypothesis.axis} from {iso.ambiguity_resolved_s - t0:.0f} s)")
        return {"verdict": "glitch" if f["kind"] == "outliers" else "failure", "fault": f,
                "candidates": [], "headline": head, "element": cv[iso.best].hypothesis.element,
                "onset_s": f["onset_s"], "magnitude": f["magnitude"]}
    if iso.isolation == "ambiguous":
        cands = [fault_record(cv, iso.best, thresholds, t0, iso.rival, 0,
                              check and check.fit_of(iso.best)),
                 fault_record(cv, iso.rival, thresholds, t0, iso.best, 0,
                              check and check.fit_of(iso.rival))]
        head = "ambiguous: " + " or ".join(describe(c) for c in cands) + _why(iso, cands)
        return {"verdict": "ambiguous", "fault": None, "candidates": cands, "headline": head,
                "element": None, "onset_s": None, "magnitude": None}
    verdict = seed.verdict
    head = ("no fault" if verdict == "no_fault" else
            f"{verdict} in the seed method (element {seed.element}); GLR finds no fault above "
            "its threshold, so no sensor is named")
    return {"verdict": verdict, "fault": None, "candidates": [], "headline": head,
            "element": seed.element, "onset_s": _rel(seed.onset_t, t0), "magnitude": None}


def _why(iso: Isolation, cands: list[dict]) -> str:
    """Why two candidates are ambiguous (``glr3d`` module docstring)."""
    a, b = (c["statistic"] for c in cands)
    if iso.reason == "nonlinear":
        return (" (beyond the small-angle model: each removed exactly, they explain the flight "
                "alike within what the model's error allows)")
    if iso.reason == "attitude":
        return (" (the INS's errors are beyond what the linearised model holds, even "
                "relinearised: no sensor is named with confidence; post_flight.model_validity)")
    if iso.reason == "model":
        return (f" (statistics {a:.4g} and {b:.4g}, signatures alike to cos "
                f"{iso.similarity:.3f}: the gap is within what the model's error allows)")
    return (f" (statistics {a:.4g} and {b:.4g}, within the margin: the flight does not "
            "separate them, e.g. a straight leg without a turn)")


def _disagreement(seed: SeedDiagnosis, glr_element: str | None, top: GlrCurve,
                  threshold: float) -> str | None:
    if seed.element == glr_element:
        return None
    if seed.element is None:
        return (f"the seed method finds no lasting chi-square episode, GLR's "
                f"{top.hypothesis.name} is above its threshold: GLR tests the fault's shape")
    if glr_element is None:
        return (f"the seed method flags {seed.element}, GLR finds no fault above its threshold "
                f"({top.statistic:.4g} <= {threshold:.4g}): a short or unmodelled "
                "disturbance, not a sensor fault GLR can name")
    return (f"the seed method's UDU^T split names {seed.element}, the first element of its "
            f"order whose term exceeds the bound; GLR compares the fault shapes and names "
            f"{glr_element}")


def post_flight(cv: dict[str, GlrCurve], iso: Isolation, seed: SeedDiagnosis,
                thresholds: dict[str, float], t0: float = 0.0,
                turn_on: list[dict] | None = None, nonlinear=None) -> dict:
    """The ``post_flight`` dict (times relative to ``t0``); ``turn_on``: the turn-on biases
    (``turn_on.TurnOn.records``; ``cv`` and ``iso`` then the decision given them), added as
    ``turn_on_bias`` and to the headline (no in-flight fault: "no in-flight fault; ...")."""
    dec = _decision(cv, iso, seed, thresholds, t0, nonlinear)
    if turn_on:
        told = "; ".join(describe_turn_on(r) for r in turn_on)
        if iso.isolation == "none" and dec["verdict"] not in ("no_fault", "insufficient_data"):
            dec["headline"] = (f"{dec['verdict']} in the seed method (element {seed.element}); "
                               "GLR finds no in-flight fault above its threshold given the "
                               "turn-on bias, so no in-flight sensor is named")
        dec["headline"] = (f"no in-flight fault; {told}" if dec["verdict"] == "no_fault" else
                           f"{dec['headline']}; {told}")
    top = cv[_top(cv, iso)]
    glr_elem = top.hypothesis.element if iso.isolation == "single" else None
    interval = onset_interval(top, cv)
    k = top.best
    return {
        "verdict": dec["verdict"], "headline": dec["headline"], "fault": dec["fault"],
        "candidates": dec["candidates"], "isolation": iso.isolation,
        "element": dec["element"], "onset_s": dec["onset_s"], "magnitude": dec["magnitude"],
        "methods_agree": bool(seed.element == glr_elem),
        "disagreement": _disagreement(seed, glr_elem, top,
                                      threshold_of(thresholds, top.hypothesis)),
        "ambiguity_resolved_s": _rel(iso.ambiguity_resolved_s, t0),
        "turn_on_bias": list(turn_on or []),
        "nonlinear": None if nonlinear is None else nonlinear.record(t0),
        "seed_method": {
            "verdict": seed.verdict, "element": seed.element,
            "onset_s": _rel(seed.onset_t, t0),
            "elements": [{"name": e.name, "J_peak": _num(e.J_peak), "gamma2": _num(e.gamma2),
                          "F_peak": _num(e.F_peak), "eta2": _num(e.eta2),
                          "exceed_fraction": float(e.exceed_fraction), "dof": int(e.dof)}
                         for e in seed.elements]},
        "glr": {
            "hypothesis": top.hypothesis.name,
            "onset_s": _rel(float(top.t[k]), t0),
            "onset_interval_s": None if interval is None else [_rel(interval[0], t0),
                                                               _rel(interval[1], t0)],
            "magnitude": _num(top.mag[k]), "unit": top.hypothesis.unit,
            "statistic": float(top.statistic),
            "threshold": threshold_of(thresholds, top.hypothesis),
            "isolation": iso.isolation, "runner_up": iso.rival,
            "runner_up_statistic": float(cv[iso.rival].statistic) if iso.rival else 0.0,
            "runner_up_gain": _num(iso.rival_gain), "signature_similarity": _num(iso.similarity),
            "residual": None,
            "statistics": {n: float(c.statistic) for n, c in cv.items()},
            "thresholds": {k_: float(v) for k_, v in thresholds.items()},
            "outliers_above_threshold": int(iso.outliers),
            "given_turn_on": [r["hypothesis"] for r in turn_on or []],
            "ambiguity_resolved_s": _rel(iso.ambiguity_resolved_s, t0)},
    }


__all__ = ["fault_record", "post_flight"]

