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
refinement is needed. To avoid a Python loop over all N samples it is evaluated as a two-level
scan: the samples are cut into blocks of ~sqrt(N); all blocks run their local recursion
simultaneously (vectorized), then one short pass over the blocks joins them through the blocks'
transfer matrices. A 3-hour flight at 10 Hz (108 000 samples, 4 states, 4 hypotheses) takes about
0.5 s. The arithmetic runs in the model's scaled coordinates (x' = diag(scale)^-1 x); magnitudes
are reported in SI units.

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
from scipy.linalg import expm
from scipy.special import erfc, owens_t

from .errors import CoreError
from .models import LinearModel

__all__ = ["GlrConfig", "GlrResult", "isolate", "first_crossing_probability",
           "DEFAULT_HYPOTHESES", "sensor_of", "kind_of"]

DEFAULT_HYPOTHESES = ("accel_bias_step", "gyro_drift_step", "accel_bias_ramp", "gyro_drift_ramp",
                      "reference_jump", "reference_outlier")
NONE = "none"
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
    block_size: samples per block of the two-level scan; 0 = automatic (about sqrt(N)). Changes
        only the speed, not the result (beyond rounding).
    curve_points: at most this many points per curve in ``GlrResult.curves`` (the maximum of
        each bin of onsets); 0 = every onset.
    ambiguity_margin: two hypotheses of different sensors whose statistics l differ by less
        than this are reported as ambiguous (l is twice the log-likelihood ratio: the default
        2 ln 100 = 9.21 asks for a likelihood ratio of 100 between the winner and the runner-up).
    residual_test: after the best hypothesis is fitted and removed, test what is left by a
        second GLR pass (see "Is the fault explained?" in the module doc).
    """

    p_false_alarm: float = 1e-3
    hypotheses: tuple = DEFAULT_HYPOTHESES
    block_size: int = 0
    curve_points: int = 4000
    ambiguity_margin: float = 2.0 * float(np.log(100.0))
    residual_test: bool = True

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
# hypotheses

@dataclass(frozen=True)
class _Hypothesis:
    name: str
    kind: str  # "step" | "ramp" | "jump" | "outlier"
    index: int  # state index (step) or measurement row (jump/outlier)
    unit: str
    scale: float  # SI units per scaled unit of the magnitude


def _measurement_unit(model: LinearModel, row: int) -> str:
    h = model.H[row]
    nz = np.flatnonzero(h)
    return model.state_units[nz[0]] if nz.size == 1 and h[nz[0]] == 1.0 else ""


def _resolve(model: LinearModel, name: str) -> _Hypothesis:
    def state(sname: str, kind: str = "step") -> _Hypothesis:
        if sname not in model.state_names:
            raise CoreError(
                f"GlrConfig.hypotheses: {name!r} needs a state {sname!r}; model {model.name!r} has "
                f"states {', '.join(model.state_names)} (use '{kind}:<state>')")
        j = model.state_names.index(sname)
        unit = model.state_units[j]
        if kind == "ramp":  # per second: m/s^2 -> m/s^3, rad/s -> rad/s^2
            unit = (unit[:-4] + "/s^3" if unit.endswith("/s^2") else
                    unit[:-2] + "/s^2" if unit.endswith("/s") else unit + "/s")
        return _Hypothesis(name, kind, j, unit, float(model.scale[j]))

    def row(kind: str, mname: str | None) -> _Hypothesis:
        if mname is None:
            if model.m != 1:
                raise CoreError(
                    f"GlrConfig.hypotheses: {name!r} needs a one-row measurement; model "
                    f"{model.name!r} measures {', '.join(model.measurement_names)} "
                    f"(use '{kind}:<measurement>')")
            r = 0
        elif mname in model.measurement_names:
            r = model.measurement_names.index(mname)
        else:
            raise CoreError(f"GlrConfig.hypotheses: {name!r}: model {model.name!r} has no "
                            f"measurement {mname!r}; measurements are "
                            f"{', '.join(model.measurement_names)}")
        return _Hypothesis(name, kind, r, _measurement_unit(model, r), 1.0)

    if name.startswith("step:"):
        return state(name[5:])
    if name.startswith("ramp:"):
        return state(name[5:], "ramp")
    if name.startswith("jump:"):
        return row("jump", name[5:])
    if name.startswith("outlier:"):
        return row("outlier", name[8:])
    if name == "reference_jump":
        return row("jump", None)
    if name == "reference_outlier":
        return row("outlier", None)
    if name.endswith("_step"):
        return state(name[:-5])
    if name.endswith("_ramp"):
        return state(name[:-5], "ramp")
    raise CoreError(f"GlrConfig.hypotheses: unknown hypothesis {name!r}; use '<state>_step', "
                    f"'step:<state>', '<state>_ramp', 'ramp:<state>', 'reference_jump', "
                    f"'jump:<measurement>', 'reference_outlier' or 'outlier:<measurement>'")


# --------------------------------------------------------------------------------------------
# the forward result

def _field(fwd: Any, name: str, shape: tuple, what: str = "") -> np.ndarray:
    if not hasattr(fwd, name):
        raise CoreError(f"isolate: the forward result has no field {name!r}")
    arr = np.asarray(getattr(fwd, name))
    if arr.shape != shape:
        raise CoreError(f"isolate: forward result field {name!r} has shape {arr.shape}, "
                        f"expected {shape}{what}")
    return arr


def _expm_table(A_s: np.ndarray, dt_values: np.ndarray, at_anchor) -> np.ndarray:
    """expm(A_s dt) for every distinct dt (sorted), A_s in scaled coordinates.

    Jittered time stamps make nearly every dt distinct. Rather than one exponential per sample,
    the dts are binned by h = 1e-3 / ||A_s||_1; ``at_anchor(d)`` gives the exponential at the
    smallest dt of each bin, and the remainder delta < h is applied as six Taylor terms of
    expm(A_s delta): ||A_s delta|| < 1e-3 makes their truncation error (< 1e-21 / 7!) far below
    rounding. A constant dt is one bin with delta = 0, i.e. exactly ``at_anchor(dt)``."""
    norm = float(np.abs(A_s).sum(axis=0).max())
    bins = np.floor(dt_values * (norm / 1e-3)) if norm > 0 else np.zeros(dt_values.size)
    _, first, inverse = np.unique(bins, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    anchors = dt_values[first]
    table = np.stack([at_anchor(float(d)) for d in anchors])[inverse]
    delta = dt_values - anchors[inverse]
    rest = np.flatnonzero(delta != 0.0)
    if rest.size:
        n = A_s.shape[0]
        X = A_s[None, :, :] * delta[rest, None, None]
        E = np.broadcast_to(np.eye(n), X.shape).copy()
        for i in range(6, 0, -1):  # Horner: I + X (I + X/2 (I + ... (I + X/6)))
            E = np.eye(n) + (X / i) @ E
        table[rest] = table[rest] @ E
    return table


def _mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched a @ b over the leading axes by a broadcast sum: much faster than matmul when the
    inner dimension (here m, the measurement rows) is tiny."""
    return np.sum(a[..., :, :, None] * b[..., None, :, :], axis=-2)


