"""The ins3d recording, no rclpy: how ``filter_node`` (``model: ins3d``) lays the 3-D filter's
inputs into FilterState / ModelInfo messages, and :func:`read_recording3d`, which reads them back
from a bag into the core's NavSteps / RefRows (raw CDR: ``cdr.decode_filter_state_columns``;
``smoother_node`` and ``flight-fdi report`` then run the analysis of ``flight-fdi analyze
--model ins3d``: ``bagio/recording_analysis.py``).

Channel ``ins3d``. ModelInfo: ``model_name`` ``ins3d/<grade>``, state names and units, the
measurement rows, Qc (diagonal), H (without the latency column), P0 (the aligned prior), the
scale, ``param_names`` ``rows, t0_sec, t0_nanosec`` (t0: the stamp all times are relative to,
the earliest first stamp of the four inputs, as the bag reader takes it), the model options
``model.vertical`` (index in ``core.ins3d.model.VERTICAL``), ``model.latency``,
``model.aligned_prior`` (1/0) and ``model.ref_markov_sigma_h`` / ``_sigma_v`` / ``_tau_s`` (0:
none), with a height reference row ``model.height_row`` (1), ``model.v0_sigma_up`` and
``model.h0_sigma`` (0: none) (``option_params``; a recording without them: the
``analyze_ins3d`` defaults; the rows are then east, north, height) and, for a
grade that is not a preset (a YAML grade file), its numbers ``grade.<field>`` (SI) and GLR
thresholds ``grade.threshold_<kind>`` (``grade_params``: the smoother analyses with the same
grade and options), and the gate.
FilterState, two kinds, in the filter's order:

* a **step** (``dt`` > 0, or ``reset`` for boundary 0): header stamp = the /ins/imu stamp of the
  boundary, x and P predicted to it, ``u`` = the step's navigation values (C_b^n row-major 9,
  f^n 3, body rate 3, v 3, latitude, height: ``STEP_U``), empty z, r, h;
* an **update** (``dt`` = 0, z not empty): header stamp = the reference stamp, x and P after it,
  z = v_INS - v_ref (ENU, 3; the third h_INS - h_ref with a height row), r = its published
  variances as a 3 x 3 diagonal, h = the rows of H
  used (with the latency column), u = the INS acceleration a^n (3), ``fused``, ``gated``.
"""
from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from . import cdr
from .cdr import FILTER_STATE_SEQUENCES as FIELDS
from .errors import BagError

