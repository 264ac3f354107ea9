"""``analyze_ins3d``: the 3-D analysis of one flight -- the forward filter with the beta^2 gate
and the persistence alarm, the observability report, and after the flight the backward
information filter, the two-filter chi^2 J with the seed method's localisation and Fisher test,
and the GLR isolation over the body-axis hypotheses (docs/ins3d.md).

``Ins3dAnalysis.post_flight_dict()`` is the ``post_flight`` section of the result
(``result-v1.schema.json``); the object keeps the time series the figures need (``J``, the GLR
curves per hypothesis, the smoothed body-axis bias estimates with their sd, the turns).
"""
from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np

from ..diagnosis import DiagnosisConfig, SeedDiagnosis
from ..errors import CoreError
from ..kalman import ALARM_RAISED, GateConfig
from .data import NavSteps, RefRows, coarsen
from .defaults import ANALYZE_DEFAULTS as _DEFAULTS
from .filter import Ins3dForward, run_forward
from .glitch import MAX_ROUNDS, Sequential, sequential
from .glr3d import THRESHOLDS, GlrCurve, Isolation, isolate, ref_axes
from .grade_file import diagnosis_config_of, grade_thresholds, resolve_grade, signature_error_of
from .grades import ImuGrade
from .model import IBA, IBG, IPHI, Ins3dModel
from .nonlinear import SMALL_ANGLE_RAD, NonlinearCheck, confirm, corrected, needs_check
from .relinearize import (MAX_PASSES, RELINEARIZE_MPS2, RELINEARIZE_RAD, TOLERANCE_RAD,
                          Relinearization, Validity, largest_attitude, relinearized,
                          velocity_remainder)
from .observability import ObservabilityReport, manoeuvres, observability
from .postflight import Ins3dBackward, glr_curves, resolve, run_backward, seed_method
from .result3d import post_flight
from .turn_on import TurnOn, decide
from .vertical import VerticalLoop