@dataclass
class _Filter:
    """The forward filter's arrays in scaled coordinates for the step k -> k+1, cut into ``nb``
    blocks of ``B`` samples and stored position-major: sample k = b B + j is at [j, b], so that
    one position of all blocks is contiguous. Entries for the last sample and the padding beyond
    it never reach a result (nothing is measured after them) and are merely kept finite."""

    t: np.ndarray  # (N,)
    nb: int
    B: int
    PhiN: np.ndarray  # (B, nb, n, n) Phi'_{k+1}
    A: np.ndarray  # (B, nb, n, n) Phi'_{k+1} (I - K'_k H'_k)
    G: np.ndarray  # (B, nb, n, m) Phi'_{k+1} K'_k  (zero where not fused)
    H: np.ndarray  # (B, nb, m, n) H'_k
    Sinv: np.ndarray  # (B, nb, m, m), zero where the sample is missing or padding
    w: np.ndarray  # (B, nb, m) S^-1 nu, zero where the sample is missing or padding
    dt_key: np.ndarray  # (B, nb) index of dt[k+1] into dt_values
    dt_values: np.ndarray  # distinct dt (rounded to 1 ns like LinearModel.discretize)
    shared: dict = field(default_factory=dict)  # arrays common to several hypotheses


def _prepare(model: LinearModel, fwd: Any, block_size: int) -> _Filter:
    n, m = model.n, model.m
    t = np.asarray(getattr(fwd, "t", None), dtype=float) if hasattr(fwd, "t") else None
    if t is None or t.ndim != 1 or t.size == 0:
        raise CoreError("isolate: the forward result needs a non-empty 1-D time array 't'")
    N = t.size
    dt = _field(fwd, "dt", (N,)).astype(float)
    nu = _field(fwd, "nu", (N, m), f" (model {model.name!r} has m = {m})").astype(float)
    S = _field(fwd, "S", (N, m, m)).astype(float)
    K = _field(fwd, "K", (N, n, m), f" (model {model.name!r} has n = {n})").astype(float)
    H = _field(fwd, "H", (N, m, n)).astype(float)
    fused = _field(fwd, "fused", (N,)).astype(bool)
    if not np.all(np.isfinite(t)):
        raise CoreError("isolate: forward result time 't' contains NaN or Inf")
    if N > 1 and (not np.all(np.isfinite(dt[1:])) or np.any(dt[1:] < 0)):
        raise CoreError("isolate: forward result 'dt' must be finite and >= 0")
    valid = np.all(np.isfinite(nu), axis=1) & np.all(np.isfinite(S), axis=(1, 2))
    if np.any(fused & ~valid):
        k = int(np.flatnonzero(fused & ~valid)[0])
        raise CoreError(f"isolate: sample {k} was fused but its innovation or S is not finite")
    if not np.all(np.isfinite(K[fused])) or not np.all(np.isfinite(H)):
        raise CoreError("isolate: forward result gains 'K' (where fused) or 'H' are not finite")

    B = block_size if block_size else max(8, int(np.ceil(np.sqrt(N))))
    B = max(1, min(B, N))
    nb = -(-N // B)
    Np = nb * B
    # position-major order: entry j * nb + b holds sample b * B + j (>= N: padding)
    order = np.arange(Np).reshape(nb, B).T.reshape(-1)
    real = order < N
    src = np.minimum(order, N - 1)

    sc = model.scale
    Hs = H[src] * sc  # H' = H T
    Ks = np.where((fused[src] & real)[:, None, None], K[src] / sc[:, None], 0.0)  # K' = T^-1 K
    Sinv = np.zeros((Np, m, m))
    w = np.zeros((Np, m))
    use = valid[src] & real
    if np.any(use):
        try:
            Sinv[use] = np.linalg.inv(S[src[use]])
        except np.linalg.LinAlgError:
            raise CoreError("isolate: an innovation covariance S is singular") from None
        w[use] = np.einsum("kij,kj->ki", Sinv[use], nu[src[use]])

    if N > 1:
        dt_values, inverse = np.unique(np.round(dt[1:], 9), return_inverse=True)
        key = np.zeros(N, dtype=np.intp)
        key[:-1] = inverse.reshape(-1)
        dt_key = key[src]
    else:
        dt_values, dt_key = np.zeros(1), np.zeros(Np, dtype=np.intp)
    # the filter's transitions (model.discretize, the agreed interface), scaled: T^-1 Phi T
    A_s = model.A / sc[:, None] * sc[None, :]
    table = _expm_table(A_s, dt_values,
                        lambda d: model.discretize(d)[0] / sc[:, None] * sc[None, :])
    PhiN = table[dt_key]
    G = _mul(PhiN, Ks)
    A = PhiN - _mul(G, Hs)

    def blocks(a: np.ndarray) -> np.ndarray:
        return a.reshape((B, nb) + a.shape[1:])

    return _Filter(t, nb, B, blocks(PhiN), blocks(A), blocks(G), blocks(Hs), blocks(Sinv),
                   blocks(w), blocks(dt_key), dt_values)


class _System:
    """Signature system s = [f; d] of one hypothesis: ``column(j)`` gives F_k, C_k^T S_k^-1 C_k
    and C_k^T S_k^-1 nu_k for the samples k = b B + j of every block b; the fault enters as the
    unit vector e_i0 of s."""

    def __init__(self, model: LinearModel, hyp: _Hypothesis, flt: _Filter) -> None:
        self.flt = flt
        B, nb, m, n = flt.H.shape
        self.kind = hyp.kind
        self.m = m
        sh = flt.shared
        if hyp.kind in ("step", "ramp"):
            j = hyp.index
            ramp = hyp.kind == "ramp"
            # a ramp carries its rate r as one more fault state: beta_j' = r, r' = 0
            self.q, self.i0 = n + ramp, (n if ramp else j)
            Abar = np.array(model.A, dtype=float)
            Abar[j, :] = 0.0  # the instrument error stays at the step: beta_j' = 0
            sc = model.scale
            Abar_s = np.zeros((self.q, self.q))
            Abar_s[:n, :n] = Abar / sc[:, None] * sc[None, :]
            if ramp:
                Abar_s[j, n] = 1.0  # (r in scaled units of state j per second)
            self.psi_table = _expm_table(Abar_s, flt.dt_values, lambda d: expm(Abar_s * d))
            if hyp.kind not in sh:
                parts = [flt.H] + ([np.zeros(flt.H.shape[:3] + (1,))] if ramp else []) \
                    + [-flt.H]
                C = np.concatenate(parts, axis=3)  # [H', (0,) -H'], (B, nb, m, p)
                GD = flt.PhiN - flt.A  # G_k H'_k
                if ramp:
                    GD = np.concatenate([GD, np.zeros(GD.shape[:3] + (1,))], axis=3)
                sh[hyp.kind] = (GD, np.ascontiguousarray(np.swapaxes(C, 2, 3)),  # C^T
                                _mul(flt.Sinv, C),  # S^-1 C
                                np.sum(C * flt.w[..., :, None], axis=-2))  # C^T S^-1 nu
            self.GD, self.Ct, self.SC, self.c = sh[hyp.kind]
        else:
            r = hyp.index
            self.q, self.i0 = 1, 0
            C = np.zeros((B, nb, m, 1 + n))
            C[:, :, r, 0] = 1.0
            C[:, :, :, 1:] = -flt.H
            self.Ct = np.ascontiguousarray(np.swapaxes(C, 2, 3))
            self.SC = _mul(flt.Sinv, C)  # S^-1 C
            self.c = np.sum(C * flt.w[..., :, None], axis=-2)  # C^T S^-1 nu, (B, nb, p)
            self.Gr = np.ascontiguousarray(flt.G[:, :, :, r])
        self.p = self.q + n
        F = np.zeros((nb, self.p, self.p))
        self._psi_varies = False
        if hyp.kind in ("step", "ramp"):
            if flt.dt_values.size == 1:
                F[:, :self.q, :self.q] = self.psi_table[0]
            else:
                self._psi_varies = True
        elif hyp.kind == "jump":
            F[:, 0, 0] = 1.0  # the offset persists (outlier: 0, it is gone after one sample)
        self._F = F

    def column(self, j: int, with_q: bool = True):
        flt, q, F = self.flt, self.q, self._F
        if self.kind in ("step", "ramp"):
            if self._psi_varies:
                F[:, :q, :q] = self.psi_table[flt.dt_key[j]]
            F[:, q:, :q] = self.GD[j]
        else:
            F[:, q:, 0] = self.Gr[j]
        F[:, q:, q:] = flt.A[j]
        if not with_q:
            return F, None, self.c[j]
        Q = self.Ct[j] * self.SC[j] if self.m == 1 else self.Ct[j] @ self.SC[j]
        return F, Q, self.c[j]


# --------------------------------------------------------------------------------------------
# the two-level backward scan

def _scan(system: _System):
    """For every onset theta, with s_theta = e_i0:
    num = e^T lambda_theta, den = e^T M_theta e, cross = <rho(theta), rho(theta+1)>_{S^-1}.
    See the module docstring for the recursions. Returns arrays of nb * B entries."""
    nb, B = system.flt.nb, system.flt.B
    p, i0 = system.p, system.i0
    lam = np.zeros((nb, p, 1))
    M = np.zeros((nb, p, p))
    T = np.broadcast_to(np.eye(p), (nb, p, p)).copy()
    num_loc = np.empty((B, nb))
    den_loc = np.empty((B, nb))
    cross_loc = np.empty((B, nb))
    v = np.empty((B, nb, p))
    for j in range(B - 1, -1, -1):
        F, Q, c = system.column(j)
        Ft = np.swapaxes(F, 1, 2)
        MF = M @ F
        cross_loc[j] = MF[:, i0, i0]  # e^T local_{k+1} F_k e
        M = Ft @ MF
        M += Q
        lam = Ft @ lam
        lam[:, :, 0] += c
        T = T @ F  # maps s_k to the state at the end of the block
        num_loc[j] = lam[:, i0, 0]
        den_loc[j] = M[:, i0, i0]
        v[j] = T[:, :, i0]
    # join the blocks: lambda and M at the end of every block (= start of the next one)
    lam = lam[:, :, 0]
    lam_e = np.zeros((nb, p))
    M_e = np.zeros((nb, p, p))
    for b in range(nb - 2, -1, -1):
        Tn = T[b + 1]
        lam_e[b] = lam[b + 1] + Tn.T @ lam_e[b + 1]
        M_e[b] = M[b + 1] + Tn.T @ M_e[b + 1] @ Tn
    num = num_loc + np.einsum("jbp,bp->jb", v, lam_e)
    Mv = (M_e @ np.transpose(v, (1, 2, 0))).transpose(2, 0, 1)  # (B, nb, p): M_e v
    den = den_loc + np.einsum("jbp,jbp->jb", v, Mv)
    vnext = np.empty_like(v)
    vnext[:-1] = v[1:]
    vnext[-1] = 0.0
    vnext[-1, :, i0] = 1.0
    cross = cross_loc + np.einsum("jbp,jbp->jb", vnext, Mv)
    # back to sample order k = b B + j
    return num.T.reshape(-1), den.T.reshape(-1), cross.T.reshape(-1)


# --------------------------------------------------------------------------------------------
# threshold

def _Q(u: float) -> float:
    return 0.5 * float(erfc(u / np.sqrt(2.0)))


def first_crossing_probability(u: float, c: np.ndarray) -> np.ndarray:
    """P(|X| <= u < |Y|) for standard bivariate normal (X, Y) with correlation c (closed form via
    Owen's T: P(X > u, Y > u) = Q(u) - 2 T(u, sqrt((1 - c) / (1 + c))))."""
    ac = np.clip(np.abs(np.asarray(c, dtype=float)), 0.0, 1.0)
    a = np.sqrt((1.0 - ac) / (1.0 + ac))
    return _crossing_from_a(u, np.asarray(a, dtype=float))


def _crossing_from_a(u: float, a: np.ndarray) -> np.ndarray:
    a = np.clip(a, 1e-300, 1.0)
    # = 2 Q - 2 [L(u,u;|c|) + L(u,u;-|c|)],  L(u,u;rho) = Q(u) - 2 T(u, a(rho)),  a(-|c|) = 1/a
    out = 4.0 * owens_t(u, a) - 4.0 * (0.5 * _Q(u) - owens_t(u, 1.0 / a))
    return np.maximum(out, 0.0)


_A_EDGES = np.logspace(-9.0, 0.0, 241)


def _threshold(fresh: int, pair_a: np.ndarray, p_false_alarm: float) -> float:
    """Smallest l threshold u^2 whose first-crossing bound is p_false_alarm. ``fresh`` onsets
    start a run (term P(|Z| > u)); ``pair_a`` holds a = sqrt((1-|c|)/(1+|c|)) of every
    neighbouring pair.
    The a values are binned up to log-spaced edges: the terms grow with a, so this only loosens
    the bound (by < 10 % for the affected terms) and keeps the root search cheap."""
    if fresh == 0:
        return float("inf")
    idx = np.searchsorted(_A_EDGES, np.clip(pair_a, 0.0, 1.0), side="left")
    counts = np.bincount(idx, minlength=_A_EDGES.size)
    keep = counts > 0
    edges, counts = _A_EDGES[keep], counts[keep].astype(float)

    def bound(u: float) -> float:
        return fresh * 2.0 * _Q(u) + float(counts @ _crossing_from_a(u, edges))

    from scipy.optimize import brentq  # (here: importing scipy.optimize costs ~0.2 s)

    hi = 8.0
    while bound(hi) > p_false_alarm:
        hi *= 2.0
    u = brentq(lambda x: bound(x) - p_false_alarm, 0.0, hi, xtol=1e-10, rtol=1e-12)
    return float(u * u)


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


def _statistics(model: LinearModel, hyps: list, flt: _Filter) -> dict:
    """num, den, cross (sample order, N entries) of every hypothesis."""
    N = flt.t.size
    out = {}
    for hyp in hyps:
        out[hyp.name] = tuple(a[:N] for a in _scan(_System(model, hyp, flt)))
    return out


def isolate(model: LinearModel, fwd: Any, config: GlrConfig = GlrConfig()) -> GlrResult:
    """Isolate the fault in a flight from the forward filter's result by GLR (module docstring).

    ``fwd`` is a ``kalman.ForwardResult`` (fields t, dt, nu, S, K, H, fused are used).
    """
    if not isinstance(model, LinearModel):
        raise CoreError(f"isolate: model must be a LinearModel, got {type(model).__name__}")
    if not isinstance(config, GlrConfig):
        raise CoreError(f"isolate: config must be a GlrConfig, got {type(config).__name__}")
    hyps = [_resolve(model, h) for h in config.hypotheses]
    flt = _prepare(model, fwd, config.block_size)
    N = flt.t.size

    per: dict[str, dict] = {}
    curves: dict[str, tuple] = {}
    fresh = 0
    pair_a: list[np.ndarray] = []
    raw = _statistics(model, hyps, flt)
    for hyp in hyps:
        num, den, cross = raw[hyp.name]
        # den = 0: the fault would leave no trace after this onset (e.g. a bias step at the
        # last sample); such onsets are not tests. (A tiny but positive den is a real test.)
        ok = den > 1e-300
        l = np.zeros(N)
        l[ok] = num[ok] ** 2 / den[ok]
        # neighbouring onsets (theta, theta+1) both informative: correlation of their Z's
        both = ok[:-1] & ok[1:]
        c = np.zeros(N - 1)
        c[both] = cross[:-1][both] / np.sqrt(den[:-1][both] * den[1:][both])
        c = np.clip(np.abs(c), 0.0, 1.0)
        pair_a.append(np.sqrt((1.0 - c[both]) / (1.0 + c[both])))
        fresh += int(ok[0]) + int(np.count_nonzero(ok[1:] & ~ok[:-1]))
        k = int(np.argmax(l))
        if ok[k]:
            # profile-likelihood 95 % interval of the onset: l within chi2(1, 0.95) of its peak
            near = np.flatnonzero(l >= l[k] - ONSET_CI_DROP)
            per[hyp.name] = {
                "onset_index": k, "onset_t": float(flt.t[k]),
                "onset_interval": (float(flt.t[near[0]]), float(flt.t[near[-1]])),
                "magnitude": float(num[k] / den[k] * hyp.scale),
                "magnitude_std": float(hyp.scale / np.sqrt(den[k])),
                "statistic": float(l[k]), "unit": hyp.unit, "kind": hyp.kind}
        else:
            per[hyp.name] = {"onset_index": None, "onset_t": None, "onset_interval": None,
                             "magnitude": None, "magnitude_std": None, "statistic": 0.0,
                             "unit": hyp.unit, "kind": hyp.kind}
        curves[hyp.name] = _pool(flt.t, l, config.curve_points)
        if hyp.kind == "outlier":
            per[hyp.name]["_l"] = l

    threshold = _threshold(fresh, np.concatenate(pair_a) if pair_a else np.zeros(0),
                           config.p_false_alarm)
    for h in per.values():
        if "_l" in h:  # outliers: every onset above the threshold is one (c ~ 0 between them)
            over = np.flatnonzero(h.pop("_l") > threshold)
            h["count"] = int(over.size)
            h["times"] = [float(flt.t[k]) for k in over[:MAX_OUTLIER_TIMES]]
            h["onset_interval"] = None
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
        hyp = next(h for h in hyps if h.name == best)
        from .glr_residual import residual_pass  # (builds on this module's scan)

        residual = residual_pass(model, hyps, flt, raw, hyp, b["onset_index"])
        more_outliers = hyp.kind == "outlier" and residual["hypothesis"] == best
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