CHANNEL = "ins3d"
STEP_U = 20
ROW_NAMES = ("east", "north", "up")
GRADE_PREFIX = "grade."
OPTION_PREFIX = "model."
_MARKOV = ("ref_markov_sigma_h", "ref_markov_sigma_v", "ref_markov_tau_s")
_MARKOV_TAU_THIRD = "ref_markov_tau_third_s"
_HEIGHT = ("v0_sigma_up", "h0_sigma")
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
    aligned_prior; with a height row also ``height_row`` 1, ``v0_sigma_up``, ``h0_sigma`` (0:
    none); module docstring)."""
    from flight_fdi.core.ins3d.model import VERTICAL

    mk = options["ref_markov"] or (0.0, 0.0, 0.0)
    vals = {"vertical": float(VERTICAL.index(options["vertical"])),
            "latency": float(options["latency"]), "aligned_prior": float(options["aligned_prior"]),
            **{k: float(v) for k, v in zip(_MARKOV, mk)}}
    if options.get("height_row"):
        vals.update({"height_row": 1.0, **{k: float(options.get(k) or 0.0) for k in _HEIGHT}})
    if len(mk) == 4:                     # the height row's own tau
        vals[_MARKOV_TAU_THIRD] = float(mk[3])
    return [OPTION_PREFIX + k for k in vals], list(vals.values())


def recorded_options(params: dict[str, float]) -> dict[str, Any]:
    """The model options of a recording's ModelInfo parameters ({} for a recording without
    them: the ``analyze_ins3d`` defaults)."""
    from flight_fdi.core.ins3d.model import VERTICAL

    p = {k[len(OPTION_PREFIX):]: v for k, v in params.items() if k.startswith(OPTION_PREFIX)}
    if not p:
        return {}
    try:
        mk = tuple(float(p[k]) for k in _MARKOV) + \
            ((float(p[_MARKOV_TAU_THIRD]),) if _MARKOV_TAU_THIRD in p else ())
        out = {"vertical": VERTICAL[int(p["vertical"])], "latency": bool(p["latency"]),
               "aligned_prior": bool(p["aligned_prior"]),
               "ref_markov": mk if any(mk) else None}
        if p.get("height_row"):
            out.update({"position": True, "height_row": True,
                        **{k: float(p[k]) or None for k in _HEIGHT}})
        return out
    except (KeyError, IndexError, ValueError) as exc:
        raise BagError(f"ins3d recording: bad model options {p} ({exc})") from None


def recorded_grade(model_name: str, params: dict[str, float]) -> Any:
    """The grade of a recording: the CustomGrade of its ``grade.*`` parameters, else the preset
    its ``model_name`` (``ins3d/<grade>``) names."""
    from flight_fdi.core.ins3d.grade_file import CustomGrade

    name = model_name.split("/", 1)[-1]
    nums = {k[len(GRADE_PREFIX):]: v for k, v in params.items() if k.startswith(GRADE_PREFIX)}
    return CustomGrade.from_numbers(name, nums) if nums else name


def read_recording3d(path: str | Path, state_topic: str = "/fdi/state",
                     model_topic: str = "/fdi/model") -> dict:
    """{grade, rows, options (``recorded_options``), gate, t0_ns, steps (NavSteps), refs
    (RefRows), x_last, frame_id} of an ins3d recording (BagError when it is not one or is
    inconsistent). The FilterStates are decoded as columns (``cdr.decode_filter_state_columns``,
    ~0.1 s for an 1800-s flight); the ModelInfo, one message, by rosbags."""
    from flight_fdi.core.gate import GateConfig
    from flight_fdi.core.ins3d.data import NavSteps, RefRows

    from .reader import read_topics_raw
    from .recording import last_model_info

    raw = read_topics_raw(path, [model_topic, state_topic])
    info = last_model_info(raw[model_topic].payloads, CHANNEL, f"bag '{path}': {model_topic}")
    if info is None:
        raise BagError(f"bag '{path}': no ModelInfo of channel {CHANNEL!r} on {model_topic} "
                       "(not a recording of filter_node with model: ins3d)")
    cols = cdr.decode_filter_state_columns(raw[state_topic].payloads,
                                           what=f"bag '{path}': {state_topic} message")
    params = dict(zip(info.param_names, info.param_values))
    t0_ns = int(params["t0_sec"]) * 1_000_000_000 + int(params["t0_nanosec"])
    mine = cols.of_channel(CHANNEL)
    starts = np.flatnonzero(cols.reset[mine])
    if not starts.size:
        raise BagError(f"bag '{path}': no initial ins3d state (reset) on {state_topic}")
    mine = mine[starts[-1]:]                # the last (re)start of the filter
    steps_at, refs_at = _kinds(path, cols, mine[1:])
    rel = lambda index: (cols.stamp_ns[index] - t0_ns) * 1e-9
    t = rel(np.concatenate([mine[:1], steps_at]))
    U = cols.values("u", steps_at)
    steps = NavSteps(t, np.diff(t), np.ascontiguousarray(U[:, :9].reshape(-1, 3, 3)),
                     U[:, 9:12].copy(), U[:, 12:15].copy(), U[:, 15:18].copy(), U[:, 18].copy(),
                     U[:, 19].copy())
    R = cols.values("r", refs_at).reshape(-1, 3, 3)
    refs = RefRows(rel(refs_at), cols.values("z", refs_at).reshape(-1, 3),
                   np.ascontiguousarray(R[:, [0, 1, 2], [0, 1, 2]]),
                   np.searchsorted(steps_at, refs_at).astype(np.int64),
                   cols.values("u", refs_at).reshape(-1, 3))
    gate = GateConfig(rule=info.gate_rule, probability=info.gate_probability,
                      alarm_m=info.alarm_m, alarm_n=info.alarm_n, action=info.gate_action)
    return {"grade": recorded_grade(info.model_name, params), "rows": int(params["rows"]),
            "options": recorded_options(params),
            "gate": gate, "t0_ns": t0_ns, "steps": steps, "refs": refs,
            "x_last": cols.values("x", mine[-1:])[0], "frame_id": info.header.frame_id}


def _kinds(path: str | Path, cols: Any, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the steps, the updates) among the messages ``index`` after the reset: a step has
    ``dt`` > 0 and STEP_U values in u; an update ``dt`` = 0, a 3-row z with its 3 x 3 r and the
    acceleration (3) in u; other states (neither) are not inputs."""
    u = cols.count[FIELDS.index("u"), index]
    is_step = cols.dt[index] > 0.0
    wrong = np.flatnonzero(is_step & (u != STEP_U))
    if wrong.size:
        raise BagError(f"bag '{path}': an ins3d step state has {u[wrong[0]]} values in u, "
                       f"expected {STEP_U}")
    steps = index[is_step]
    if not steps.size:
        raise BagError(f"bag '{path}': the ins3d recording has no propagation step")
    is_ref = ~is_step & (cols.count[FIELDS.index("z"), index] > 0)
    refs = index[is_ref]
    sizes = {f: cols.count[FIELDS.index(f), refs] for f in ("z", "r", "u")}
    for f, want in (("z", 3), ("r", 9), ("u", 3)):
        off = np.flatnonzero(sizes[f] != want)
        if off.size:
            raise BagError(f"bag '{path}': an ins3d update state has {sizes[f][off[0]]} values "
                           f"in {f}, expected {want}")
    return steps, refs


__all__ = ["CHANNEL", "GRADE_PREFIX", "OPTION_PREFIX", "ROW_NAMES", "STEP_U", "grade_params",
           "option_params", "pack_step", "read_recording3d", "recorded_grade",
           "recorded_options", "state_units", "t0_params"]
