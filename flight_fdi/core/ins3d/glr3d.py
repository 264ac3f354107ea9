"""GLR isolation over the body-axis hypotheses of the ins3d model.

Hypotheses (``hypotheses``): accelerometer and gyro x / y / z bias *step* and *ramp* (body axes),
reference *jump* per row (east, north, up), reference *outliers* per row. Every onset is a
boundary with reference updates; the statistics of all onsets come from one backward sweep
(``backward.py``): for the direction tau of a hypothesis in the fault vector,

    GLR(theta) = (tau' eta)^2 / (tau' I tau),   b^ = tau' eta / tau' I tau,
    sd(b^) = 1 / sqrt(tau' I tau)

(a step or a jump: tau = the unit vector of its column; a ramp r (t - theta): tau = e_r -
(theta~ / T) e_a in the scaled columns). Per hypothesis the maximum over the onsets, the onset,
its profile-likelihood 95 % interval (onsets within 3.84 of the maximum, contiguous around it),
the magnitude and its sd.

``joint``: the same for a step on all three axes of a sensor at once (3 dof), reported beside.

Decision (``isolate``), per IMU grade a threshold per hypothesis kind (``THRESHOLDS_BY_GRADE``)
and, where calibrated, per hypothesis (``HYPOTHESIS_THRESHOLDS_BY_GRADE``; ``threshold_of``),
calibrated on nominal simulated flights (docs/ins3d.md, "Thresholds"). Each step / ramp / jump
is judged by its *excess* L - c over its own threshold c (the evidence beyond what its own
search over the onsets reaches on nominal flights; with equal thresholds the raw comparison):

* outliers above their threshold whose largest statistic is at least that of every step / ramp /
  jump above its threshold (a spike explains the data better than a sustained fault starting
  at it) -> ``single`` outliers (a glitch); no step / ramp / jump above its threshold -> ``none``;
* else the largest excess (a step rather than a ramp of the same sensor and axis unless the
  ramp's excess is larger by the margin: over a short span after the onset the two shapes are
  alike); the largest excess naming *another* (sensor, axis) is its rival: closer
  than ``margin`` (default 2 ln 100 = 9.21, a likelihood ratio of 100) -> ``ambiguous``, both
  named; else ``single``, with the time the ambiguity resolved: the first time t from which the
  GLR gap computed with the data up to t (``signature.signature_stats``, each at its own onset)
  stays above the margin -- on a straight leg a gyro and an accelerometer error can look alike
  until a turn;
* a ``single`` isolation is then checked against its rival fitted *together* with it (each at
  its own onset; the cross information of their signatures through the forward filter:
  ``pair_glr``, ``settle``): the rival, its signature allowed the model's relative error
  ``eps`` on this kind of flight (an angle), must not explain the data in the pair's plane
  within the margin -- else ``ambiguous``, reason ``model``. The fixed margin alone is not
  enough when the model is not exact: a signature error delta moves the gap by up to
  2 L |delta| sin(theta) (theta the angle between the two signatures), and on real
  recordings gyro steps of 3000 deg/h were named, with confidence, as the accelerometer ramp
  of the other horizontal axis (the tilt identity) by gaps of 14-100 at GLRs of 200-650
  (docs/ins3d_real.md). The default eps, the grade's axis misalignment (1e-5 to 1e-3 for the
  presets), leaves the gap rule as it was.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from .backward import GROUP_START, REF

IMU_AXES = ("x", "y", "z")
REF_AXES = ("east", "north", "up")
HEIGHT = "height"          # the third row of a height reference (m)
AMBIGUITY_MARGIN = 2.0 * math.log(100.0)
#: thresholds of the maximum GLR over the onsets per IMU grade and hypothesis kind
#: (docs/ins3d.md, "Thresholds": calibrated on nominal simulated flights with scale factors,
#: misalignment, correlated GNSS and latency -- navigation 36 flights of 30-60 min: largest
#: step 14.4, ramp 13.2, jump 23.5, outliers 28.0; tactical 12 flights of 30 min: 17.0, 14.7,
#: 22.0, 22.3). mems: not calibrated (the linear error model leaves the small-angle regime
#: within minutes on a free-inertial mems INS); it uses the tactical values.
THRESHOLDS_BY_GRADE = {
    "navigation": {"step": 20.0, "ramp": 20.0, "jump": 30.0, "outliers": 32.0},
    "tactical": {"step": 25.0, "ramp": 22.0, "jump": 30.0, "outliers": 32.0},
}
THRESHOLDS = THRESHOLDS_BY_GRADE["navigation"]


#: the flight length the thresholds were calibrated on (s), and per kind how the largest GLR of
#: a nominal flight grows with its length: + c ln(T / CALIBRATED_LENGTH_S). Jumps and outliers
#: have independent onsets per reference epoch (maximum of N chi^2 terms: + 2 ln N); steps'
#: onsets are correlated (slower growth), ramps' strongly. Calibrated with
#: tools/ins3d_calibrate.py (docs/ins3d_eval.md, "Long flights"): the median of the flights'
#: maxima, 90 flights of 30 min (seeds 21000-21089) -> 160 of 2 h (20000-20159): step 7.8 ->
#: 9.1 (+1.3 = 0.94 ln 4), ramp 5.4 -> 5.3, jump 17.8 -> 20.5 (+2.7 = 1.95 ln 4), outliers
#: 19.3 -> 22.0 (1.95 ln 4).
CALIBRATED_LENGTH_S = 1800.0
LENGTH_GROWTH = {"step": 1.0, "ramp": 0.0, "jump": 2.0, "outliers": 2.0}

#: the hypotheses a threshold of its own can be given to (outliers keep their kind's: their
#: statistic is per reference update, one threshold for every row)
PER_HYPOTHESIS = tuple(f"{s}_{a}_{k}" for s in ("accelerometer", "gyro") for a in IMU_AXES
                       for k in ("step", "ramp")) + tuple(f"reference_{a}_jump" for a in REF_AXES)
#: thresholds per hypothesis (for a flight of CALIBRATED_LENGTH_S) per IMU grade, where
#: calibrated (docs/ins3d.md, "Thresholds"): each hypothesis' maximum over its onsets on nominal
#: simulated flights, an equal share of the grade's false-isolation budget per hypothesis
#: (``eval.calibrate3d.calibrate_hypotheses``). A hypothesis without one uses its kind's.
HYPOTHESIS_THRESHOLDS_BY_GRADE: dict[str, dict[str, float]] = {
    "navigation": {
        "accelerometer_x_step": 19.7,
        "accelerometer_x_ramp": 17.1,
        "accelerometer_y_step": 25.5,
        "accelerometer_y_ramp": 20.5,
        "accelerometer_z_step": 19.3,
        "accelerometer_z_ramp": 16.8,
        "gyro_x_step": 21.6,
        "gyro_x_ramp": 21.6,
        "gyro_y_step": 20.6,
        "gyro_y_ramp": 16.8,
        "gyro_z_step": 20.6,
        "gyro_z_ramp": 22.0,
        "reference_east_jump": 32.3,
        "reference_north_jump": 30.3,
        "reference_up_jump": 30.2}}
#: per hypothesis how its nominal maximum grows with the flight length (c of c ln(T / 1800 s),
#: measured: the median of the maxima on 30-min and 2-h flights); else its kind's
HYPOTHESIS_LENGTH_GROWTH: dict[str, float] = {
    "accelerometer_x_step": 0.71,
    "accelerometer_x_ramp": 0.00,
    "accelerometer_y_step": 0.31,
    "accelerometer_y_ramp": 0.00,
    "accelerometer_z_step": 1.20,
    "accelerometer_z_ramp": 0.00,
    "gyro_x_step": 0.30,
    "gyro_x_ramp": 0.00,
    "gyro_y_step": 0.16,
    "gyro_y_ramp": 0.00,
    "gyro_z_step": 0.03,
    "gyro_z_ramp": 0.27,
    "reference_east_jump": 2.42,
    "reference_north_jump": 1.86,
    "reference_up_jump": 0.00}


def thresholds_for(grade: str, duration_s: float | None = None) -> dict[str, float]:
    """The calibrated thresholds of a grade (tactical's for grades not calibrated): per kind,
    and per hypothesis where the grade has them (``HYPOTHESIS_THRESHOLDS_BY_GRADE``; looked up
    with :func:`threshold_of`); for a flight longer than ``CALIBRATED_LENGTH_S``, each raised by
    its growth x ln(duration / it) (:func:`length_growth`: the same false-alarm rate per flight
    on longer flights; shorter flights keep them)."""
    thr = dict(THRESHOLDS_BY_GRADE.get(grade, THRESHOLDS_BY_GRADE["tactical"]))
    thr.update(HYPOTHESIS_THRESHOLDS_BY_GRADE.get(grade, {}))
    growth = length_growth(duration_s)
    return {k: v + growth.get(k, 0.0) for k, v in thr.items()}


def growth_of(key: str) -> float:
    """c of the length rule of a threshold key: a kind's (``LENGTH_GROWTH``) or a hypothesis'
    (``HYPOTHESIS_LENGTH_GROWTH``, else its kind's: the name's last part)."""
    if key in LENGTH_GROWTH:
        return LENGTH_GROWTH[key]
    return HYPOTHESIS_LENGTH_GROWTH.get(key, LENGTH_GROWTH.get(key.rsplit("_", 1)[-1], 0.0))


def length_growth(duration_s: float | None) -> dict[str, float]:
    """What a flight of ``duration_s`` adds to each threshold (per kind and per hypothesis of
    ``PER_HYPOTHESIS``): :func:`growth_of` x ln(duration / ``CALIBRATED_LENGTH_S``) when
    longer, nothing otherwise (None: nothing)."""
    if duration_s is None or duration_s <= CALIBRATED_LENGTH_S:
        return {}
    ln = math.log(duration_s / CALIBRATED_LENGTH_S)
    return {k: growth_of(k) * ln for k in (*LENGTH_GROWTH, *PER_HYPOTHESIS)}


def threshold_of(thresholds: dict[str, float], h: "Hypothesis") -> float:
    """A hypothesis' threshold in a thresholds dict: its own (key ``h.name``) if given, else
    its kind's (outliers: always the kind's)."""
    if h.kind != "outliers" and h.name in thresholds:
        return float(thresholds[h.name])
    return float(thresholds[h.kind])


@dataclass(frozen=True)
class Hypothesis:
    name: str          # e.g. "gyro_x_step"
    sensor: str        # accelerometer | gyro | reference
    axis: str          # x | y | z (IMU, body) or east | north | up (reference)
    kind: str          # step | ramp | jump | outliers
    column: int        # its column of the fault vector (a ramp: the rate's; outliers: the row)

    @property
    def unit(self) -> str:
        return {("accelerometer", "step"): "m/s^2", ("accelerometer", "ramp"): "m/s^3",
                ("gyro", "step"): "rad/s", ("gyro", "ramp"): "rad/s^2"}.get(
            (self.sensor, self.kind), "m" if self.axis == HEIGHT else "m/s")

    @property
    def element(self) -> str:
        """The state (or measurement) element the hypothesis acts on."""
        if self.sensor == "reference":
            return "dp_u" if self.axis == HEIGHT else "dv_" + self.axis[0]
        return ("ba_" if self.sensor == "accelerometer" else "bg_") + self.axis


def ref_axes(height_row: bool = False) -> tuple[str, str, str]:
    """The reference rows' names: east, north and up, or height (``Ins3dModel.height_row``)."""
    return (*REF_AXES[:2], HEIGHT) if height_row else REF_AXES


