"""Post-flight analysis of a recording of the filter node (no rclpy, no bag I/O).

A recording (``flight_fdi.bagio.recording.read_recording``) holds per channel the filter's
model description (ModelInfo) and one FilterState per reference sample. Here: the model rebuilt
from its description (:func:`model_from_info`), the measurement rows of one state
(:func:`measurement_of`, stacked redundant rows as their information-equivalent single row),
states missing from a recording bridged by prediction (:func:`bridge_gaps`), and the analysis
(:func:`analyze_recording`: the forward pass rebuilt with ``ForwardResult.from_record`` and the
same :func:`flight_fdi.core.analysis.analyze_forward` as ``flight-fdi analyze``), with the
result helpers the smoother node and the CLI share (:func:`error_result`, :func:`summary_line`,
:func:`write_json`).
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .errors import CoreError


def _mat(values: Any, rows: int, cols: int, what: str) -> np.ndarray:
    arr = np.asarray(values, dtype=float)
    if arr.size != rows * cols:
        raise CoreError(f"{what}: expected {rows} x {cols} = {rows * cols} values, got {arr.size}")
    return arr.reshape(rows, cols)


def model_from_info(msg: Any):
    """(LinearModel, GateConfig) from a flight_fdi_msgs/ModelInfo (rclpy or rosbags message);
    the inverse of ``convert.model_info_msg``. CoreError when the description is inconsistent."""
    from .kalman import GateConfig
    from .models import LinearModel

    n, m, p = int(msg.n), int(msg.m), int(msg.p)
    what = f"ModelInfo of channel {msg.channel!r}"
    names = [str(s) for s in msg.state_names]
    if len(names) != n:
        raise CoreError(f"{what}: n = {n} but {len(names)} state names")
    model = LinearModel(
        name=str(msg.model_name), state_names=tuple(names),
        state_units=tuple(str(s) for s in msg.state_units),
        A=_mat(msg.a, n, n, f"{what}: a"), Qc=_mat(msg.qc, n, n, f"{what}: qc"),
        H=_mat(msg.h, m, n, f"{what}: h"), R=_mat(msg.r, m, m, f"{what}: r"),
        P0=_mat(msg.p0, n, n, f"{what}: p0"),
        B=_mat(msg.b, n, p, f"{what}: b") if p else None,
        scale=np.asarray(msg.scale, dtype=float) if len(msg.scale) else None,
        measurement_names=tuple(str(s) for s in msg.measurement_names),
        params={str(k): float(v) for k, v in zip(msg.param_names, msg.param_values)})
    gate = GateConfig(rule=str(msg.gate_rule), probability=float(msg.gate_probability),
                      alarm_m=int(msg.alarm_m), alarm_n=int(msg.alarm_n),
                      action=str(msg.gate_action))
    return model, gate


def measurement_of(msg: Any, model: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """(z, R, H) of a FilterState in the model's m rows, or None when its arrays are malformed.

    * m rows: as recorded.
    * no rows (a prediction-only step, e.g. every reference excluded): z = 0, the model's R and H,
      and the step counts as not fused -- the backward pass adds no information there.
    * k > m = 1 rows sharing one H row with a diagonal R (redundant references stacked by the
      filter): the information-equivalent single row z = sum(z_i / r_i) / sum(1 / r_i),
      r = 1 / sum(1 / r_i), which gives the backward filter exactly the same information.
    Anything else raises ValueError (not representable in the model's rows).
    """
    n, m = model.n, model.m
    k = len(msg.z)
    if len(msg.h) != k * n or len(msg.r) != k * k:
        return None
    if k == 0:
        return np.zeros(m), np.array(model.R, dtype=float), np.array(model.H, dtype=float)
    z = np.asarray(msg.z, dtype=float)
    R = np.asarray(msg.r, dtype=float).reshape(k, k)
    H = np.asarray(msg.h, dtype=float).reshape(k, n)
    if k == m:
        return z, R, H
    if m == 1 and np.all(H == H[0]) and np.count_nonzero(R - np.diag(np.diag(R))) == 0 \
            and np.all(np.diag(R) > 0):
        w = 1.0 / np.diag(R)
        return (np.array([float(w @ z / w.sum())]), np.array([[1.0 / w.sum()]]), H[:1].copy())
    raise ValueError(f"{k} measurement rows that are not stacked copies of the model's "
                     f"{m} row(s)")


def bridge_gaps(dt: np.ndarray, spacing: np.ndarray, t: np.ndarray,
                 where: str) -> tuple[np.ndarray, list[dict]]:
    """States missing from a recording (a recorder that lost messages): the recorded dt of the
    state after them is one filter step, but its stamp is further from the previous recorded
    state. The analysis predicts across the gap, as the filter does over a reference dropout
    (dt = the stamp spacing); each gap is reported as {"after_s", "before_s", "missing_states"}.
    A stamp spacing SHORTER than the recorded dt cannot come from missing states: ValueError
    (naming ``where``)."""
    if dt.size < 2:
        return dt, []
    ok = np.isclose(dt[1:], spacing, rtol=1e-6, atol=1e-6)
    short = ~ok & (spacing < dt[1:])
    if short.any():
        k = int(np.argmax(short)) + 1
        raise ValueError(f"{where}: FilterState #{k} has dt {dt[k]:.6g} s but its stamp is only "
                       f"{spacing[k - 1]:.6g} s after the previous one")
    gaps = []
    for k in np.flatnonzero(~ok) + 1:
        step = dt[k]
        missing = int(round(spacing[k - 1] / step)) - 1 if step > 0 else -1
        gaps.append({"after_s": float(t[k - 1]), "before_s": float(t[k]),
                     "missing_states": max(missing, 0) if step > 0 else None})
    out = dt.copy()
    out[1:][~ok] = spacing[~ok]
    return out, gaps



def analysis_config(gate: Any = None, **fields: Any):
    """The core's AnalysisConfig: its defaults, the recorded gate, and ``fields`` (e.g. the
    node's ``fisher_window``, ``persistence_s``, ``glr_p_false_alarm``)."""
    from .analysis import AnalysisConfig

    if gate is not None:
        fields["gate"] = gate
    return AnalysisConfig(**fields)


@dataclass
class SmootherRun:
    """The result dict (JSON schema of ``flight-fdi analyze``) and the core's arrays."""

    result: dict
    recording: Any = None        # flight_fdi.bagio.recording.Recording
    analysis: Any = None          # the core's AnalysisResult (fwd, bwd, seed, glr, ...)
    error: str = ""
    #: channel ins3d: (Ins3dAnalysis, the recording's dict) (bagio.recording_analysis)
    ins3d: Any = None


def analyze_recording(rec: Recording, config: Any = None, flight_start_s: float | None = None,
                      bag_label: str | None = None) -> SmootherRun:
    """Rebuild the forward pass of ``rec`` and run the core's post-flight analysis on it."""
    from .analysis import analyze_forward
    from .kalman import ForwardResult

    if config is None:
        config = analysis_config(gate=rec.gate)
    fwd = ForwardResult.from_record(rec.model, rec.t, rec.dt, rec.z, rec.R, rec.H, rec.fused,
                                    rec.u, rec.x, rec.P, gate=config.gate)
    t0 = rec.first_stamp_s if not flight_start_s else float(flight_start_s)
    analysis = analyze_forward(rec.model, fwd, config, bag=bag_label or rec.path,
                               channel=rec.channel, t0=t0)
    result = dict(analysis.summary)
    # states missing from the recording, bridged by prediction (times relative to t0)
    result["recording"] = {"gaps": [dict(g, after_s=g["after_s"] - t0,
                                         before_s=g["before_s"] - t0) for g in rec.gaps]}
    return SmootherRun(result=result, recording=rec, analysis=analysis)


def decorrelated_residual(model: Any, a: Any) -> tuple[np.ndarray, np.ndarray]:
    """v~ = dU^-1 v and its variances dD per step (physical units; NaN / Inf where an element
    carries no information), for SmoothedState."""
    return a.seed.v_tilde, a.seed.delta_d


def error_result(bag: str, channel: str, message: str) -> dict:
    """A schema-valid ``insufficient_data`` result for a bag that could not be analysed, with
    the reason under the extra key ``error``."""
    from .result import SCHEMA_ID

    return {
        "schema": SCHEMA_ID,
        "bag": bag, "channel": channel, "duration_s": 0.0, "samples": 0,
        "in_flight": {"gate_threshold": None, "exceed_fraction": 0.0,
                      "first_alarm_s": None, "alarms": []},
        "post_flight": {
            "verdict": "insufficient_data", "headline": f"not analysed: {message}",
            "fault": None, "candidates": [], "isolation": "none", "disagreement": None,
            "element": None, "onset_s": None, "magnitude": None,
            "methods_agree": True,
            "seed_method": {"verdict": "insufficient_data", "element": None, "elements": []},
            "glr": {"hypothesis": "none", "onset_s": None, "magnitude": None,
                    "statistic": 0.0, "threshold": None}},
        "error": message,
    }


def summary_line(result: dict) -> str:
    """One log line: verdict, element, onset, magnitude, GLR, first alarm."""
    post, inf = result["post_flight"], result["in_flight"]
    # (a result without GLR or seed method -- e.g. a forward-only one -- still gives a line)
    glr = post.get("glr") or {"hypothesis": "none (" + post.get("method", "-") + ")",
                              "statistic": None, "threshold": None}

    def f(v: Any, spec: str = ".4g") -> str:
        return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else format(v, spec)

    text = (f"channel {result['channel']}: {post['verdict']}"
            + (f": {post['headline']}" if post.get("headline") else
               f" of {post['element']}" if post["element"] else "")
            + f", onset {f(post['onset_s'], '.1f')} s, magnitude {f(post['magnitude'])}; "
            f"seed method {post.get('seed_method', {}).get('verdict', '-')}, GLR "
            f"{glr['hypothesis']} "
            f"(l = {f(glr['statistic'])}, threshold {f(glr['threshold'])}); "
            f"{len(inf['alarms'])} in-flight alarm(s), first at {f(inf['first_alarm_s'], '.1f')} s")
    if result.get("error"):
        text += f"; error: {result['error']}"
    return text


def json_safe(v: Any) -> Any:
    """``v`` with every non-finite float (in dicts, lists, tuples) as None: strict JSON."""
    if isinstance(v, float) and not math.isfinite(v):
        return None
    if isinstance(v, dict):
        return {k: json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [json_safe(x) for x in v]
    return v


def write_json(result: dict, path: str | Path) -> None:
    """Write the result (NaN as null, so the file is strict JSON)."""
    p = Path(path)
    tmp = p.with_name(p.name + ".tmp")
    tmp.write_text(json.dumps(json_safe(result), indent=2, allow_nan=False) + "\n",
                   encoding="utf-8")
    tmp.replace(p)
