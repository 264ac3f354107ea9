"""Detection and isolation power bounds of a bias step in the post-flight linear-Gaussian setting
of the ins3d GLR (docs/ins3d_power_bound.md; the onset's bounds: ``eval.onset_bound``).

The forward filter of the no-fault model turns the data into independent innovations
nu_j ~ N(0, S_j); a step of size b along a column of the fault vector from onset tau adds
b rho_j(tau) (``core.ins3d.signature``). Whitened, the data are y = b u sqrt(I) + w with
I = sum_j rho_j' S_j^-1 rho_j (per SI unit of b), u a unit vector, w ~ N(0, 1), and the GLR of
that hypothesis at that onset is (u'y)^2 ~ chi^2_1(lambda), lambda = b^2 I. Bounds:

* ``np_power``: the Neyman-Pearson test of "no fault" against *this* fault (onset, size, sign,
  direction all known) at false-alarm probability alpha per flight has power
  Phi(sqrt(lambda) - z_(1-alpha)); no test that raises a false alarm (or names this sensor and
  axis on a nominal flight) with probability <= alpha does better. alpha = ``ALPHA`` = 1 %: the
  issue's false-isolation budget per flight.
* ``mixture_power_bound``: the onset unknown, uniform over the study's window (the size, sign,
  sensor and axis still known): with L = dP_1/dP_0 the likelihood ratio of the mixture over the
  onsets, every test of level alpha has power (averaged over the onset prior)
  <= P_1(L > k) + k alpha for every k (E_1 phi = E_1[phi 1{L > k}] + E_0[phi L 1{L <= k}]).
  P_1(L > k) is estimated on data drawn from the model with onsets drawn from the prior; the
  test L > 1/alpha has level <= alpha (E_0 L = 1), so its power (``mixture_achieved``) is
  reached: the best such power lies between the two.
* ``separation_bound``: the closest rival explanation (another sensor or axis, its own onset
  and size free: the largest cos^2 between u and a rival's signature) leaves a distance
  d^2 = lambda (1 - cos^2) in S^-1 between the two means; no rule names the right one of the two
  with probability above Phi(d / 2) under both (total variation 2 Phi(d / 2) - 1).
* ``glr_known_onsets``: what the GLR itself does when told the onsets: P(chi^2_1(lambda) > c)
  with its calibrated threshold c (``glr3d.thresholds_for``: the grade's, for the flight's
  length) and P(z1^2 > c, z1^2 - z2^2 >= margin) with z2 the nearest rival's projection.
  Not a bound on the GLR (its onset search can only raise its statistics) but its prediction.

``PowerFlight`` computes the per-unit information and the rivals of an analysed flight from the
GLR curves of a noiseless sweep (nu := rho: each curve's statistic is then the squared
projection of the signature on that hypothesis), and draws data from the model itself: the
sweep's fault information is linear in nu, so eta(noise + b rho) = eta(noise) + b eta(rho)
and one sweep per noise draw and per (column, onset) gives the GLR's exact decision at every
size (``decide``). ``RULES``: the decision rules compared on the same draws (``decide_rules``):
the thresholds per kind only or per hypothesis too, best and rival by their raw statistics or
by their excess over their own thresholds (``glr3d.isolate``'s ``compare``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import ncx2, norm

from flight_fdi.core.diagnosis import DiagnosisConfig
from flight_fdi.core.ins3d.glr3d import AMBIGUITY_MARGIN, GlrCurve, isolate
from flight_fdi.core.ins3d.grade_file import KINDS
from flight_fdi.core.ins3d.postflight import glr_curves, run_backward

from .errors import EvalError
from .onset_bound import Signatures

#: the issue's per-flight false-isolation budget: the false-alarm level of the bounds
ALPHA = 0.01
#: decision rules compared on model-drawn data: name -> (per-hypothesis thresholds too, the
#: comparison of best and rival); "kinds_raw" is the isolator before per-hypothesis thresholds
RULES = {"kinds_raw": (False, "raw"), "kinds_excess": (False, "excess"),
         "hyp_raw": (True, "raw"), "hyp_excess": (True, "excess")}
#: the k of the mixture bound P_1(L > k) + k alpha (a fixed grid: a minimum over noisy
#: estimates at many k would be biased low)
K_GRID = tuple(float(k) for k in np.geomspace(0.1, 1.0 / ALPHA, 16))


def np_power(lam, alpha: float = ALPHA):
    """Power of the Neyman-Pearson test of a known signature (one-sided, the fault's sign known)
    at false-alarm probability ``alpha``: Phi(sqrt(lambda) - z_(1-alpha))."""
    if not 0.0 < alpha < 1.0:
        raise EvalError(f"np_power: alpha must be in (0, 1), got {alpha!r}")
    return norm.sf(norm.isf(alpha) - np.sqrt(np.maximum(lam, 0.0)))


def glr_power(lam, threshold: float):
    """P(chi^2_1(lambda) > threshold): the GLR at the true onset above its threshold."""
    return ncx2.sf(threshold, 1, np.maximum(lam, 1e-300))


def separation_bound(d2):
    """Phi(d / 2): the largest probability with which any rule names the right one of two
    Gaussian explanations at Mahalanobis distance d under both."""
    return norm.cdf(0.5 * np.sqrt(np.maximum(d2, 0.0)))


def glr_known_onsets(lam: float, cos2: float, threshold: float,
                     margin: float = AMBIGUITY_MARGIN, n: int = 4001) -> tuple[float, float]:
    """(P(z1^2 > c), P(z1^2 > c and z1^2 - z2^2 >= margin)) for z1 = u'y ~ N(sqrt(lambda), 1) and
    z2 = v'y, v'u = sqrt(cos2): the GLR told the true onset and the rival's best one, against
    its threshold and the ambiguity margin (integral over z1 of the normal z2 | z1). With
    unequal thresholds (``glr3d.isolate`` by excess) the margin is 9.21 + c - c_rival, negative
    when the rival's threshold is the higher by more than 9.21."""
    if not 0.0 <= cos2 <= 1.0 + 1e-9:
        raise EvalError(f"glr_known_onsets: cos2 must be in [0, 1], got {cos2!r}")
    m = math.sqrt(max(lam, 0.0))
    a0 = math.sqrt(max(threshold, margin, 0.0))
    c = math.sqrt(min(cos2, 1.0))
    s = math.sqrt(max(1.0 - cos2, 0.0))
    iso = 0.0
    for lo, hi in ((max(a0, m - 10.0), m + 10.0), (m - 10.0, min(-a0, m + 10.0))):
        if hi <= lo or s == 0.0:
            continue
        z1 = np.linspace(lo, hi, n)
        a = np.sqrt(np.maximum(z1 * z1 - margin, 0.0))
        inside = norm.cdf((a - c * z1) / s) - norm.cdf((-a - c * z1) / s)
        iso += float(np.trapezoid(norm.pdf(z1 - m) * inside, z1))
    return float(glr_power(lam, threshold)), iso


def mixture_power_bound(log_lr: np.ndarray, alpha: float = ALPHA,
                        ks: tuple[float, ...] = K_GRID) -> float:
    """min over k of P_1(L > k) + k alpha from draws of log L under the alternative (onsets from
    the prior): an upper bound on the prior-averaged power of every test of level alpha."""
    x = np.asarray(log_lr, dtype=float)
    if x.size == 0:
        raise EvalError("mixture_power_bound: no draws")
    return float(min(1.0, *(np.mean(x > math.log(k)) + k * alpha for k in ks)))


def mixture_achieved(log_lr: np.ndarray, alpha: float = ALPHA) -> float:
    """P_1(L > 1 / alpha) from draws of log L under the alternative: the power of the test
    "L > 1 / alpha", whose level is <= alpha (Markov: E_0 L = 1) -- achieved, so a lower bound of
    the best prior-averaged power at level alpha."""
    x = np.asarray(log_lr, dtype=float)
    if x.size == 0:
        raise EvalError("mixture_achieved: no draws")
    return float(np.mean(x > -math.log(alpha)))


def onset_terms(c: GlrCurve, window: tuple[float, float] | None = None
                ) -> tuple[np.ndarray, np.ndarray]:
    """(e, d) of the curve's onsets in ``window`` (None: all) where it has information:
    d = 1 / sd^2 (the information per SI unit of the size, SI^-2) and e = b^ d, so that the
    GLR there is e^2 / d and the log likelihood ratio of a size b is b e - b^2 d / 2."""
    on = np.isfinite(c.sd) & np.isfinite(c.mag)
    if window is not None:
        on &= (c.t >= window[0]) & (c.t <= window[1])
    if not on.any():
        raise EvalError(f"no onset of {c.hypothesis.name} with information in {window}")
    d = 1.0 / c.sd[on] ** 2
    return c.mag[on] * d, d


def log_mixture_lr(c: GlrCurve, b: float, window: tuple[float, float]) -> float:
    """log of the likelihood ratio of the onset mixture (uniform over the curve's onsets in
    ``window``) against no fault, b (SI, signed) known: log mean exp(b e - b^2 d / 2) with
    e = b^ / sd^2 and d = 1 / sd^2 of the curve (SI)."""
    e, d = onset_terms(c, window)
    x = b * e - 0.5 * b * b * d
    top = float(x.max())
    return top + math.log(float(np.mean(np.exp(x - top))))


@dataclass(frozen=True)
class Rival:
    """A rival hypothesis' best imitation of a signature (noiseless curves, per unit fault)."""

    name: str          # hypothesis, e.g. "reference_east_jump"
    onset_s: float     # its best onset
    cos2: float        # its statistic / the true one's at the true onset
    magnitude: float   # its size per SI unit of the true fault (SI of the rival)


@dataclass(frozen=True)
class Separation:
    """A step's information (lambda per b^2, SI^-2) and its nearest rivals."""

    info: float
    rivals: tuple[Rival, ...]     # the best per rival (sensor, axis), nearest first

    def lam(self, b: float) -> float:
        return b * b * self.info

    def d2(self, b: float) -> float:
        """Squared distance from the nearest rival at size b."""
        return self.lam(b) * (1.0 - (self.rivals[0].cos2 if self.rivals else 0.0))

    def as_dict(self) -> dict:
        return {"info": self.info, "rivals": [r.__dict__ for r in self.rivals]}


def separation(cv: dict[str, GlrCurve], sensor: str, axis: str, onset_s: float) -> Separation:
    """The information and nearest rivals of the step (sensor, axis) at ``onset_s`` from the
    GLR curves of the noiseless sweep of its own signature (``PowerFlight.noiseless``)."""
    own = cv.get(f"{sensor}_{axis}_step")
    if own is None:
        raise EvalError(f"separation: no step hypothesis {sensor} {axis}")
    k = int(np.argmin(np.abs(own.t - onset_s)))
    info = float(own.stat[k])
    if not info > 0:
        raise EvalError(f"separation: no information on {sensor} {axis} at {onset_s} s")
    best: dict[tuple, Rival] = {}
    for c in cv.values():
        h = c.hypothesis
        if h.kind == "outliers" or (h.sensor, h.axis) == (sensor, axis) or c.best < 0:
            continue
        r = Rival(h.name, float(c.t[c.best]), min(c.statistic / info, 1.0),
                  float(c.mag[c.best]))
        if (h.sensor, h.axis) not in best or r.cos2 > best[(h.sensor, h.axis)].cos2:
            best[(h.sensor, h.axis)] = r
    return Separation(info, tuple(sorted(best.values(), key=lambda r: -r.cos2)))


def main_curves(cv: dict[str, GlrCurve]) -> dict[str, GlrCurve]:
    """The step / ramp / jump curves (the outlier statistics of a sweep on drawn innovations are
    not the drawn data's: they use the measurements themselves)."""
    return {k: c for k, c in cv.items() if c.hypothesis.kind != "outliers"}


class PowerFlight:
    """Noiseless and model-drawn sweeps of one analysed flight (``onset_bound.Signatures``)."""

    def __init__(self, sig: Signatures):
        self.sig = sig
        self.an = sig.an
        self.rank_tol = DiagnosisConfig().rank_tol
        self.chol = np.linalg.cholesky(sig.fwd.S)
        self.thresholds = dict(self.an.thresholds)
        kinds = {k: v for k, v in self.thresholds.items() if k in KINDS}
        self.rules = {r: (self.thresholds if hyp else kinds, cmp)
                      for r, (hyp, cmp) in RULES.items()}

    def sweep(self, nu: np.ndarray):
        """The backward sweep (``postflight.run_backward``) on innovations ``nu``."""
        an = self.an
        return run_backward(an.model, an.steps, an.refs, replace(self.sig.fwd, nu=nu),
                            self.rank_tol)

    def noiseless(self, sensor: str, axis: str, onset_s: float):
        """The sweep of the signature of a unit (SI) step from ``onset_s``: nu = rho."""
        return self.sweep(self.sig.rho(sensor, axis, self.sig.boundary(onset_s)))

    def noise(self, rng: np.random.Generator):
        """The sweep of innovations drawn from the no-fault model, N(0, S_j)."""
        w = rng.standard_normal((self.chol.shape[0], self.chol.shape[1]))
        return self.sweep(np.einsum("jik,jk->ji", self.chol, w))

    def curves(self, bwd, signal=None, b: float = 0.0) -> dict[str, GlrCurve]:
        """The main GLR curves of noise (``bwd``) plus b x a unit signature (``signal``)."""
        if signal is not None:
            bwd = replace(bwd, eta=bwd.eta + b * signal.eta)
        return main_curves(glr_curves(self.an.model, self.an.steps, bwd))

    def separation(self, sensor: str, axis: str, onset_s: float, signal=None) -> Separation:
        """:func:`separation` of the step at ``onset_s`` (``signal``: its noiseless sweep)."""
        if signal is None:
            signal = self.noiseless(sensor, axis, onset_s)
        return separation(self.curves(signal), sensor, axis, onset_s)

    def decide(self, cv: dict[str, GlrCurve], sensor: str | None, axis: str | None) -> dict:
        """The isolator's decision on the curves: ``named`` (the isolated hypothesis or None),
        ``isolation``, ``right`` (single, this sensor and axis), ``detected`` (any step / ramp /
        jump above its threshold)."""
        iso = isolate(cv, self.thresholds)
        h = cv[iso.best].hypothesis if iso.best else None
        right = (iso.isolation == "single" and h is not None and (h.sensor, h.axis) ==
                 (sensor, axis))
        return {"named": iso.best, "isolation": iso.isolation, "right": bool(right),
                "detected": iso.isolation != "none"}

    def decide_rules(self, cv: dict[str, GlrCurve], sensor: str | None, axis: str | None
                     ) -> dict[str, list]:
        """Per rule of ``RULES``: [named (or None), isolation, right]."""
        out = {}
        for r, (thr, cmp) in self.rules.items():
            iso = isolate(cv, thr, compare=cmp)
            h = cv[iso.best].hypothesis if iso.best else None
            out[r] = [iso.best, iso.isolation, bool(
                iso.isolation == "single" and h is not None and (h.sensor, h.axis) ==
                (sensor, axis))]
        return out


#: the levels of the bounds per sensor (the studies' scenario and unit: ``montecarlo3d.SCENARIOS``)
LEVELS = {"gyro": ("gyro_step", (0.05, 0.1, 0.2)), "accelerometer": ("accel_step", (0.3,))}


def _draws(pf: PowerFlight, noise: list, signal, sensor: str, axis: str, b: float,
           window: tuple[float, float]) -> dict[str, list]:
    """The GLR's decisions on the model-drawn data noise + b x signal, per noise draw, and the
    onset mixture's log likelihood ratio of each."""
    out: dict[str, list] = {"right": [], "detected": [], "named": [], "true_max": [],
                            "log_lr": [], "rules": []}
    name = f"{sensor}_{axis}_step"
    for b0 in noise:
        cv = pf.curves(b0, signal, b)
        d = pf.decide(cv, sensor, axis)
        for k in ("right", "detected", "named"):
            out[k].append(d[k])
        out["rules"].append(pf.decide_rules(cv, sensor, axis))
        out["true_max"].append(float(cv[name].statistic))
        out["log_lr"].append(log_mixture_lr(cv[name], b, window))
    return out


def flight_record(item: tuple) -> dict:
    """One study flight, item = (case, config, extra onsets, noise draws[, columns: the
    (sensor, axis) pairs, default every IMU step column]): the isolator's
    result on the flight itself, and at its own onset and ``extra`` onsets drawn from the
    study's prior (uniform over its onset window, on the GLR's onset grid), for every IMU step
    column and level of ``LEVELS``: the information and the nearest rivals
    (:class:`Separation`), and the GLR's decisions on ``noise`` sets of innovations drawn from
    the model (shared by all onsets and columns) with the fault added (sign: the case's at its
    own onset, random elsewhere); also the decisions on the noise alone (false alarms) and each
    hypothesis' largest GLR there."""
    from .montecarlo3d import SCENARIOS, decision
    from .onset_bound import AXES, analyse_case

    case, config, extra, n_noise = item[:4]
    columns = item[4] if len(item) > 4 else [(s, a) for s in LEVELS for a in AXES]
    _, an = analyse_case(case, config)
    dec = decision(an.post_flight_dict())
    pf = PowerFlight(Signatures(an))
    rng = np.random.default_rng([case.sim_seed, 16])
    window = tuple(f * config.duration_s for f in config.onset_window)
    grid = an.glr["gyro_x_step"].t
    grid = grid[(grid >= window[0]) & (grid <= window[1])]
    taus = [float(case.onset_s)] + [float(x) for x in rng.choice(grid, extra)]
    signs = [1.0 if case.magnitude >= 0 else -1.0] + [float(rng.choice((-1.0, 1.0)))
                                                      for _ in range(extra)]
    noise = [pf.noise(rng) for _ in range(n_noise)]
    rows = []
    for tau, sign in zip(taus, signs):
        for sensor, axis in columns:
            scen, levels = LEVELS[sensor]
            signal = pf.noiseless(sensor, axis, tau)
            sep = pf.separation(sensor, axis, tau, signal)
            for lev in levels:
                b = sign * lev * SCENARIOS[scen][6]
                rows.append({"onset_s": tau, "own": tau == taus[0], "sensor": sensor,
                             "axis": axis, "level": lev, "b": b, **sep.as_dict(),
                             "draws": _draws(pf, noise, signal, sensor, axis, b, window)})
    sensor = SCENARIOS[case.scenario][2]
    return {"key": f"{case.scenario}:{case.index}", "index": case.index,
            "scenario": case.scenario, "sensor": sensor, "axis": case.axis,
            "level": case.level, "magnitude": case.magnitude, "onset_s": case.onset_s,
            "sim_seed": case.sim_seed, "traj_seed": case.traj_seed,
            "ins3d": {k: dec.get(k) for k in ("verdict", "isolation", "sensor", "axis", "kind",
                                             "onset_s", "statistic")},
            "thresholds": pf.thresholds, "window": list(window),
            "h0_named": [pf.decide(pf.curves(b0), None, None)["named"] for b0 in noise],
            "h0_rules": [pf.decide_rules(pf.curves(b0), None, None) for b0 in noise],
            "h0_max": [{k: float(c.statistic) for k, c in pf.curves(b0).items()}
                       for b0 in noise],
            "rows": rows}


__all__ = ["ALPHA", "K_GRID", "LEVELS", "PowerFlight", "RULES", "Rival", "Separation",
           "flight_record",
           "glr_known_onsets", "glr_power", "log_mixture_lr", "main_curves", "mixture_achieved",
           "mixture_power_bound", "np_power", "onset_terms", "separation", "separation_bound"]
