"""Post-flight results <-> ROS messages: FaultLocalization from the analysis result dict (the JSON
schema of ``flight-fdi analyze --json``) and SmoothedState from the backward pass.

All message construction for the smoother lives here (the filter's messages are in
:mod:`.convert`). NaN encodes "unknown" in float fields, "" in string fields, as the .msg files say.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from .convert import header, s_to_stamp

VERDICTS = ("no_fault", "glitch", "failure", "ambiguous", "insufficient_data")
#: verdict name -> FaultLocalization.VERDICT_* value (0..4, in the order of the .msg constants)
VERDICT_CODES = {name: code for code, name in enumerate(VERDICTS)}

_NAN = float("nan")


def _num(value: Any) -> float:
    """A JSON number or null as a message float (NaN for null)."""
    return _NAN if value is None else float(value)


def _opt(value: float) -> float | None:
    """A message float as a JSON value (None for NaN)."""
    v = float(value)
    return None if math.isnan(v) else v


def fault_localization_msg(result: Mapping[str, Any], stamp: Any, flight_start_s: float,
                           end_s: float | None = None, frame_id: str = ""):
    """flight_fdi_msgs/FaultLocalization from an analysis result dict.

    ``stamp``: header stamp (builtin_interfaces/Time, e.g. the node's clock); ``flight_start_s``:
    the absolute time (s) that the result's times are relative to; ``end_s``: end of the
    isolated fault relative to the flight start when known.
    """
    from flight_fdi_msgs.msg import FaultLocalization

    post = result["post_flight"]
    # (an ins3d forward-only result has neither: empty fields)
    seed = post.get("seed_method") or {"verdict": "", "element": None, "elements": []}
    glr = post.get("glr") or {"hypothesis": "", "onset_s": None, "magnitude": None,
                              "statistic": None, "threshold": None}
    verdict = post["verdict"]
    if verdict not in VERDICT_CODES:
        raise ValueError(f"unknown verdict {verdict!r}; expected one of {', '.join(VERDICTS)}")
    elements = seed["elements"]
    fault = post.get("fault") or {}
    return FaultLocalization(
        header=header(stamp, frame_id),
        channel=str(result["channel"]),
        flight_start=s_to_stamp(flight_start_s),
        duration_s=float(result["duration_s"]),
        samples=int(result["samples"]),
        verdict=VERDICT_CODES[verdict],
        verdict_name=verdict,
        element=post["element"] or "",
        onset_s=_num(post["onset_s"]),
        end_s=_num(end_s),
        magnitude=_num(post["magnitude"]),
        methods_agree=bool(post["methods_agree"]),
        headline=str(post.get("headline") or ""),
        isolation=str(post.get("isolation") or ""),
        sensor=str(fault.get("sensor") or ""), axis=str(fault.get("axis") or ""),
        kind=str(fault.get("kind") or ""), unit=str(fault.get("unit") or ""),
        magnitude_eng=_num(fault.get("magnitude_eng")), unit_eng=str(fault.get("unit_eng") or ""),
        seed_verdict=str(seed["verdict"]),
        seed_element=seed["element"] or "",
        element_names=[str(e["name"]) for e in elements],
        j_peak=[_num(e["J_peak"]) for e in elements],
        gamma2=[_num(e["gamma2"]) for e in elements],
        f_peak=[_num(e["F_peak"]) for e in elements],
        eta2=[_num(e["eta2"]) for e in elements],
        exceed_fraction=[float(e["exceed_fraction"]) for e in elements],
        dof=[int(e["dof"]) for e in elements],
        glr_hypothesis=str(glr["hypothesis"]),
        glr_onset_s=_num(glr["onset_s"]),
        glr_magnitude=_num(glr["magnitude"]),
        glr_statistic=_num(glr["statistic"]),
        glr_threshold=_num(glr["threshold"]),
        **_turn_on_fields(post.get("turn_on_bias") or []),
    )


#: post_flight.turn_on_bias keys carried as FaultLocalization turn_on_<key> arrays (text or number,
#: NaN for None)
_TURN_ON = ("sensor", "axis", "magnitude", "magnitude_std", "magnitude_eng", "unit_eng",
            "prior_sigmas")
_TURN_ON_TEXT = ("sensor", "axis", "unit_eng")


def _turn_on_value(key: str, value: Any, to_msg: bool):
    if key in _TURN_ON_TEXT:
        return str(value)
    return _num(value) if to_msg else _opt(value)


def _turn_on_fields(biases: Sequence[Mapping[str, Any]]) -> dict:
    return {f"turn_on_{k}": [_turn_on_value(k, b[k], True) for b in biases] for k in _TURN_ON}


def _turn_on_from_msg(msg: Any) -> list[dict]:
    cols = [list(getattr(msg, f"turn_on_{k}")) for k in _TURN_ON]
    return [{k: _turn_on_value(k, col[i], False) for k, col in zip(_TURN_ON, cols)}
            for i in range(len(cols[0]))]


def post_flight_from_msg(msg: Any) -> dict:
    """The ``post_flight`` part of the result dict back from a FaultLocalization message (works
    on rclpy and rosbags messages alike); the inverse of :func:`fault_localization_msg`."""
    elements = [
        {"name": str(name), "J_peak": _opt(j), "gamma2": _opt(g), "F_peak": _opt(f),
         "eta2": _opt(e), "exceed_fraction": float(x), "dof": int(d)}
        for name, j, g, f, e, x, d in zip(msg.element_names, msg.j_peak, msg.gamma2, msg.f_peak,
                                          msg.eta2, msg.exceed_fraction, msg.dof)]
    fault = None
    if msg.sensor:
        fault = {"sensor": str(msg.sensor), "axis": str(msg.axis), "kind": str(msg.kind),
                 "unit": str(msg.unit), "magnitude_eng": _opt(msg.magnitude_eng),
                 "unit_eng": str(msg.unit_eng)}
    return {
        "verdict": str(msg.verdict_name),
        "headline": str(msg.headline), "isolation": str(msg.isolation), "fault": fault,
        "element": str(msg.element) or None,
        "onset_s": _opt(msg.onset_s),
        "magnitude": _opt(msg.magnitude),
        "methods_agree": bool(msg.methods_agree),
        "seed_method": {"verdict": str(msg.seed_verdict), "element": str(msg.seed_element) or None,
                        "elements": elements},
        "glr": {"hypothesis": str(msg.glr_hypothesis), "onset_s": _opt(msg.glr_onset_s),
                "magnitude": _opt(msg.glr_magnitude), "statistic": float(msg.glr_statistic),
                "threshold": _opt(msg.glr_threshold)},
        "turn_on_bias": _turn_on_from_msg(msg),
    }


def _flat(a: Any) -> list[float]:
    return np.asarray(a, dtype=float).reshape(-1).tolist()


def smoothed_state_msgs(stamps_s: Sequence[float], channel: str, state_names: Sequence[str],
                        x_s: np.ndarray, P_s: np.ndarray, v: np.ndarray, v_tilde: np.ndarray,
                        delta_d: np.ndarray, J: np.ndarray, j_terms: np.ndarray, F: np.ndarray,
                        dof: np.ndarray, frame_id: str = "") -> list:
    """One flight_fdi_msgs/SmoothedState per step (arrays over N steps, n states; NaN / Inf as
    the backward pass produced them)."""
    from flight_fdi_msgs.msg import SmoothedState

    names = list(state_names)
    out = []
    for i, t in enumerate(stamps_s):
        out.append(SmoothedState(
            header=header(s_to_stamp(float(t)), frame_id), channel=channel, state_names=names,
            x_smoothed=_flat(x_s[i]), p_smoothed=_flat(P_s[i]), v=_flat(v[i]),
            v_tilde=_flat(v_tilde[i]), delta_d=_flat(delta_d[i]), j=float(J[i]),
            j_terms=_flat(j_terms[i]), f=_flat(F[i]), dof=int(dof[i])))
    return out