@dataclass
class Ins3dAnalysis:
    model: Ins3dModel
    forward: Ins3dForward
    observability: ObservabilityReport | None
    manoeuvres: list[tuple[float, float, str]]
    steps: NavSteps | None = None            # the step grid the passes ran on
    refs: RefRows | None = None              # the reference updates, sorted
    backward: Ins3dBackward | None = None
    seed: SeedDiagnosis | None = None
    glr: dict[str, GlrCurve] = field(default_factory=dict)
    isolation: Isolation | None = None
    joint: dict[str, np.ndarray] = field(default_factory=dict)   # 3-dof GLR over the onsets
    thresholds: dict[str, float] = field(default_factory=lambda: dict(THRESHOLDS))
    #: turn-on biases (a step best at the first update) and the in-flight decision given them
    #: (``turn_on.decide``; None: none, the decision is the unconditional one)
    turn_on: TurnOn | None = None
    #: the nonlinear check of a large gyro fault (``nonlinear.confirm``; None: not needed)
    nonlinear: NonlinearCheck | None = None
    #: the passes about the smoothed attitude error (``relinearize``; None: small angles)
    relinearization: Relinearization | None = None
    #: whether the model may name a sensor on this flight (``relinearize.Validity``)
    validity: Validity | None = None
    #: reference outliers named: the decision again without their updates (``glitch``;
    #: None: no outliers named, the decision above stands)
    sequential: Sequential | None = None

    @property
    def decided(self) -> "Ins3dAnalysis":
        """The analysis whose decision the result reports: this one, or the flight without
        its reference glitches when that names a fault (``glitch.sequential``)."""
        seq = self.sequential
        return seq.rest if seq is not None and seq.found else self

    @property
    def decision_glr(self) -> dict[str, GlrCurve]:
        """The GLR curves ``isolation`` was decided on: ``glr``, or given the turn-on biases."""
        return self.glr if self.turn_on is None else self.turn_on.curves

    def summary(self) -> dict:
        """Plain numbers for reports and JSON."""
        f = self.forward
        raised = f.t_ref[f.alarm == ALARM_RAISED]
        names = ref_axes(self.model.height_row)[:self.model.rows]
        out = {
            "model": "ins3d", "grade": self.model.grade.name, "states": list(self.model.names),
            "updates": int(f.beta2.size), "beta2_mean": float(f.beta2.mean()),
            "beta2_row_mean": dict(zip(names, map(float, f.beta2_row.mean(axis=0)))),
            "gate_exceeded_fraction": float(f.exceeded.mean()),
            "alarms_raised_s": [float(t) for t in raised],
            "final_state": dict(zip(self.model.names, map(float, f.x[-1]))),
            "final_sd": dict(zip(self.model.names, map(float, f.sd[-1]))),
            "manoeuvres": [list(m) for m in self.manoeuvres],
        }
        if self.observability is not None:
            out["observability"] = self.observability.excited_at
        return out

    def post_flight_dict(self, t0: float = 0.0) -> dict:
        """The ``post_flight`` section (times relative to ``t0``)."""
        if self.seed is None or self.isolation is None:
            raise CoreError("analyze_ins3d ran without the post-flight part (post=False)")
        seq = self.sequential
        if seq is not None:
            return seq.post_flight(None if seq.found else self._decision_dict(t0), t0)
        out = self._decision_dict(t0)
        out["glitches"] = []
        return out

    def _decision_dict(self, t0: float) -> dict:
        """``post_flight`` of this analysis' own decision (without ``glitches``)."""
        turn_on = None if self.turn_on is None else \
            self.turn_on.records(self.glr, self.thresholds, t0)
        out = post_flight(self.decision_glr, self.isolation, self.seed, self.thresholds, t0,
                          turn_on, self.nonlinear)
        rel = self.relinearization
        out["relinearization"] = None if rel is None else rel.record()
        out["model_validity"] = None if self.validity is None else self.validity.record()
        out["glr"]["joint"] = {k: float(v.max(initial=0.0)) for k, v in self.joint.items()}
        return out

    # ---- series for the figures
    @property
    def t_J(self) -> np.ndarray:
        """Times of the chi^2 series (boundaries with reference updates)."""
        return self.seed.t

    @property
    def J(self) -> np.ndarray:
        """Two-filter chi^2 J(t) (its effective dof: ``seed.dof``, bound ``seed.gamma2``)."""
        return self.seed.J

    def bias_estimates(self) -> dict[str, np.ndarray]:
        """At the update times (SI): the smoothed body-axis bias states of the no-fault model
        with their sd (``accelerometer``, ``gyro``, ``*_sd``: the slow bias model follows a
        step only partly) and the isolated fault's profile per axis (``*_fault``: the step or
        ramp of the result's ``fault`` record (``post_flight_dict``) from its onset, zero
        elsewhere and without an isolated IMU fault). The record is the one source: its onset
        and magnitude are the linear GLR's, or the exact fit's when the nonlinear check of a
        large gyro fault named it (``nonlinear.confirm``), so the figures draw what the result
        says. After a reference glitch's updates were removed and the rest named the fault
        (``decided``), the smoothed states are those of the rest."""
        b = self.decided.backward
        out = {"t": b.t, "accelerometer": b.x_s[:, IBA:IBA + 3],
               "accelerometer_sd": b.sd_s[:, IBA:IBA + 3], "gyro": b.x_s[:, IBG:IBG + 3],
               "gyro_sd": b.sd_s[:, IBG:IBG + 3],
               "accelerometer_fault": np.zeros((b.t.size, 3)),
               "gyro_fault": np.zeros((b.t.size, 3))}
        f = self.post_flight_dict()["fault"] if self.seed is not None and \
            self.isolation is not None else None
        if f and f["sensor"] in ("accelerometer", "gyro") and f["kind"] in ("step", "ramp") \
                and f["onset_s"] is not None and f["magnitude"] is not None:
            t0 = f["onset_s"]                           # t0 = 0: the times of b.t
            on = b.t >= t0
            shape = np.where(on, 1.0, 0.0) if f["kind"] == "step" else \
                np.where(on, b.t - t0, 0.0)
            out[f["sensor"] + "_fault"][:, "xyz".index(f["axis"])] = f["magnitude"] * shape
        return out

    def as_recorded(self) -> tuple[NavSteps, RefRows, Ins3dForward]:
        """The steps, updates and forward pass of the flight as recorded (before a
        relinearisation: what a fault is removed from exactly)."""
        rel = self.relinearization
        return (self.steps, self.refs, self.forward) if rel is None else \
            (rel.steps, rel.refs, rel.forward)

    def turns(self) -> list[tuple[float, float]]:
        return [(a, b) for a, b, kind in self.manoeuvres if kind == "turn"]