def hypotheses(rows: int, height_row: bool = False) -> list[Hypothesis]:
    axes = ref_axes(height_row)
    out = []
    for sensor, g in (("accelerometer", 0), ("gyro", 1)):
        for c, ax in enumerate(IMU_AXES):
            out.append(Hypothesis(f"{sensor}_{ax}_step", sensor, ax, "step", GROUP_START[g] + c))
            out.append(Hypothesis(f"{sensor}_{ax}_ramp", sensor, ax, "ramp",
                                  GROUP_START[g] + 3 + c))
    for i in range(rows):
        out.append(Hypothesis(f"reference_{axes[i]}_jump", "reference", axes[i], "jump", REF + i))
    for i in range(rows):
        out.append(Hypothesis(f"reference_{axes[i]}_outliers", "reference", axes[i], "outliers",
                              i))
    return out


@dataclass
class GlrCurve:
    """One hypothesis over its onsets (outliers: over the updates)."""

    hypothesis: Hypothesis
    t: np.ndarray          # onset times
    stat: np.ndarray       # GLR(theta)
    mag: np.ndarray        # b^(theta), SI (reference: the offset of z = v_INS - v_ref)
    sd: np.ndarray         # its sd

    @property
    def best(self) -> int:
        return int(np.argmax(self.stat)) if self.stat.size else -1

    @property
    def statistic(self) -> float:
        return float(self.stat.max()) if self.stat.size else 0.0

    def onset_interval(self, drop: float = 3.84) -> tuple[float, float] | None:
        k = self.best
        if k < 0:
            return None
        ok = self.stat >= self.stat[k] - drop
        a = k
        while a > 0 and ok[a - 1]:
            a -= 1
        b = k
        while b < ok.size - 1 and ok[b + 1]:
            b += 1
        return float(self.t[a]), float(self.t[b])


