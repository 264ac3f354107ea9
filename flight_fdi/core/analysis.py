"""The offline analysis of one flight channel (what ``flight-fdi analyze`` and the ROS smoother
call): align the INS velocity to the reference stamps, run the forward filter, the backward
information filter, the seed diagnosis and the GLR isolator, and summarise.

:func:`run_analysis` returns everything (:class:`AnalysisResult`: arrays for plots and ROS
messages, and the summary); :func:`analyze_flight` returns only the JSON-able summary;
:func:`analyze_forward` is the post-flight part alone, on a forward pass (e.g. one rebuilt from a
recording with ``ForwardResult.from_record``).
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .align import align_to_reference
from .diagnosis import DiagnosisConfig, SeedDiagnosis, diagnose
from .errors import CoreError
from .glr import GlrConfig, GlrResult, isolate
from .kalman import ForwardResult, GateConfig, measurement_record, run_forward
from .models import LinearModel
from .result import SCHEMA_ID, post_flight
from .smoother import DEFAULT_RANK_TOL, BackwardResult, run_backward

_GLR_DEFAULTS = GlrConfig()


@dataclass(frozen=True)
class AnalysisConfig:
    """Settings of the offline analysis.

    gate: the in-flight gate replayed by the forward filter.
    max_gap_s: INS samples further apart than this are not interpolated across (alignment).
    fisher_window, persistence_s, episode_probability, min_valid_steps, rank_tol: the seed
        diagnosis (:class:`~flight_fdi.core.diagnosis.DiagnosisConfig`).
    glr_p_false_alarm, glr_hypotheses, glr_ambiguity_margin: the GLR isolator
        (:class:`~flight_fdi.core.glr.GlrConfig`).
    jobs: processes ``flight-fdi analyze`` may use: with 2 it reads the bag in a forked child
        while it imports the estimation core and loads the compiled kernels
        (``core.warmup.preload``). The analysis itself runs in one process (its
        compiled kernels release the GIL, so GLR's thread overlaps the backward pass; a forked
        backward pass or GLR no longer pays, docs/performance.md).
    """

    gate: GateConfig = field(default_factory=GateConfig)
    max_gap_s: float = 0.5
    fisher_window: int = 50
    persistence_s: float = 1.0
    episode_probability: float = 1e-6
    min_valid_steps: int = 100
    rank_tol: float = DEFAULT_RANK_TOL
    glr_p_false_alarm: float = 1e-3
    glr_hypotheses: tuple = _GLR_DEFAULTS.hypotheses
    glr_ambiguity_margin: float = _GLR_DEFAULTS.ambiguity_margin
    jobs: int = 1

    def __post_init__(self) -> None:
        if isinstance(self.jobs, bool) or not isinstance(self.jobs, (int, np.integer)) \
                or self.jobs not in (1, 2):
            raise CoreError(f"AnalysisConfig.jobs must be 1 or 2, got {self.jobs!r}")
        if not isinstance(self.gate, GateConfig):
            raise CoreError(f"AnalysisConfig.gate must be a GateConfig, got "
                            f"{type(self.gate).__name__}")
        g = self.max_gap_s
        if isinstance(g, bool) or not isinstance(g, (int, float)) or not math.isfinite(g) \
                or g <= 0:
            raise CoreError(f"AnalysisConfig.max_gap_s must be a number > 0, got {g!r}")
        # the sub-configurations validate their fields; name ours in the message
        try:
            self.diagnosis_config()
        except CoreError as exc:
            raise CoreError(f"AnalysisConfig: {exc}".replace("DiagnosisConfig.",
                                                             "AnalysisConfig.")) from None
        try:
            self.glr_config()
        except CoreError as exc:
            raise CoreError(f"AnalysisConfig: {exc}".replace("GlrConfig.p_false_alarm",
                                                             "AnalysisConfig.glr_p_false_alarm")
                            .replace("GlrConfig.hypotheses", "AnalysisConfig.glr_hypotheses")
                            .replace("GlrConfig.ambiguity_margin",
                                     "AnalysisConfig.glr_ambiguity_margin")
                            ) from None

    def diagnosis_config(self) -> DiagnosisConfig:
        return DiagnosisConfig(fisher_window=self.fisher_window, persistence_s=self.persistence_s,
                               episode_probability=self.episode_probability,
                               min_valid_steps=self.min_valid_steps, rank_tol=self.rank_tol)

    def glr_config(self) -> GlrConfig:
        return GlrConfig(p_false_alarm=self.glr_p_false_alarm,
                         hypotheses=tuple(self.glr_hypotheses),
                         ambiguity_margin=self.glr_ambiguity_margin)


@dataclass
class AnalysisResult:
    """Everything :func:`run_analysis` computed. Times in ``fwd``/``bwd``/``seed``/``glr`` are
    absolute (the input's time base); the summary's ``*_s`` are seconds from ``t0``."""

    t0: float
    fwd: ForwardResult
    bwd: BackwardResult
    seed: SeedDiagnosis
    glr: GlrResult
    summary: dict
    aligned: np.ndarray        # (M,) bool: reference samples that could be aligned (all True
                               # from analyze_forward, which gets no raw messages)
    end_s: float | None        # end of the seed method's J episode, seconds from t0 (None:
                               # no episode, or it lasts to the end of the record)


def glr_element(model: LinearModel, hypothesis: str) -> str | None:
    """The state element a GLR hypothesis points at: the state of a step or ramp hypothesis, the
    state a measurement observes for a measurement fault (``reference_jump`` ->
    ``velocity_error`` on the INS channel); None for ``"none"``."""
    if hypothesis == "none":
        return None
    if hypothesis.endswith(("_step", "_ramp")) and not hypothesis.startswith(("step:", "ramp:")):
        return hypothesis[:-5]
    if hypothesis.startswith(("step:", "ramp:")):
        return hypothesis[5:]
    # a fault of a measurement row: the state that row observes
    if ":" in hypothesis:
        name = hypothesis.split(":", 1)[1]
        row = model.measurement_names.index(name) if name in model.measurement_names else 0
    else:
        row = 0
    h = model.H[row]
    nz = np.flatnonzero(h)
    return model.state_names[int(nz[0])] if nz.size == 1 else None


def _glr_is_outlier(hypothesis: str) -> bool:
    return hypothesis == "reference_outlier" or hypothesis.startswith("outlier:")


def _num(x: Any) -> float | None:
    """A JSON number, or None where undefined (NaN / inf)."""
    if x is None:
        return None
    x = float(x)
    return x if math.isfinite(x) else None


def _vector(a: Any, what: str, n: int | None = None) -> np.ndarray:
    try:
        arr = np.asarray(a, dtype=float)
    except (TypeError, ValueError):
        raise CoreError(f"{what} is not numeric") from None
    if arr.ndim == 2 and arr.shape[1] == 1:
        arr = arr[:, 0]
    if arr.ndim != 1:
        raise CoreError(f"{what} must be one-dimensional, got shape {arr.shape}")
    if n is not None and arr.size != n:
        raise CoreError(f"{what} must have {n} entries, got {arr.size}")
    return arr


def run_analysis(model: LinearModel, t_ins: Any, v_ins: Any, t_ref: Any, v_ref: Any,
                 r_ref: Any = None, config: AnalysisConfig = AnalysisConfig(), bag: str = "",
                 channel: str = "x", t0: float | None = None) -> AnalysisResult:
    """Analyse one channel of a flight (see :func:`analyze_flight` for the summary).

    t_ins, v_ins: INS stamps (strictly increasing) and velocity; t_ref, v_ref: reference stamps
    and velocity; r_ref: the reference's variance per message ((M,) or (M, 1, 1)), NaN where the
    message's covariance was invalid -- the model's R is used there and the samples are counted
    in ``input.reference.dropped.invalid_covariance_replaced``; None: model.R throughout. The
    filter runs on z = V_INS(t_ref) - V_ref at the reference stamps the INS covers (the others
    are counted by :func:`input_counts`).
    """
    if not isinstance(model, LinearModel):
        raise CoreError(f"run_analysis: model must be a LinearModel, got {type(model).__name__}")
    if not isinstance(config, AnalysisConfig):
        raise CoreError(f"run_analysis: config must be an AnalysisConfig, got "
                        f"{type(config).__name__}")
    if model.m != 1:
        raise CoreError(f"run_analysis: the velocity channel needs a one-row measurement; "
                        f"model {model.name!r} has {model.m}")
    ti = _vector(t_ins, "t_ins")
    vi = _vector(v_ins, "v_ins", ti.size)
    tr = _vector(t_ref, "t_ref")
    vr = _vector(v_ref, "v_ref", tr.size)
    if ti.size == 0 or tr.size == 0:
        raise CoreError("run_analysis: no INS or no reference samples")
    if not np.all(np.isfinite(vr)):
        raise CoreError("run_analysis: v_ref contains NaN or Inf")
    if r_ref is None:
        rr = np.full(tr.size, np.nan)
        invalid_cov = 0
    else:
        if np.size(r_ref) != tr.size:
            raise CoreError(f"r_ref must hold one variance per reference message ({tr.size}), "
                            f"got shape {np.shape(r_ref)}")
        rr = _vector(np.reshape(np.asarray(r_ref, dtype=float), -1), "r_ref", tr.size)
        bad = ~np.isfinite(rr)
        invalid_cov = int(bad.sum())
        if np.any(rr[~bad] < 0):
            raise CoreError(f"run_analysis: r_ref is negative at index "
                            f"{int(np.flatnonzero((rr < 0) & ~bad)[0])}")

    aligned, v_at = align_to_reference(ti, vi, tr, max_gap_s=config.max_gap_s)
    if not np.any(aligned):
        raise CoreError("run_analysis: no reference sample lies within the INS record "
                        f"(max_gap_s = {config.max_gap_s} s)")
    t = tr[aligned]
    z = v_at[aligned] - vr[aligned]
    r = rr[aligned]
    R = np.where(np.isfinite(r), r, float(model.R[0, 0])).reshape(-1, 1, 1)
    origin = float(min(np.min(ti), np.min(tr))) if t0 is None else float(t0)
    if not math.isfinite(origin):
        raise CoreError(f"run_analysis: t0 must be finite, got {t0!r}")

    record = measurement_record(model, t, z, R)
    fwd = run_forward(model, None, None, gate=config.gate, record=record)
    result = analyze_forward(model, fwd, config, bag=bag, channel=channel, t0=origin)
    result.aligned = aligned
    result.summary["input"] = input_counts(ti, tr, aligned, invalid_cov)
    return result


def input_counts(t_ins: np.ndarray, t_ref: np.ndarray, aligned: np.ndarray,
                 invalid_covariance: int) -> dict:
    """``input`` of the summary for arrays (no topics): per role (``ins``, ``reference``) the
    samples given, used, and those not used by reason -- reference samples outside the INS
    record or in an INS gap longer than max_gap_s; ``invalid_covariance_replaced`` counts
    samples used with the model's R instead of their invalid covariance. The bag layer
    (flight_fdi.bagio.inputs) names the topics and adds the reasons of the raw messages."""
    outside = (t_ref < t_ins[0]) | (t_ref > t_ins[-1])
    return {
        "ins": {"role": "ins", "messages": int(t_ins.size), "used": int(t_ins.size),
                "dropped": {}},
        "reference": {"role": "reference", "messages": int(t_ref.size),
                      "used": int(aligned.sum()), "dropped": {
            "outside_ins_record": int((outside & ~aligned).sum()),
            "ins_gap": int((~outside & ~aligned).sum()),
            "invalid_covariance_replaced": int(invalid_covariance)}},
    }


#: records longer than this (steps; 5.5 hours at 10 Hz) run GLR before the backward pass
#: instead of beside it, to bound the peak memory (see analyze_forward)
GLR_CONCURRENT_MAX_STEPS = 200_000


def analyze_forward(model: LinearModel, fwd: ForwardResult,
                    config: AnalysisConfig = AnalysisConfig(), bag: str = "", channel: str = "x",
                    t0: float | None = None) -> AnalysisResult:
    """The post-flight part of the analysis on a forward pass -- what :func:`run_analysis` does
    after its own forward pass, and what the ROS smoother calls on a forward pass rebuilt from a
    recording (``ForwardResult.from_record``): the backward pass, the seed diagnosis, GLR and
    the summary (without the ``input`` counts, which belong to the raw messages). ``t0``
    defaults to ``fwd.t[0]``."""
    if not isinstance(model, LinearModel):
        raise CoreError(f"analyze_forward: model must be a LinearModel, got "
                        f"{type(model).__name__}")
    if not isinstance(config, AnalysisConfig):
        raise CoreError(f"analyze_forward: config must be an AnalysisConfig, got "
                        f"{type(config).__name__}")
    if not isinstance(fwd, ForwardResult):
        raise CoreError(f"analyze_forward: expected a ForwardResult, got {type(fwd).__name__}")
    origin = float(fwd.t[0]) if t0 is None else float(t0)
    if not math.isfinite(origin):
        raise CoreError(f"analyze_forward: t0 must be finite, got {t0!r}")
    # GLR needs only the forward pass: it runs in a second thread while this one does the
    # backward pass (both are compiled kernels that release the GIL), so the two use both cores
    # of a small machine. On very long records the working memory of the two together is too
    # much (GLR ~0.5 kB per step, the backward pass ~1 kB): GLR then runs first, alone.
    if len(fwd.t) > GLR_CONCURRENT_MAX_STEPS:
        glr = isolate(model, fwd, config.glr_config())
        bwd = run_backward(model, fwd, rank_tol=config.rank_tol)
        seed = diagnose(model, fwd, bwd, config.diagnosis_config())
    else:
        with ThreadPoolExecutor(max_workers=1) as pool:
            glr_future = pool.submit(isolate, model, fwd, config.glr_config())
            bwd = run_backward(model, fwd, rank_tol=config.rank_tol)
            seed = diagnose(model, fwd, bwd, config.diagnosis_config())
            glr = glr_future.result()
    summary = _summary(model, fwd, seed, glr, origin, bag, channel)
    end_s = None if seed.end_t is None else seed.end_t - origin
    return AnalysisResult(t0=origin, fwd=fwd, bwd=bwd, seed=seed, glr=glr, summary=summary,
                          aligned=np.ones(len(fwd.t), dtype=bool), end_s=end_s)


def combine(model: LinearModel, seed: SeedDiagnosis, glr: GlrResult) -> dict:
    """The overall verdict from both methods (times absolute):

    * ``insufficient_data`` when the seed method has too little data;
    * GLR isolated one fault (its statistic exceeds its threshold, no rival hypothesis of
      another sensor within the margin, and what it leaves passes the second GLR pass):
      element, onset and magnitude are GLR's -- it separates weakly observable elements that
      the seed's UDU^T order can confuse; the verdict is ``glitch`` for an outlier hypothesis
      and ``failure`` for a step, ramp or jump;
    * GLR detected but ambiguous or unexplained: ``ambiguous``, no element;
    * otherwise the seed method's verdict, element and onset (magnitude unknown).

    ``methods_agree``: the seed element equals the element of the GLR hypothesis
    (accel_bias_* <-> accel_bias, gyro_drift_* <-> gyro_drift, reference_jump /
    reference_outlier <-> the measured element, velocity_error; none <-> no element).
    """
    g_elem = glr_element(model, glr.hypothesis)
    agree = seed.element == g_elem
    if seed.verdict == "insufficient_data":
        return {"verdict": "insufficient_data", "element": None, "onset": None,
                "magnitude": None, "methods_agree": agree}
    if glr.detected and glr.confident:
        return {"verdict": "glitch" if _glr_is_outlier(glr.hypothesis) else "failure",
                "element": g_elem, "onset": glr.onset_t, "magnitude": glr.magnitude,
                "methods_agree": agree}
    if glr.detected:
        return {"verdict": "ambiguous", "element": None, "onset": None, "magnitude": None,
                "methods_agree": agree}
    return {"verdict": seed.verdict, "element": seed.element, "onset": seed.onset_t,
            "magnitude": None, "methods_agree": agree}


def _summary(model: LinearModel, fwd: ForwardResult, seed: SeedDiagnosis, glr: GlrResult,
             t0: float, bag: str, channel: str) -> dict:
    def rel(x: float | None) -> float | None:
        return None if x is None else _num(x - t0)

    alarms = fwd.alarms()
    both = combine(model, seed, glr)
    end_s = None if seed.end_t is None else seed.end_t - t0
    decision = post_flight(seed, glr, t0, channel, glr_element(model, glr.hypothesis), end_s)
    best = glr.per_hypothesis.get(glr.hypothesis, {})
    interval = best.get("onset_interval")
    return {
        "schema": SCHEMA_ID,
        "bag": str(bag),
        "channel": str(channel),
        "duration_s": float(fwd.t[-1] - fwd.t[0]),
        "samples": int(len(fwd.t)),
        "in_flight": {
            "gate_threshold": float(fwd.threshold[0]),
            "exceed_fraction": float(np.mean(fwd.exceeded)),
            "first_alarm_s": rel(alarms[0]["start_s"]) if alarms else None,
            "alarms": [{"start_s": rel(a["start_s"]), "end_s": rel(a["end_s"]),
                        "peak_beta2": float(a["peak_beta2"])} for a in alarms],
        },
        "post_flight": {
            "verdict": both["verdict"],
            "headline": decision["headline"],
            "fault": decision["fault"],
            "candidates": decision["candidates"],
            "isolation": decision["isolation"],
            "element": both["element"],
            "onset_s": rel(both["onset"]),
            "magnitude": _num(both["magnitude"]),
            "methods_agree": bool(both["methods_agree"]),
            "disagreement": decision["disagreement"],
            "seed_method": {
                "verdict": seed.verdict,
                "element": seed.element,
                "onset_s": rel(seed.onset_t),
                "elements": [{"name": e.name, "J_peak": _num(e.J_peak), "gamma2": _num(e.gamma2),
                              "F_peak": _num(e.F_peak), "eta2": _num(e.eta2),
                              "exceed_fraction": float(e.exceed_fraction), "dof": int(e.dof)}
                             for e in seed.elements],
            },
            "glr": {
                "hypothesis": glr.hypothesis,
                "onset_s": rel(glr.onset_t),
                "onset_interval_s": None if interval is None or not glr.detected
                else [rel(interval[0]), rel(interval[1])],
                "magnitude": _num(glr.magnitude),
                "unit": best.get("unit") if glr.detected else None,
                "statistic": float(glr.statistic),
                "threshold": float(glr.threshold),
                "isolation": glr.isolation,
                "runner_up": glr.runner_up,
                "runner_up_statistic": float(glr.runner_up_statistic),
                "residual": None if glr.residual is None else {
                    "hypothesis": glr.residual["hypothesis"],
                    "onset_s": rel(glr.residual["onset_t"]),
                    "statistic": float(glr.residual["statistic"])},
                "statistics": {h: float(v["statistic"])
                               for h, v in glr.per_hypothesis.items()},
            },
        },
    }


def analyze_flight(model: LinearModel, t_ins: Any, v_ins: Any, t_ref: Any, v_ref: Any,
                   r_ref: Any = None, config: AnalysisConfig = AnalysisConfig(), bag: str = "",
                   channel: str = "x", t0: float | None = None) -> dict:
    """The JSON-able summary of :func:`run_analysis`::

        {"bag", "channel", "duration_s", "samples",
         "in_flight": {"gate_threshold", "exceed_fraction", "first_alarm_s",
                       "alarms": [{"start_s", "end_s", "peak_beta2"}]},
         "post_flight": {"verdict", "element", "onset_s", "magnitude", "methods_agree",
                         "seed_method": {"verdict", "element",
                                         "elements": [{"name", "J_peak", "gamma2", "F_peak",
                                                       "eta2", "exceed_fraction", "dof"}]},
                         "glr": {"hypothesis", "onset_s", "magnitude", "statistic",
                                 "threshold"}},
         "input": {"ins_messages", "ref_messages", "invalid_covariance", "dropped_unaligned"}}

    ``*_s`` are seconds from ``t0`` (default: the earliest INS or reference stamp);
    ``duration_s`` is the span of the filtered record. Numbers that are undefined (e.g. the
    Fisher peak of an element without information) are null. How the two methods are combined
    is documented in :func:`combine`.
    """
    return run_analysis(model, t_ins, v_ins, t_ref, v_ref, r_ref, config, bag, channel,
                        t0).summary