def initial_covariance(model: Ins3dModel, C0: np.ndarray, f0: np.ndarray, lat0: float,
                       aligned: bool = True) -> np.ndarray:
    """P0 at the first step (attitude C0, specific force f0 in the navigation frame, latitude
    lat0): a levelled INS's (``Ins3dModel.p0_aligned``: the tilt cancels the horizontal
    accelerometer bias) when ``aligned``, else independent states (``Ins3dModel.p0``)."""
    return model.p0_aligned(C0, f0, lat0) if aligned else np.diag(model.p0())


def analyze_ins3d(steps: NavSteps, refs: RefRows, grade: str | ImuGrade = "navigation",
                  rows: int = 3,
                  position: bool = False, vertical: str = _DEFAULTS["vertical"],
                  latency: bool = _DEFAULTS["latency"],
                  ref_markov: tuple[float, float, float] | None = _DEFAULTS["ref_markov"],
                  gate: GateConfig = GateConfig(), aligned_prior: bool = _DEFAULTS["aligned_prior"],
                  post: bool = True, max_dt: float | None = 0.1,
                  thresholds: dict[str, float] | None = None,
                  diagnosis: DiagnosisConfig | None = None,
                  with_observability: bool = True,
                  loop: VerticalLoop | None = None,
                  signature_error: float | None = None,
                  height_row: bool = False,
                  v0_sigma_up: float | None = None,
                  h0_sigma: float | None = None,
                  glitch_rounds: int = MAX_ROUNDS) -> Ins3dAnalysis:
    """The 3-D analysis of one flight (see ``bagio.ins3d_input`` for the inputs from a bag or a
    simulated flight). ``grade``: an ImuGrade, a preset name or a YAML grade file
    (``grade_file.resolve_grade``). ``max_dt``: the steps are merged onto the reference grid, at
    least every ``max_dt`` s (``data.coarsen``; None: the input grid). ``post``: also the
    post-flight part (backward sweep, seed method, GLR isolation). ``thresholds``: GLR
    thresholds per kind (default: the grade's for the flight's length,
    ``grade_file.grade_thresholds``). ``loop``: the INS height loop of ``vertical="loop"``
    (default: the simulator's baro loop, its gains at the first step's latitude and height).
    ``signature_error``: the relative error of the model's fault signatures on this kind of
    flight, which a confident isolation must leave room for (``glr3d.settle``; default the
    grade's: a grade file's ``signature_error_rad``, else its axis misalignment).
    ``height_row``: the third reference row is a height reference (``data.with_height``; needs
    ``rows=3`` and ``position=True``); ``v0_sigma_up``: the initial vertical velocity error's
    sigma (m/s) of a free vertical channel (default: the horizontal ones'); ``h0_sigma``: the
    initial height error's sigma (m; default the position's 5 m: ``bagio.height_input``'s datum).
    ``diagnosis``: the seed method's rules (default ``grade_file.diagnosis_config_of`` the
    grade: a grade file's ``seed_episode_probability``, else ``DiagnosisConfig()``).
    ``glitch_rounds``: when reference outliers are named, the rounds of removing their updates
    and deciding again on the rest (``glitch.sequential``; 0: the decision as it was before)."""
    if vertical == "loop" and steps.t.size:
        base = loop or VerticalLoop()
        loop = replace(base, lat=float(steps.lat[0]), h=float(steps.h[0]))
    model = Ins3dModel.from_grade(resolve_grade(grade), position=position, rows=rows,
                                  vertical=vertical,
                                  latency=latency, ref_markov=ref_markov, loop=loop,
                                  height_row=height_row, v0_sigma_up=v0_sigma_up,
                                  h0_sigma=h0_sigma)
    if refs.t.size == 0:
        raise CoreError("ins3d analysis: no reference update inside the INS record")
    order = np.argsort(refs.step, kind="stable")
    refs = RefRows(refs.t[order], np.ascontiguousarray(refs.z[order]),
                   np.ascontiguousarray(refs.r[order]), refs.step[order],
                   np.ascontiguousarray(refs.a[order]))
    turns = manoeuvres(steps)
    if max_dt is not None:
        steps, refs = coarsen(steps, refs, max_dt)
    P0 = initial_covariance(model, steps.C[0], steps.f_n[0], float(steps.lat[0]), aligned_prior)
    with ThreadPoolExecutor(max_workers=1) as pool:     # the second core: the Gramian
        obs = pool.submit(observability, model, steps, refs, P0=P0) if with_observability \
            else None
        fwd = run_forward(model, steps, refs, gate=gate, P0=P0, keep_prior=post,
                          threads=1 if obs is not None else None)   # one thread per core
        out = Ins3dAnalysis(model, fwd, None, turns, steps, refs,
                            thresholds=grade_thresholds(model.grade,
                                                        float(steps.t[-1] - steps.t[0])))
        if thresholds is not None:
            out.thresholds.update(thresholds)
        if post:
            cfg = diagnosis or diagnosis_config_of(model.grade)
            _post(out, gate, aligned_prior, cfg, signature_error)
            out.sequential = sequential(
                out, lambda rest: _decide_without(out, rest, gate, aligned_prior, cfg,
                                                  signature_error),
                out.as_recorded()[1], lambda a: _curves_given_fault(a, cfg.rank_tol),
                glitch_rounds)
        out.observability = obs.result() if obs is not None else None
    return out