#: onsets searched per step / ramp / jump: information (1 / sd^2 of the magnitude) above this
#: fraction of the hypothesis' largest on the flight (1e-4: its sd at most 100x its best).
#: Below it the data left after the onset carry (almost) nothing of the hypothesis -- a
#: vertical gyro step after the last turn -- but the GLR e^2 / d is scale-free there: those
#: onsets add chi^2 terms to the search (the largest nominal maxima of the vertical gyro, on
#: realistic and on model-drawn data alike). Measured with 1e-4 and re-calibrated thresholds
#: (docs/ins3d_eval.md, "Sixth evaluation"): it removes them, but the thresholds of the tail
#: rule do not fall and the vertical gyro is not isolated more often -- so **off** (0: every
#: onset with information, the isolator as calibrated).
INFORMATION_FLOOR = 0.0


def _direction(eta, I3, g, c_a, c_r, alpha):
    """(tau' eta, tau' I tau) over the onsets for tau = e_r - alpha e_a (alpha per onset; a step:
    c_r = -1)."""
    if c_r < 0:
        return eta[:, GROUP_START[g] + c_a], I3[:, g, c_a, c_a]
    e = eta[:, GROUP_START[g] + c_r] - alpha * eta[:, GROUP_START[g] + c_a]
    i = (I3[:, g, c_r, c_r] - 2.0 * alpha * I3[:, g, c_a, c_r]
         + alpha * alpha * I3[:, g, c_a, c_a])
    return e, i


