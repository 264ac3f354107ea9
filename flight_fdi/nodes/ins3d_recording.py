"""The ins3d recording: how ``filter_node`` (``model: ins3d``) lays the 3-D filter's inputs into
FilterState / ModelInfo messages, and how ``smoother_node`` (``channel: ins3d``) reads them back
into the core's NavSteps / RefRows and runs the same analysis as ``flight-fdi analyze --model
ins3d``.

Channel ``ins3d``. ModelInfo: ``model_name`` ``ins3d/<grade>``, state names and units, the
measurement rows, Qc (diagonal), H (without the latency column), P0 (the aligned prior), the
scale, ``param_names`` ``rows, t0_sec, t0_nanosec`` (t0: the stamp all times are relative to,
the earliest first stamp of the four inputs, as the bag reader takes it), the model options
``model.vertical`` (index in ``core.ins3d.model.VERTICAL``), ``model.latency``,
``model.aligned_prior`` (1/0) and ``model.ref_markov_sigma_h`` / ``_sigma_v`` / ``_tau_s`` (0:
none) (``option_params``; a recording without them: the ``analyze_ins3d`` defaults) and, for a
grade that is not a preset (a YAML grade file), its numbers ``grade.<field>`` (SI) and GLR
thresholds ``grade.threshold_<kind>`` (``grade_params``: the smoother analyses with the same
grade and options), and the gate.
FilterState, two kinds, in the filter's order:

* a **step** (``dt`` > 0, or ``reset`` for boundary 0): header stamp = the /ins/imu stamp of the
  boundary, x and P predicted to it, ``u`` = the step's navigation values (C_b^n row-major 9,
  f^n 3, body rate 3, v 3, latitude, height: ``STEP_U``), empty z, r, h;
* an **update** (``dt`` = 0, z not empty): header stamp = the reference stamp, x and P after it,
  z = v_INS - v_ref (ENU, 3), r = its published variances as a 3 x 3 diagonal, h = the rows of H
  used (with the latency column), u = the INS acceleration a^n (3), ``fused``, ``gated``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from flight_fdi.bagio.errors import BagError

CHANNEL = "ins3d"
STEP_U = 20
ROW_NAMES = ("east", "north", "up")
GRADE_PREFIX = "grade."
OPTION_PREFIX = "model."
_MARKOV = ("ref_markov_sigma_h", "ref_markov_sigma_v", "ref_markov_tau_s")
_UNITS = {"dv": "m/s", "ph": "rad", "ba": "m/s^2", "bg": "rad/s", "dp": "m", "re": "m/s",
          "la": "s"}


def state_units(names: tuple[str, ...]) -> list[str]:
    return [_UNITS.get(n[:2], "") for n in names]


def pack_step(step: Any) -> np.ndarray:
    """The 20 navigation values of a one-step NavSteps (the ``u`` of a step message)."""
    return np.concatenate([step.C[0].reshape(-1), step.f_n[0], step.w_b[0], step.v[0],
                           [step.lat[0], step.h[0]]])


def t0_params(t0_ns: int) -> tuple[float, float]:
    return float(t0_ns // 1_000_000_000), float(t0_ns % 1_000_000_000)


def grade_params(grade: Any) -> tuple[list[str], list[float]]:
    """The ModelInfo parameters of a grade: none for a preset (``model_name`` names it), the
    numbers of a CustomGrade (a grade file)."""
    from flight_fdi.core.ins3d.grade_file import CustomGrade

    if not isinstance(grade, CustomGrade):
        return [], []
    nums = grade.numbers()
    return [GRADE_PREFIX + k for k in nums], list(nums.values())


def option_params(options: dict[str, Any]) -> tuple[list[str], list[float]]:
    """The ModelInfo parameters of the model options (vertical, latency, ref_markov,
    aligned_prior; module docstring)."""
    from flight_fdi.core.ins3d.model import VERTICAL

    mk = options["ref_markov"] or (0.0, 0.0, 0.0)
    vals = {"vertical": float(VERTICAL.index(options["vertical"])),
            "latency": float(options["latency"]), "aligned_prior": float(options["aligned_prior"]),
            **{k: float(v) for k, v in zip(_MARKOV, mk)}}
    return [OPTION_PREFIX + k for k in vals], list(vals.values())


def recorded_options(params: dict[str, float]) -> dict[str, Any]:
    """The model options of a recording's ModelInfo parameters ({} for a recording without
    them: the ``analyze_ins3d`` defaults)."""
    from flight_fdi.core.ins3d.model import VERTICAL

    p = {k[len(OPTION_PREFIX):]: v for k, v in params.items() if k.startswith(OPTION_PREFIX)}
    if not p:
        return {}
    try:
        mk = tuple(float(p[k]) for k in _MARKOV)
        return {"vertical": VERTICAL[int(p["vertical"])], "latency": bool(p["latency"]),
                "aligned_prior": bool(p["aligned_prior"]),
                "ref_markov": mk if any(mk) else None}
    except (KeyError, IndexError, ValueError) as exc:
        raise BagError(f"ins3d recording: bad model options {p} ({exc})") from None


def recorded_grade(model_name: str, params: dict[str, float]) -> Any:
    """The grade of a recording: the CustomGrade of its ``grade.*`` parameters, else the preset
    its ``model_name`` (``ins3d/<grade>``) names."""
    from flight_fdi.core.ins3d.grade_file import CustomGrade

    name = model_name.split("/", 1)[-1]
    nums = {k[len(GRADE_PREFIX):]: v for k, v in params.items() if k.startswith(GRADE_PREFIX)}
    return CustomGrade.from_numbers(name, nums) if nums else name


def _stamp_ns(msg: Any) -> int:
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def read_recording3d(path: str | Path, state_topic: str = "/fdi/state",
                     model_topic: str = "/fdi/model") -> dict:
    """{grade, rows, options (``recorded_options``), gate, t0_ns, steps (NavSteps), refs
    (RefRows), x_last} of an ins3d recording (BagError when it is not one or is
    inconsistent)."""
    from flight_fdi.bagio.reader import read_messages
    from flight_fdi.core.gate import GateConfig
    from flight_fdi.core.ins3d.data import NavSteps, RefRows

    info, states = None, []
    for topic, _, _, msg in read_messages(path, [model_topic, state_topic]):
        if msg.channel != CHANNEL:
            continue
        if topic == model_topic:
            info = msg
        else:
            states.append(msg)
    if info is None:
        raise BagError(f"bag '{path}': no ModelInfo of channel {CHANNEL!r} on {model_topic} "
                       "(not a recording of filter_node with model: ins3d)")
    params = dict(zip(info.param_names, info.param_values))
    t0_ns = int(params["t0_sec"]) * 1_000_000_000 + int(params["t0_nanosec"])
    rel = lambda m: (_stamp_ns(m) - t0_ns) * 1e-9
    starts = [i for i, m in enumerate(states) if m.reset]
    if not starts:
        raise BagError(f"bag '{path}': no initial ins3d state (reset) on {state_topic}")
    states = states[starts[-1]:]            # the last (re)start of the filter
    t, u, t_ref, z, r, a, step = [rel(states[0])], [], [], [], [], [], []
    for m in states[1:]:
        if m.dt > 0.0:
            if len(m.u) != STEP_U:
                raise BagError(f"bag '{path}': an ins3d step state has {len(m.u)} values in u, "
                               f"expected {STEP_U}")
            t.append(rel(m))
            u.append(np.asarray(m.u, dtype=float))
        elif len(m.z):
            t_ref.append(rel(m))
            z.append(np.asarray(m.z, dtype=float))
            r.append(np.diag(np.asarray(m.r, dtype=float).reshape(3, 3)))
            a.append(np.asarray(m.u, dtype=float))
            step.append(len(t) - 1)
    if not u:
        raise BagError(f"bag '{path}': the ins3d recording has no propagation step")
    t = np.array(t)
    U = np.vstack(u)
    steps = NavSteps(t, np.diff(t), np.ascontiguousarray(U[:, :9].reshape(-1, 3, 3)),
                     U[:, 9:12].copy(), U[:, 12:15].copy(), U[:, 15:18].copy(), U[:, 18].copy(),
                     U[:, 19].copy())
    refs = RefRows(np.array(t_ref), np.array(z).reshape(-1, 3),
                   np.ascontiguousarray(np.array(r).reshape(-1, 3)),
                   np.array(step, dtype=np.int64), np.array(a).reshape(-1, 3))
    gate = GateConfig(rule=info.gate_rule, probability=info.gate_probability,
                      alarm_m=info.alarm_m, alarm_n=info.alarm_n, action=info.gate_action)
    return {"grade": recorded_grade(info.model_name, params), "rows": int(params["rows"]),
            "options": recorded_options(params),
            "gate": gate, "t0_ns": t0_ns, "steps": steps, "refs": refs,
            "x_last": np.asarray(states[-1].x, dtype=float), "frame_id": info.header.frame_id}


def analyze_recording3d(path: str | Path, state_topic: str = "/fdi/state",
                        model_topic: str = "/fdi/model", bag_label: str | None = None,
                        gate: Any = None) -> tuple[dict, Any, dict]:
    """(result dict, Ins3dAnalysis, recording) of an ins3d recording: the analysis of
    ``flight-fdi analyze --model ins3d`` on the recorded inputs (``gate``: override the
    recorded one)."""
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.core.ins3d_result import ins3d_result

    rec = read_recording3d(path, state_topic, model_topic)
    analysis = analyze_ins3d(rec["steps"], rec["refs"], grade=rec["grade"], rows=rec["rows"],
                             gate=gate or rec["gate"], **rec["options"])
    return ins3d_result(analysis, bag_label or str(path)), analysis, rec


def smoother_run3d(bag: str, state_topic: str, model_topic: str, gate: Any = None):
    """What ``smoother_node`` (``channel: ins3d``) runs: a SmootherRun with the result (and in
    its ``ins3d`` the analysis and the recording read), or for a bag that cannot be analysed a
    schema-valid ``insufficient_data`` result with the error (never raises for bad input)."""
    from flight_fdi.core.errors import CoreError

    from .smoother_node import SmootherRun, error_result

    try:
        if not bag:
            raise BagError("no bag given (set the 'bag' parameter)")
        result, analysis, rec = analyze_recording3d(bag, state_topic, model_topic,
                                                    bag_label=bag, gate=gate)
        return SmootherRun(result=result, ins3d=(analysis, rec))
    except (BagError, CoreError, ValueError) as exc:
        return SmootherRun(result={**error_result(bag, "en", str(exc)), "model": "ins3d"},
                           error=str(exc))


__all__ = ["CHANNEL", "STEP_U", "analyze_recording3d", "grade_params", "option_params",
           "pack_step", "read_recording3d", "recorded_grade", "recorded_options",
           "smoother_run3d", "state_units", "t0_params"]
