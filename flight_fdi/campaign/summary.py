"""One summary row per flight, from its result JSON (what ``flight-fdi analyze --json`` prints).

:func:`summary_row` reads both forms of the result:

* with ``post_flight.fault`` (the schema-versioned result: ``{sensor, axis, kind, onset_s,
  end_s, magnitude, unit, statistic, threshold, runner_up: {hypothesis, statistic}}`` or null)
  and drop counts per topic and reason (``input.<topic>.dropped.<reason>``);
* the earlier form: ``post_flight.element`` / ``onset_s`` / ``magnitude`` with ``channel`` as the
  axis, GLR's hypothesis for the kind, and ``input.dropped_unaligned``.

An ambiguous result (``fault`` null, ``post_flight.candidates`` listed) gives the candidates'
sensors, axes and kinds joined with '|' (e.g. ``gyro|accelerometer``, ``step|ramp``).

``confidence`` is how clearly the best GLR hypothesis beats the runner-up:
1 - runner_up.statistic / statistic (1: no rival, 0: a tie); the result's own ``confidence``
when it has one; empty when there is no fault or no runner-up (the earlier form has none).
"""
from __future__ import annotations

import math
from typing import Any

#: the summary table's columns, in order
COLUMNS = ("flight", "bag", "duration_s", "verdict", "sensor", "axis", "kind", "onset_s",
           "magnitude", "unit", "confidence", "dropped_samples", "error")

#: earlier results: the model state a fault acts on -> the sensor and the unit of its magnitude
_ELEMENT_SENSOR = {"accel_bias": ("accelerometer", "m/s^2"), "gyro_drift": ("gyro", "rad/s"),
                   "velocity_error": ("reference", "m/s")}
#: earlier results: GLR hypothesis -> (sensor, kind)
_HYPOTHESIS = {"accel_bias_step": ("accelerometer", "step"), "gyro_drift_step": ("gyro", "step"),
               "reference_jump": ("reference", "jump"),
               "reference_outlier": ("reference", "outliers")}


def _num(x: Any) -> float | None:
    if isinstance(x, bool) or not isinstance(x, (int, float)):
        return None
    return float(x) if math.isfinite(x) else None


def _dropped(inp: Any) -> int | None:
    """Input samples not used: the sum of every ``<topic>.dropped.<reason>`` count, or the
    earlier ``dropped_unaligned``."""
    if not isinstance(inp, dict):
        return None
    per_topic = [v["dropped"] for v in inp.values()
                 if isinstance(v, dict) and isinstance(v.get("dropped"), dict)]
    if per_topic:
        return int(sum(n for d in per_topic for n in d.values()
                       if isinstance(n, (int, float)) and not isinstance(n, bool)))
    n = inp.get("dropped_unaligned")
    return int(n) if isinstance(n, (int, float)) and not isinstance(n, bool) else None


def _confidence(fault: dict) -> float | None:
    own = _num(fault.get("confidence"))
    if own is not None:
        return own
    stat = _num(fault.get("statistic"))
    runner = fault.get("runner_up")
    rival = _num(runner.get("statistic")) if isinstance(runner, dict) else None
    if stat is None or rival is None or stat <= 0:
        return None
    return min(1.0, max(0.0, 1.0 - rival / stat))


def _ambiguous(candidates: Any) -> dict:
    """An ambiguous result (no single fault; its candidates named): the candidates' sensors,
    axes and kinds joined with '|', the onset and confidence of the best one, no magnitude
    (the candidates' magnitudes differ in kind and unit)."""
    cands = [c for c in candidates or [] if isinstance(c, dict)]
    if not cands:
        return {}

    def join(key: str) -> str | None:
        seen = list(dict.fromkeys(str(c[key]) for c in cands if c.get(key) is not None))
        return "|".join(seen) or None

    return {"sensor": join("sensor"), "axis": join("axis"), "kind": join("kind"),
            "onset_s": _num(cands[0].get("onset_s")), "confidence": _confidence(cands[0])}


def summary_row(flight: str, result: dict | None, error: str | None = None,
                bag: str | None = None) -> dict:
    """The summary row (keys :data:`COLUMNS`) of one flight's result; a row with only the
    error when the flight could not be analysed."""
    row: dict[str, Any] = dict.fromkeys(COLUMNS)
    row.update(flight=flight, bag=bag, error=error)
    if not isinstance(result, dict):
        return row
    post = result.get("post_flight") or {}
    row["bag"] = bag or result.get("bag")
    row["duration_s"] = _num(result.get("duration_s"))
    row["verdict"] = post.get("verdict")
    row["dropped_samples"] = _dropped(result.get("input"))
    if "fault" in post:  # the schema-versioned result
        fault = post["fault"]
        if isinstance(fault, dict):
            row.update(sensor=fault.get("sensor"), axis=fault.get("axis"),
                       kind=fault.get("kind"), onset_s=_num(fault.get("onset_s")),
                       magnitude=_num(fault.get("magnitude")), unit=fault.get("unit"),
                       confidence=_confidence(fault))
        else:
            row.update(_ambiguous(post.get("candidates")))
        return row
    element = post.get("element")
    if element is None:
        return row
    glr = post.get("glr") or {}
    sensor, unit = _ELEMENT_SENSOR.get(element, (element, None))
    g_sensor, kind = _HYPOTHESIS.get(glr.get("hypothesis"), (None, None))
    row.update(sensor=sensor, axis=result.get("channel"),
               kind=kind if g_sensor == sensor else None, onset_s=_num(post.get("onset_s")),
               magnitude=_num(post.get("magnitude")),
               unit=unit if post.get("magnitude") is not None else None)
    return row