def curves(hyps: list[Hypothesis], t_onset: np.ndarray, t_start: float, duration: float,
           eta: np.ndarray, I3: np.ndarray, sB: np.ndarray, t_upd: np.ndarray,
           oe: np.ndarray, oI: np.ndarray, floor: float | None = None
           ) -> dict[str, GlrCurve]:
    """GLR curves of every hypothesis from the sweep's per-onset eta (U, pB), I3 (U, 3, 6, 6)
    and per-update outlier information oe (M, rows), oI (M, rows, rows). A step / ramp / jump
    is searched only at onsets whose information is above ``floor`` times its largest on the
    flight (None: ``INFORMATION_FLOOR``; elsewhere its statistic is 0, its magnitude NaN)."""
    floor = INFORMATION_FLOOR if floor is None else floor
    alpha = (t_onset - t_start) / duration
    out = {}
    for h in hyps:
        if h.kind == "outliers":
            i = h.column
            info = oI[:, i, i]
            e = oe[:, i]
            t, scale = t_upd, 1.0
        else:
            g = 2 if h.sensor == "reference" else (0 if h.sensor == "accelerometer" else 1)
            c = h.column - GROUP_START[g]
            e, info = _direction(eta, I3, g, c % 3 if h.kind == "ramp" else c,
                                 c if h.kind == "ramp" else -1, alpha)
            t, scale = t_onset, sB[h.column]
        rel = 1e-12 if h.kind == "outliers" else max(floor, 1e-12)
        ok = info > rel * max(float(np.max(np.abs(info))) if info.size else 0.0, 1e-300)
        safe = np.where(ok, info, 1.0)
        stat = np.where(ok, e * e / safe, 0.0)
        mag = np.where(ok, e / safe, np.nan) * scale
        sd = np.where(ok, 1.0 / np.sqrt(safe), np.nan) * scale
        out[h.name] = GlrCurve(h, t, stat, mag, sd)
    return out


