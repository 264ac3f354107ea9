"""The result dict (``flight-fdi/result/v1`` with ``"model": "ins3d"``) of a 3-D analysis: what
``flight-fdi analyze --model ins3d --json``, ``run --model ins3d`` and the smoother node on an
ins3d recording write (one function for all of them).

``post_flight`` comes from the analysis' ``post_flight_dict()`` (the backward information filter,
two-filter chi-square and body-axis GLR of core/ins3d); an analysis run without its post-flight
part (``analyze_ins3d(..., post=False)``) gives the forward filter's in-flight verdict only,
marked ``"method": "forward_only"`` (no sensor is isolated: ``fault`` null, ``isolation`` none).
"""
from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np

from .records import ForwardResult
from .result import SCHEMA_ID

MODEL_NAME = "ins3d"
ROW_NAMES = ("east", "north", "up")


def _num(x: Any) -> float | None:
    return None if x is None or not math.isfinite(float(x)) else float(x)


def in_flight(fwd: Any, row_names: tuple[str, ...] = ROW_NAMES) -> dict:
    """The ``in_flight`` section of a forward pass (core.ins3d.filter.Ins3dForward; its rows
    named ``row_names``)."""
    alarms = ForwardResult.alarms(SimpleNamespace(t=fwd.t_ref, alarm_state=fwd.alarm,
                                                  beta2=fwd.beta2))
    rows = row_names[:fwd.beta2_row.shape[1]]
    return {
        "gate_threshold": float(fwd.threshold),
        "exceed_fraction": float(np.mean(fwd.exceeded)) if fwd.beta2.size else 0.0,
        "first_alarm_s": alarms[0]["start_s"] if alarms else None,
        "alarms": alarms,
        "row_gate_threshold": float(fwd.threshold_row),
        "row_exceed_fraction": {r: float(np.mean(fwd.exceeded_row[:, i]))
                                for i, r in enumerate(rows)} if fwd.beta2.size else {},
    }


def forward_only_post_flight(inf: dict) -> dict:
    """``post_flight`` when only the forward filter exists (see the module docstring)."""
    n = len(inf["alarms"])
    verdict = "failure" if n else "no_fault"
    head = ("forward filter only (no post-flight isolation): "
            + (f"{n} in-flight alarm(s), the first at {inf['first_alarm_s']:.1f} s" if n
               else "no in-flight alarm"))
    return {"verdict": verdict, "headline": head, "fault": None, "candidates": [],
            "isolation": "none", "element": None, "onset_s": inf["first_alarm_s"],
            "magnitude": None, "methods_agree": True, "disagreement": None,
            "method": "forward_only"}


def ins3d_result(analysis: Any, bag: str, source: dict | None = None) -> dict:
    """The whole result of one 3-D analysis (core.ins3d.analysis.Ins3dAnalysis)."""
    fwd = analysis.forward
    height = bool(getattr(analysis.model, "height_row", False))
    inf = in_flight(fwd, ("east", "north", "height") if height else ROW_NAMES)
    post = analysis.post_flight_dict() if getattr(analysis, "seed", None) is not None \
        else forward_only_post_flight(inf)
    rows = fwd.beta2_row.shape[1]
    res = {
        "schema": SCHEMA_ID,
        "model": MODEL_NAME,
        "bag": str(bag),
        "channel": "en_height" if height else "enu" if rows == 3 else "en",
        "duration_s": float(fwd.t[-1] - fwd.t[0]) if fwd.t.size else 0.0,
        "samples": int(fwd.beta2.size),
        "in_flight": inf,
        "post_flight": post,
        "ins3d": analysis.summary(),
    }
    if source is not None:
        res["source"] = source
    return res


def fault_line(res: dict) -> str:
    """One line naming the isolated sensor and axis (or why none is named), and the reference
    glitches found beside it (``post_flight.glitches``)."""
    post = res["post_flight"]
    f = post.get("fault")
    if f:
        line = (f"isolated: {f['sensor']} {f['axis']} {f['kind']}, "
                f"{f.get('magnitude_eng', f['magnitude']):+.4g} {f.get('unit_eng', f['unit'])} "
                f"at {f['onset_s']:.1f} s")
    elif post.get("candidates"):
        line = "ambiguous between " + " and ".join(f"{c['sensor']} {c['axis']} {c['kind']}"
                                                     for c in post["candidates"])
    else:
        line = f"no sensor isolated ({post['verdict']})"
    removed = post["verdict"] != "glitch"
    return line + "".join(glitch_text(g, removed) for g in post.get("glitches") or [])


def glitch_text(g: dict, removed: bool = True) -> str:
    """"; reference glitch: east, 1 update at 26.5 s (statistic 36.9 > 32), removed before the
    decision" (``removed``: the decision was taken on the rest of the flight)."""
    times = ", ".join(f"{t:.1f}" for t in g["times_s"][:5]) + (" ..." if g["count"] > 5 else "")
    return (f"; reference glitch: {g['axis']}, {g['count']} update{'s' * (g['count'] > 1)} at "
            f"{times} s (statistic {g['statistic']:.4g} > {g['threshold']:.4g})"
            + (", removed before the decision" if removed else ""))


__all__ = ["MODEL_NAME", "fault_line", "forward_only_post_flight", "glitch_text", "in_flight",
           "ins3d_result"]