def _post(out: Ins3dAnalysis, gate: GateConfig, aligned_prior: bool, cfg: DiagnosisConfig,
          signature_error: float | None) -> None:
    """The post-flight part on ``out``'s steps, updates and forward pass: the backward sweep,
    the relinearisation when the errors leave small angles, the decision."""
    out.backward = run_backward(out.model, out.steps, out.refs, out.forward, cfg.rank_tol)
    _relinearize(out, gate, aligned_prior, cfg.rank_tol)
    _post_flight(out, cfg, signature_error)


def _decide_without(out: Ins3dAnalysis, refs: RefRows, gate: GateConfig, aligned_prior: bool,
                    cfg: DiagnosisConfig, signature_error: float | None) -> Ins3dAnalysis:
    """The analysis of ``out``'s flight (as recorded) with the updates ``refs`` (the rest
    after reference glitches were removed, ``glitch.sequential``): the forward filter from the
    same P0, then ``_post`` -- the path of ``analyze_ins3d``; the same thresholds."""
    steps, _, fwd0 = out.as_recorded()
    fwd = run_forward(out.model, steps, refs, gate=gate, P0=fwd0.P0, keep_prior=True)
    rest = Ins3dAnalysis(out.model, fwd, None, out.manoeuvres, steps, refs,
                         thresholds=dict(out.thresholds))
    _post(rest, gate, aligned_prior, cfg, signature_error)
    return rest


def _relinearize(out: Ins3dAnalysis, gate: GateConfig, aligned_prior: bool,
                 rank_tol: float) -> None:
    """When the first pass's smoothed attitude error leaves small angles: passes about it
    (``relinearize``), each kept while it raises the no-fault likelihood; ``out``'s steps,
    updates, forward filter and backward sweep become the best pass's."""
    first = largest_attitude(out.backward.x_s)
    if first <= RELINEARIZE_RAD and velocity_remainder(out.backward.x_s) <= RELINEARIZE_MPS2:
        return
    model = out.model
    rel = Relinearization(out.steps, out.refs, out.forward, [first],
                          [out.forward.neg2_log_likelihood()])
    x_s = out.backward.x_s
    for _ in range(MAX_PASSES):
        steps, refs = relinearized(model, rel.steps, rel.refs, x_s)
        P0 = initial_covariance(model, steps.C[0], steps.f_n[0], float(steps.lat[0]),
                                aligned_prior)
        fwd = run_forward(model, steps, refs, gate=gate, P0=P0, keep_prior=True)
        nll = fwd.neg2_log_likelihood()
        if nll >= rel.neg2_log_likelihood[-1]:
            break
        bwd = run_backward(model, steps, refs, fwd, rank_tol)
        out.steps, out.refs, out.forward, out.backward = steps, refs, fwd, bwd
        rel.attitude_max_rad.append(largest_attitude(bwd.x_s))
        rel.neg2_log_likelihood.append(nll)
        moved = float(np.abs(bwd.x_s[:, IPHI:IPHI + 3] - x_s[:, IPHI:IPHI + 3]).max())
        x_s = bwd.x_s
        if moved <= TOLERANCE_RAD:
            break
    out.relinearization = rel