@njit(cache=True, nogil=True)
def _pinv_quadratic(info, e, rcond, out):
    """out[k] = e_k' pinv(I_k) e_k for symmetric I_k (m x m, small): cyclic Jacobi eigen
    decomposition, eigenvalues at or below rcond * max |lambda| dropped (numpy's pinv)."""
    m = e.shape[1]
    A = np.empty((m, m))
    V = np.empty((m, m))
    for k in range(e.shape[0]):
        for i in range(m):
            for c in range(m):
                A[i, c] = info[k, i, c]
                V[i, c] = 1.0 if i == c else 0.0
        for _ in range(50):
            off = 0.0
            for i in range(m):
                for c in range(i + 1, m):
                    off += A[i, c] * A[i, c]
            diag = 0.0
            for i in range(m):
                diag += A[i, i] * A[i, i]
            if not off > 1e-34 * diag:
                break
            for p in range(m):
                for q in range(p + 1, m):
                    if A[p, q] == 0.0:
                        continue
                    th = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
                    t = (1.0 if th >= 0.0 else -1.0) / (abs(th) + np.sqrt(th * th + 1.0))
                    cs = 1.0 / np.sqrt(t * t + 1.0)
                    sn = t * cs
                    for r in range(m):          # A <- J' A J, V <- V J
                        a_rp, a_rq = A[r, p], A[r, q]
                        A[r, p] = cs * a_rp - sn * a_rq
                        A[r, q] = sn * a_rp + cs * a_rq
                    for r in range(m):
                        a_pr, a_qr = A[p, r], A[q, r]
                        A[p, r] = cs * a_pr - sn * a_qr
                        A[q, r] = sn * a_pr + cs * a_qr
                    for r in range(m):
                        v_rp, v_rq = V[r, p], V[r, q]
                        V[r, p] = cs * v_rp - sn * v_rq
                        V[r, q] = sn * v_rp + cs * v_rq
        big = 0.0
        for i in range(m):
            big = max(big, abs(A[i, i]))
        acc = 0.0
        for i in range(m):
            lam = A[i, i]
            if abs(lam) > rcond * big:
                u = 0.0
                for r in range(m):
                    u += V[r, i] * e[k, r]
                acc += u * u / lam
        out[k] = acc


def joint(eta: np.ndarray, I3: np.ndarray, rows: int) -> dict[str, np.ndarray]:
    """GLR over the onsets of a step on all three axes of a sensor at once (3 dof; a reference
    jump on all its rows): eta_a' I_aa^+ eta_a of the step columns (pseudo-inverse as numpy's
    ``pinv(rcond=1e-10, hermitian=True)``: near the end of the flight an axis may carry no
    information)."""
    out = {}
    for name, g, m in (("accelerometer_step", 0, 3), ("gyro_step", 1, 3),
                       ("reference_jump", 2, rows)):
        e = np.ascontiguousarray(eta[:, GROUP_START[g]:GROUP_START[g] + m])
        info = np.ascontiguousarray(I3[:, g, :m, :m])
        out[name] = np.empty(e.shape[0])
        _pinv_quadratic(info, e, 1e-10, out[name])
    return out


