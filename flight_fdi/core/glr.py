"""Generalized likelihood ratio (GLR) fault isolation over the forward innovations
(Willsky & Jones 1976; SPEC section 3, "Beyond the seed").

The forward Kalman filter (``kalman.run_forward``) leaves innovations nu_k with covariances S_k.
A fault of hypothesis h that starts at sample theta with unknown magnitude mu adds ``mu rho_k``
to every later innovation; ``rho_k(theta, h)`` (the *signature*) follows from the filter's own
gains. With ``w_k = S_k^-1 nu_k``::

    num(theta, h) = sum_{k >= theta} rho_k^T S_k^-1 nu_k
    den(theta, h) = sum_{k >= theta} rho_k^T S_k^-1 rho_k
    l(theta, h) = num^2 / den,   mu_hat = num / den,   std(mu_hat) = 1 / sqrt(den)

The isolated fault is the (h, theta) with the largest l (the maximum likelihood choice), when that
l exceeds the one threshold shared by all hypotheses; the sums run to the end of the flight.

Hypotheses (``GlrConfig.hypotheses``)
-------------------------------------
``"<state>_step"`` or ``"step:<state>"`` (``accel_bias_step``, ``gyro_drift_step`` on the INS)
    The instrument error in state j steps by mu at the onset and *stays* there. The model's
    Gauss-Markov decay exp(-dt/tau) describes the slow random wander of a healthy instrument, not
    a hardware fault: a real bias step is a persistent offset added to the instrument's output.
    So the true-state deviation beta is not ``Phi^(k-theta) mu e_j`` (a one-time state jump, which
    would decay with tau) but the solution of ``beta' = A_bar beta``, ``beta(theta) = mu e_j``,
    where ``A_bar`` is A with row j zeroed: beta_j stays mu and the other states respond through
    column j of A (on the INS channel the velocity error ramps after an accelerometer bias step,
    the tilt ramps after a gyro drift step). Magnitude unit: the state's (m/s^2, rad/s).
``"<state>_ramp"`` or ``"ramp:<state>"`` (``accel_bias_ramp``, ``gyro_drift_ramp``)
    The instrument error in state j grows at the rate mu from the onset: the fault state is
    [beta; r] with ``beta' = A_bar beta + e_j r``, ``r' = 0``, ``r(theta) = mu``. Magnitude unit:
    the state's per second (m/s^3, rad/s^2). **On one velocity channel a gyro drift step w and an
    accelerometer bias ramp of -g w have the same signature** (both give V'' = -g V / R - g w):
    no test on velocity alone separates them, so both are reported (``ambiguous``).
``"reference_jump"`` or ``"jump:<measurement>"``
    The measurement z fused by the filter is offset by mu from the onset on. The magnitude is the
    offset of z (on the INS channel z = V_INS - V_ref: a reference velocity that jumps by +d gives
    mu = -d). ``reference_jump`` needs a one-row measurement; name the row otherwise.
``"reference_outlier"`` or ``"outlier:<measurement>"``
    A single-sample measurement fault of size mu at the onset (the signature includes the filter's
    response to having fused it). It is in the default set on purpose: a lone wild sample then
    wins as ``reference_outlier`` instead of being reported as a jump or a step.

Is the fault explained?
-----------------------
The best (h, theta) is reported with confidence (``isolation = "single"``) only when

* no hypothesis of *another sensor* comes within ``ambiguity_margin`` of its statistic
  (else ``"ambiguous"``, both named), and
* a second pass on what it leaves finds nothing: the fitted fault mu rho(theta, h) is removed
  from the innovations and every hypothesis h2 is tested again *given* the first fault
  (the joint fit of both: l2 = n2'^2 / (d22 - d12^2 / d11), chi2(1) per onset when one fault
  explains the data); above the threshold -> ``"unexplained"`` (two faults, or one no
  hypothesis describes). More outliers after the largest one are one ``outliers`` fault.

Signature recursion (exact, time-varying)
-----------------------------------------
With the filter's transitions Phi_k (from k-1 to k, ``model.discretize(dt[k])``), gains K_k
(zero where ``fused[k]`` is False) and H_k; the fault state f (beta for a step, a scalar for a
jump or outlier) and the filter's response d = delta x_hat_{k|k-1}, both zero before theta::

    rho_k = D_k f_k - H_k d_k           (D = H for a state step, D = e_row for a jump/outlier)
    d_{k+1} = Phi_{k+1} (d_k + K_k rho_k)
    f_{k+1} = Psi_{k+1} f_k             (Psi = expm(A_bar dt), 1, 0 for step, jump, outlier)

i.e. ``s_{k+1} = F_k s_k``, ``rho_k = C_k s_k`` with ``s_theta = e_fault``. Hence for *every* onset
at once, by backward (adjoint) recursions::

    lambda_k = C_k^T w_k + F_k^T lambda_{k+1},            num(theta) = e^T lambda_theta
    M_k = C_k^T S_k^-1 C_k + F_k^T M_{k+1} F_k,            den(theta) = e^T M_theta e

and the correlation of neighbouring onsets (for the threshold) is
``<rho(theta), rho(theta+1)>_{S^-1} = e^T M_{theta+1} F_theta e``. This is exact (no stationarity
assumption, any dt, any gain history, gated samples included) and O(N), so no coarse onset grid or
refinement is needed. The recursion is compiled (``core/glr_kernel.py``, one pass over the
samples): the hypothesis-free blocks of M and lambda (the filter's own response) are computed
once per flight, each hypothesis adds its fault-state blocks, and a fault state keeps only the
states the fault can reach (3 of the INS channel's 4 for a step). The arithmetic runs in the
model's scaled coordinates (x' = diag(scale)^-1 x); magnitudes are reported in SI units.

Threshold
---------
Under H0 (healthy system, consistent filter) Z(theta, h) = num / sqrt(den) is exactly N(0, 1) for
each onset, and l = Z^2 ~ chi2(1); but the maximum over all onsets and hypotheses is not. The
threshold u^2 is the smallest value for which a rigorous upper bound on P(max |Z| > u) equals
``p_false_alarm``: the first-crossing union bound (Hunter/Worsley type)::

    P(max_theta |Z_theta| > u) <= P(|Z_0| > u) + sum_theta P(|Z_theta| <= u < |Z_theta+1|)

summed over the hypotheses. Each term is a bivariate normal probability that depends only on the
exact correlation c = <rho(theta), rho(theta+1)>_{S^-1} / sqrt(den den') of neighbouring onsets,
which the same scan delivers; it is evaluated in closed form with Owen's T function. For smooth
signatures (steps: c ~ 0.9999) neighbouring onsets are nearly the same test and cost almost
nothing; for outliers (c ~ 0) the bound reduces to Bonferroni. Being an upper bound, it keeps the
false-alarm probability at most ``p_false_alarm`` when the filter's innovations are white with
covariance S (a mistuned filter on real data violates that premise: check the beta^2 statistics
first). On simulated healthy flights the observed rate is 0.5-0.9 x ``p_false_alarm``.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .errors import CoreError
from .glr_residual import residual_pass
from .glr_system import NONE, each_system, prepare, resolve, systems as _systems
from .glr_kernel import onset_statistics
from .glr_threshold import A_EDGES, first_crossing_probability, threshold as _threshold
from .models import LinearModel
from .threads import usable_threads

__all__ = ["GlrConfig", "GlrResult", "isolate", "first_crossing_probability",
           "DEFAULT_HYPOTHESES", "sensor_of", "kind_of"]

DEFAULT_HYPOTHESES = ("accel_bias_step", "gyro_drift_step", "accel_bias_ramp", "gyro_drift_ramp",
                      "reference_jump", "reference_outlier")
#: chi2(1) 95 % quantile: the onsets whose l is within this of the peak form the onset interval
ONSET_CI_DROP = 3.841458820694124
#: at most this many outlier times are listed in per_hypothesis
MAX_OUTLIER_TIMES = 100


@dataclass(frozen=True)
class GlrConfig:
    """Settings of the GLR isolator.

    p_false_alarm: probability that a healthy flight is reported with a fault (an upper bound,
        see the module docstring).
    hypotheses: fault hypotheses to test (names in the module doc).
    block_size: accepted for compatibility and ignored (the compiled recursion runs over the
        samples in one pass; it was the block length of the former two-level numpy scan).
    curve_points: at most this many points per curve in ``GlrResult.curves`` (the maximum of
        each bin of onsets); 0 = every onset.
    ambiguity_margin: two hypotheses of different sensors whose statistics l differ by less
        than this are reported as ambiguous (l is twice the log-likelihood ratio: the default
        2 ln 100 = 9.21 asks for a likelihood ratio of 100 between the winner and the runner-up).
    residual_test: after the best hypothesis is fitted and removed, test what is left by a
        second GLR pass (see "Is the fault explained?" in the module doc).
    threads: the independent fault systems (one per instrument and the reference's) are
        scanned on this many threads (the compiled kernels release the GIL); 1: in the calling
        thread; None: :func:`~flight_fdi.core.threads.usable_threads` (the cores the process may
        use, 1 on a campaign worker). The results do not depend on it.
    """

    p_false_alarm: float = 1e-3
    hypotheses: tuple = DEFAULT_HYPOTHESES
    block_size: int = 0
    curve_points: int = 4000
    ambiguity_margin: float = 2.0 * float(np.log(100.0))
    residual_test: bool = True
    threads: int | None = None

    def __post_init__(self) -> None:
        p = self.p_false_alarm
        if isinstance(p, (bool, np.bool_)) or not isinstance(p, (int, float, np.integer,
                                                                 np.floating)) \
                or not np.isfinite(p) or not 0.0 < p < 1.0:
            raise CoreError(f"GlrConfig.p_false_alarm must be a number in (0, 1), got {p!r}")
        object.__setattr__(self, "p_false_alarm", float(p))
        hyps = self.hypotheses
        if isinstance(hyps, str) or not isinstance(hyps, (tuple, list)) or not hyps:
            raise CoreError(f"GlrConfig.hypotheses must be a non-empty tuple of names, "
                            f"got {hyps!r}")
        if not all(isinstance(h, str) and h.strip() for h in hyps):
            raise CoreError(f"GlrConfig.hypotheses must be non-empty strings, got {hyps!r}")
        if len(set(hyps)) != len(hyps):
            raise CoreError(f"GlrConfig.hypotheses has duplicates: {hyps!r}")
        if NONE in hyps:
            raise CoreError(f"GlrConfig.hypotheses: {NONE!r} is the no-fault answer, "
                            "not a hypothesis")
        object.__setattr__(self, "hypotheses", tuple(hyps))
        for nm in ("block_size", "curve_points"):
            val = getattr(self, nm)
            if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 0:
                raise CoreError(f"GlrConfig.{nm} must be an integer >= 0, got {val!r}")
        if self.threads is not None and (isinstance(self.threads, bool) or not isinstance(
                self.threads, (int, np.integer)) or self.threads < 1):
            raise CoreError(f"GlrConfig.threads must be an integer >= 1, got {self.threads!r}")
        if self.block_size == 1:
            raise CoreError("GlrConfig.block_size must be 0 (automatic) or >= 2, got 1")
        am = self.ambiguity_margin
        if isinstance(am, bool) or not isinstance(am, (int, float, np.integer, np.floating)) \
                or not np.isfinite(am) or am < 0:
            raise CoreError(f"GlrConfig.ambiguity_margin must be a number >= 0, got {am!r}")
        object.__setattr__(self, "ambiguity_margin", float(am))
        if not isinstance(self.residual_test, (bool, np.bool_)):
            raise CoreError(f"GlrConfig.residual_test must be true or false, got "
                            f"{self.residual_test!r}")


@dataclass(frozen=True)
class GlrResult:
    """Outcome of ``isolate``.

    hypothesis: the isolated fault, or ``"none"`` when the best statistic is below the threshold.
    onset_index / onset_t / magnitude: of the isolated fault (None for "none"); onset_t on fwd.t,
    magnitude in SI units of the hypothesis (state unit for steps, measurement unit for jumps).
    statistic: the largest l over all hypotheses and onsets (also when below the threshold).
    threshold: the threshold on l for ``p_false_alarm``.
    per_hypothesis: for each hypothesis its best onset: dict(onset_index, onset_t, magnitude,
        magnitude_std, statistic, unit).
    curves: for each hypothesis (onset_t array, l array), max-pooled to ``curve_points``.
    runner_up, runner_up_statistic: the best other hypothesis and its statistic (None / 0.0
        with a single hypothesis).
    isolation: ``"none"`` (nothing above the threshold), ``"single"`` (one fault explains the
        data), ``"ambiguous"`` (the runner-up, a hypothesis of another sensor, is within
        ``ambiguity_margin``) or ``"unexplained"`` (the second pass on what the best hypothesis
        leaves still finds a fault above the threshold).
    residual: the second pass: dict(hypothesis, onset_index, onset_t, statistic) of its best
        hypothesis (the statistic conditioned on the first fault), None when not run.
    """

    hypothesis: str
    onset_index: int | None
    onset_t: float | None
    magnitude: float | None
    statistic: float
    threshold: float
    per_hypothesis: dict = field(default_factory=dict)
    curves: dict = field(default_factory=dict)
    runner_up: str | None = None
    runner_up_statistic: float = 0.0
    isolation: str = NONE
    residual: dict | None = None

    @property
    def detected(self) -> bool:
        return self.hypothesis != NONE

    @property
    def confident(self) -> bool:
        """A fault above the threshold that one hypothesis alone explains, clear of the
        runner-up."""
        return self.isolation == "single"

# --------------------------------------------------------------------------------------------

def _pool(t: np.ndarray, l: np.ndarray, points: int):
    if points == 0 or l.size <= points:
        return t.copy(), l.copy()
    size = -(-l.size // points)
    nbin = -(-l.size // size)
    pad = nbin * size - l.size
    lp = np.concatenate([l, np.full(pad, -np.inf)]).reshape(nbin, size)
    arg = np.argmax(lp, axis=1) + np.arange(nbin) * size
    return t[arg], l[arg]


def _best_onset(hyp, t: np.ndarray, num: np.ndarray, den: np.ndarray, l: np.ndarray,
                ok: np.ndarray) -> dict:
    """The hypothesis' entry of ``per_hypothesis``: its largest l, with the onset's 95 %
    profile-likelihood interval (l within chi2(1, 0.95) of the peak)."""
    k = int(np.argmax(l))
    if not ok[k]:
        return {"onset_index": None, "onset_t": None, "onset_interval": None,
                "magnitude": None, "magnitude_std": None, "statistic": 0.0,
                "unit": hyp.unit, "kind": hyp.kind}
    near = np.flatnonzero(l >= l[k] - ONSET_CI_DROP)
    return {"onset_index": k, "onset_t": float(t[k]),
            "onset_interval": (float(t[near[0]]), float(t[near[-1]])),
            "magnitude": float(num[k] / den[k] * hyp.scale),
            "magnitude_std": float(hyp.scale / np.sqrt(den[k])),
            "statistic": float(l[k]), "unit": hyp.unit, "kind": hyp.kind}


def _onset_statistics(num: np.ndarray, den: np.ndarray, cross: np.ndarray,
                      counts: np.ndarray) -> tuple:
    """(l, ok, fresh) of one hypothesis: l = num^2 / den where the onset is a test (den > 0:
    else the fault would leave no trace, e.g. a bias step at the last sample; a tiny but
    positive den is a real test), and the number of onsets that start a run of tests; the
    correlations of neighbouring tests are counted into the threshold's bins ``counts``
    (:func:`.glr_kernel.onset_statistics`)."""
    l, ok = np.empty(num.size), np.empty(num.size, dtype=bool)
    fresh = onset_statistics(num, den, cross, A_EDGES, l, ok, counts)
    return l, ok, fresh


def isolate(model: LinearModel, fwd: Any, config: GlrConfig = GlrConfig()) -> GlrResult:
    """Isolate the fault in a flight from the forward filter's result by GLR (module docstring).

    ``fwd`` is a ``kalman.ForwardResult`` (fields t, dt, nu, S, K, H, fused are used).
    """
    if not isinstance(model, LinearModel):
        raise CoreError(f"isolate: model must be a LinearModel, got {type(model).__name__}")
    if not isinstance(config, GlrConfig):
        raise CoreError(f"isolate: config must be a GlrConfig, got {type(config).__name__}")
    hyps = [resolve(model, h) for h in config.hypotheses]
    flt = prepare(model, fwd)
    systems = _systems(model, hyps)
    threads = config.threads or usable_threads()
    raw = each_system(lambda system: system.scan(flt), systems, threads)
    per: dict[str, dict] = {}
    curves: dict[str, tuple] = {}
    fresh, counts, outlier_l = 0, np.zeros(A_EDGES.size + 1, dtype=np.int64), {}
    for hyp in hyps:
        num, den, cross = raw[hyp.name]
        l, ok, f = _onset_statistics(num, den, cross, counts)
        fresh += f
        per[hyp.name] = _best_onset(hyp, flt.t, num, den, l, ok)
        curves[hyp.name] = _pool(flt.t, l, config.curve_points)
        if hyp.kind == "outlier":
            outlier_l[hyp.name] = l
    threshold = _threshold(fresh, counts, config.p_false_alarm)
    for name, l in outlier_l.items():  # every onset above the threshold is one (c ~ 0)
        over = np.flatnonzero(l > threshold)
        per[name].update(count=int(over.size), onset_interval=None,
                         times=[float(flt.t[k]) for k in over[:MAX_OUTLIER_TIMES]])
    return _verdict(config, systems, flt, raw, per, curves, threshold, threads)


def _verdict(config: GlrConfig, systems: dict, flt, raw: dict, per: dict, curves: dict,
             threshold: float, threads: int) -> GlrResult:
    """The isolated hypothesis and how confidently (module doc, "Is the fault explained?")."""
    ranked = rank_hypotheses(per)
    best = ranked[0]
    runner = ranked[1] if len(ranked) > 1 else None
    stat = per[best]["statistic"]
    extra = {"runner_up": runner,
             "runner_up_statistic": per[runner]["statistic"] if runner else 0.0}
    if not stat > threshold:
        return GlrResult(NONE, None, None, None, stat, threshold, per, curves, **extra)
    b = per[best]
    isolation, residual = "single", None
    rival = next((h for h in ranked[1:] if sensor_of(h) != sensor_of(best)), None)
    if rival is not None and stat - per[rival]["statistic"] < config.ambiguity_margin:
        isolation = "ambiguous"
        extra = {"runner_up": rival, "runner_up_statistic": per[rival]["statistic"]}
    if config.residual_test and isolation == "single":  # (an ambiguous result stays so)
        residual = residual_pass(systems, flt, raw, best, b["onset_index"], threads)
        more_outliers = kind_of(best) == "outliers" and residual["hypothesis"] == best
        if residual["statistic"] > threshold and not more_outliers:
            isolation = "unexplained"
    return GlrResult(best, b["onset_index"], b["onset_t"], b["magnitude"], stat, threshold,
                     per, curves, isolation=isolation, residual=residual, **extra)


def rank_hypotheses(per: dict, rel_tie: float = 1e-9) -> list:
    """Hypothesis names by statistic, largest first. Statistics equal to ``rel_tie`` (relative)
    are a tie -- hypotheses with the same signature, e.g. a gyro drift step and an accelerometer
    bias ramp of -g w on one velocity channel, agree to ~1e-14 and rounding would decide -- and
    a tie keeps the declared order (steps before ramps), so every path (``analyze``, the ROS
    pipeline) names the same hypothesis first."""
    order = {h: i for i, h in enumerate(per)}
    ranked = sorted(per, key=lambda h: per[h]["statistic"], reverse=True)
    out: list = []
    while ranked:
        top = per[ranked[0]]["statistic"]
        tie = [h for h in ranked if top - per[h]["statistic"] <= rel_tie * abs(top)]
        out += sorted(tie, key=order.__getitem__)
        ranked = [h for h in ranked if h not in tie]
    return out


def sensor_of(hypothesis: str) -> str | None:
    """The instrument a hypothesis blames: ``accelerometer`` (accel_bias_*), ``gyro``
    (gyro_drift_*), ``reference`` (reference_* / jump: / outlier:), the stepped state's name
    for other state hypotheses, None for "none"."""
    if hypothesis == NONE:
        return None
    if hypothesis.startswith(("reference_", "jump:", "outlier:")):
        return "reference"
    state = hypothesis[5:] if hypothesis.startswith(("step:", "ramp:")) else hypothesis[:-5]
    return {"accel_bias": "accelerometer", "gyro_drift": "gyro"}.get(state, state)


def kind_of(hypothesis: str) -> str | None:
    """step | ramp | jump | outliers of a hypothesis name (None for "none")."""
    if hypothesis == NONE:
        return None
    if hypothesis.startswith(("reference_outlier", "outlier:")):
        return "outliers"
    if hypothesis.startswith(("reference_jump", "jump:")):
        return "jump"
    return "ramp" if hypothesis.startswith("ramp:") or hypothesis.endswith("_ramp") else "step"