def _post_flight(out: Ins3dAnalysis, cfg: DiagnosisConfig,
                 signature_error: float | None = None) -> None:
    model, steps, refs, fwd = out.model, out.steps, out.refs, out.forward
    out.seed = seed_method(model, out.backward, cfg)
    out.glr = glr_curves(model, steps, out.backward)
    out.joint = out.backward.joint
    out.isolation = isolate(out.glr, out.thresholds)
    out.turn_on = decide(model, steps, refs, fwd, out.backward, out.glr, out.isolation,
                         out.thresholds, signature_error)
    if out.turn_on is not None:
        out.isolation = out.turn_on.isolation
    else:
        resolve(model, steps, refs, fwd, out.glr, out.isolation, signature_error)
    # relinearised (the no-fault estimate about which the signatures were taken absorbs part
    # of a fault): every confident gyro decision is checked, whatever angle it implies
    limit = 0.0 if out.relinearization is not None and out.isolation.isolation == "single" \
        else SMALL_ANGLE_RAD
    if needs_check(out.decision_glr, out.isolation, float(steps.t[-1]), limit):
        steps, refs, fwd = out.as_recorded()    # the exact removal: from the flight as recorded
        out.nonlinear = confirm(model, steps, refs, fwd, out.decision_glr, out.isolation,
                                signature_error_of(model.grade)
                                if signature_error is None else signature_error,
                                rank_tol=None if out.relinearization is None else
                                cfg.rank_tol)
    out.validity = _validity(out)
    iso = out.isolation            # beyond the (relinearised) model: no confident name
    if not out.validity.valid and iso.isolation == "single" and iso.rival is not None \
            and out.decision_glr[iso.best].hypothesis.kind != "outliers":
        iso.isolation, iso.reason = "ambiguous", "attitude"


def _validity(out: Ins3dAnalysis) -> Validity:
    """The model's validity on the flight (``relinearize.Validity``): of the smoothed errors;
    when those are beyond it and an IMU fault is named, of the forward filter on the flight as
    recorded with that fault removed exactly (``_without_fault``) -- a large fault leaves a
    large attitude error in the no-fault model's estimate; what matters is what is left if it
    is the cause."""
    valid = Validity.of(out.backward.x_s)
    if valid.valid:
        return valid
    rest = _without_fault(out)
    return valid if rest is None else Validity.of(run_forward(out.model, rest[0], rest[1],
                                                              P0=rest[2]).x)


def _without_fault(out: Ins3dAnalysis) -> tuple[NavSteps, RefRows, np.ndarray] | None:
    """The flight as recorded with the named IMU fault removed exactly (``nonlinear.corrected``;
    the nonlinear check's fit, else the GLR's onset and magnitude), and the initial covariance;
    None unless the decision is a single accelerometer or gyro step or ramp."""
    iso = out.isolation
    if iso.isolation != "single":
        return None
    c = out.decision_glr[iso.best]
    h = c.hypothesis
    if h.sensor not in ("accelerometer", "gyro") or h.kind not in ("step", "ramp"):
        return None
    fit = None if out.nonlinear is None else out.nonlinear.fit_of(iso.best)
    onset, mag = (fit.onset, fit.magnitude) if fit else (float(c.t[c.best]), float(c.mag[c.best]))
    steps, refs, fwd = out.as_recorded()
    k0 = int(np.searchsorted(steps.t, onset))
    s2, r2 = corrected(out.model, steps, refs, h.sensor, h.axis, h.kind, k0, mag)
    return s2, r2, fwd.P0


def _curves_given_fault(out: Ins3dAnalysis, rank_tol: float) -> dict[str, GlrCurve] | None:
    """The GLR curves of the flight with the named fault removed exactly (``_without_fault``),
    when reference outliers exceed their threshold beside it: whether they are that fault's
    own effect or a glitch of their own (``glitch.sequential``). None when no outlier exceeds
    it, or the decision is not a single IMU step / ramp (nor one given a turn-on bias: that
    bias would stay in the flight). Like ``_validity``, the flight without the fault is taken
    with the model about zero errors (what is left if the fault is the cause)."""
    if out.isolation.outliers == 0 or out.turn_on is not None:
        return None
    rest = _without_fault(out)
    if rest is None:
        return None
    steps, refs, P0 = rest
    fwd = run_forward(out.model, steps, refs, P0=P0, keep_prior=True)
    return glr_curves(out.model, steps, run_backward(out.model, steps, refs, fwd, rank_tol))


__all__ = ["Ins3dAnalysis", "analyze_ins3d", "initial_covariance"]