@dataclass
class Isolation:
    """The decision (module docstring)."""

    isolation: str                   # none | single | ambiguous
    best: str | None                 # hypothesis name
    rival: str | None                # the best hypothesis of another (sensor, axis)
    outliers: int                    # updates whose outlier statistic exceeds its threshold
    ambiguity_resolved_s: float | None = None
    gap: np.ndarray | None = None    # (M,) the decision's gap best - rival with the data up to t_j
    rival_gain: float | None = None  # what the rival adds to the best fitted with it (settle)
    similarity: float | None = None  # |cos| of the angle between their signatures (0..1)
    reason: str | None = None        # ambiguous: "margin" (isolate), "model" (settle), "nonlinear",
                                     # "attitude" (analysis: beyond the relinearised model)
    pair: float | None = None        # the GLR of the best and the rival fitted together
    offset: float = 0.0              # threshold of the best - the rival's: the decision's gap
                                     # is the raw gap minus it (isolate, compare="excess")


def isolate(cv: dict[str, GlrCurve], thresholds: dict[str, float],
            margin: float = AMBIGUITY_MARGIN, compare: str = "excess") -> Isolation:
    """The decision (module docstring, "Decision"). Every step / ramp / jump is judged by its
    *excess* over its own threshold (:func:`threshold_of`), L - c: the best is the largest
    excess, its rival the largest excess of another (sensor, axis), ambiguous when the two
    excesses are closer than ``margin``. With one threshold for all (one kind) this is the raw
    comparison; with unequal ones it compares each hypothesis' evidence beyond what its own
    search over the onsets reaches on nominal flights (docs/ins3d.md, "Thresholds"). The
    outlier rule compares raw statistics, as before. ``compare="raw"``: best and rival by the
    raw statistics (the rule before per-hypothesis thresholds; kept for comparisons,
    ``eval.power_bound``)."""
    if compare not in ("excess", "raw"):
        raise ValueError(f"isolate: compare must be 'excess' or 'raw', got {compare!r}")
    main = [c for c in cv.values() if c.hypothesis.kind != "outliers"]
    outl = [c for c in cv.values() if c.hypothesis.kind == "outliers"]
    n_out = int(sum(np.sum(c.stat > thresholds["outliers"]) for c in outl))
    score = {c.hypothesis.name: c.statistic - threshold_of(thresholds, c.hypothesis)
             for c in main}                      # the excess over the own threshold
    det = [c for c in main if score[c.hypothesis.name] > 0.0]
    if compare == "raw":
        score = {c.hypothesis.name: c.statistic for c in main}
    top = max(outl, key=lambda c: c.statistic) if outl else None
    if n_out and (not det or top.statistic >= max(c.statistic for c in det)):
        return Isolation("single", top.hypothesis.name, None, n_out)   # spikes explain best
    if not det:
        return Isolation("none", None, None, n_out)
    best = max(det, key=lambda c: score[c.hypothesis.name])
    hb = best.hypothesis
    step = cv.get(hb.name.replace("_ramp", "_step")) if hb.kind == "ramp" else None
    if step is not None and step in det and \
            score[step.hypothesis.name] > score[hb.name] - margin:
        best, hb = step, step.hypothesis        # the simpler shape unless the ramp is clear
    others = [c for c in main if (c.hypothesis.sensor, c.hypothesis.axis) != (hb.sensor, hb.axis)]
    rival = max(others, key=lambda c: score[c.hypothesis.name]) if others else None
    if rival is None:
        return Isolation("single", hb.name, None, n_out)
    off = 0.0 if compare == "raw" else (threshold_of(thresholds, hb)
                                        - threshold_of(thresholds, rival.hypothesis))
    if score[hb.name] - score[rival.hypothesis.name] < margin:
        return Isolation("ambiguous", hb.name, rival.hypothesis.name, n_out, reason="margin",
                         offset=off)
    return Isolation("single", hb.name, rival.hypothesis.name, n_out, offset=off)


def pair_glr(e: np.ndarray, D: np.ndarray) -> float:
    """The GLR of two hypotheses fitted together at their own onsets: e' D^+ e for e = (tau_1'
    eta, tau_2' eta) and their information D (2 x 2; the cross term the inner product of the
    two signatures through the forward filter). Pseudo-inverse: two signatures that are the
    same on the flight carry the GLR of one."""
    return float(e @ np.linalg.pinv(D, rcond=1e-10, hermitian=True) @ e)


def settle(iso: Isolation, e: np.ndarray, D: np.ndarray, eps: float,
           margin: float = AMBIGUITY_MARGIN) -> Isolation:
    """Whether a ``single`` isolation survives its rival allowed the model's error (module
    docstring): e, D of ``pair_glr`` for (best, rival). The pair's GLR L2 is the data in the
    plane of their two signatures; the rival alone leaves L2 - L_r of it, the data's angle
    alpha_r off the rival's signature being sin^2(alpha_r) = (L2 - L_r) / L2. A signature wrong
    by an angle ``eps`` (rad; the model's relative error on this kind of flight) leaves up to
    L2 sin^2(eps), noise 9.21 more (``margin``): L2 - L_r <= margin + L2 sin^2(eps) ->
    ``ambiguous``, reason ``model`` (the rival explains the data as well, up to the model's
    error). With eps -> 0 this is the gap rule of ``isolate`` (L2 - L_r >= L_b - L_r); like
    it, the gap is taken net of ``iso.offset`` (the two hypotheses' thresholds differ: each
    one's evidence counts beyond what its own search over the onsets reaches on nominal
    flights), so a pair that ``isolate`` separated by the margin stays separated at eps = 0.
    Records ``pair``, ``rival_gain`` = L2 - L_b (what the rival adds to the best) and
    ``similarity`` = |cos| of the angle between the signatures."""
    both = pair_glr(e, D)
    alone = [float(e[i] * e[i] / D[i, i]) if D[i, i] > 0 else 0.0 for i in (0, 1)]
    iso.pair, iso.rival_gain = both, max(both - alone[0], 0.0)
    iso.similarity = float(min(abs(D[0, 1]) / math.sqrt(D[0, 0] * D[1, 1]), 1.0)) \
        if D[0, 0] > 0 and D[1, 1] > 0 else 0.0
    if iso.isolation == "single" and iso.rival is not None and \
            both - alone[1] - iso.offset <= margin + both * math.sin(eps) ** 2:
        iso.isolation, iso.reason = "ambiguous", "model"
    return iso


def resolved_time(t_upd: np.ndarray, gap: np.ndarray, margin: float = AMBIGUITY_MARGIN
                  ) -> float | None:
    """The first update time from which the gap stays above the margin (None: never)."""
    below = np.flatnonzero(~(gap >= margin))
    if below.size == 0:
        return float(t_upd[0]) if t_upd.size else None
    if below[-1] == gap.size - 1:
        return None
    return float(t_upd[below[-1] + 1])


__all__ = ["AMBIGUITY_MARGIN", "GlrCurve", "HYPOTHESIS_LENGTH_GROWTH",
           "HYPOTHESIS_THRESHOLDS_BY_GRADE", "Hypothesis", "IMU_AXES", "Isolation",
           "HEIGHT", "PER_HYPOTHESIS", "REF_AXES", "THRESHOLDS", "THRESHOLDS_BY_GRADE", "curves",
           "growth_of", "hypotheses", "ref_axes", "isolate", "joint", "length_growth", "pair_glr",
           "resolved_time", "settle", "threshold_of", "thresholds_for"]
