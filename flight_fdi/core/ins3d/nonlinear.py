"""The nonlinear check of a large gyro fault: the fault, removed from the INS exactly (not to
first order), must leave a nominal flight (docs/ins3d_nonlinear.md).

**Why.** The ins3d model is linear in the attitude error (small angles). A gyro step of degrees
per second leaves tens of degrees of attitude error within seconds; the linear signatures are
then wrong and GLR may name the wrong axis with confidence (on the real Xsens excerpt, a gyro z
step of 10 deg/s 10 s before the end was named gyro x: the linear signature of a yaw error
cannot follow a rotation of 100 deg).

**The exact removal** of a fault u (body axis, ``step``: b from the onset, ``ramp``: b (t -
onset)) from the INS of the steps (``data.NavSteps``: attitude C, measured rate w and specific
force f_b = C^T f_n of each step):

* attitude: the INS integrated w, the fault-free INS w - u_g; both see the same navigation-frame
  rates, so C_c = C D with the body-frame rotation D' = -[w x] D + D [(w - u_g) x], per step
  D_k+1 = exp(-[w dt]) D_k exp([(w - u_g) dt]) (exact for the step's mean rate);
* velocity, position, the vertical channel and its loop: the model's own transition Phi_k
  (Coriolis, Schuler, gravity with height) driven by the exact specific-force difference
  C (f_b - D (f_b - u_a)) dt (D at mid-step; an accelerometer fault: C u_a, as the model). The
  state's phi carries only the attitude error the velocity error itself causes (Schuler);
  the biases stay zero.

The fault-free flight is then C_c, f_n_c = C_c (f_b - u_a), v - dv (mid-step), h - dh, w - u_g
and z - dv at the updates (``corrected``).

**The fit** (``fit``): onset and magnitude minimising -2 ln L = sum(nu' S^-1 nu + ln det S) of
the no-fault forward filter on the corrected flight: the magnitude over a log grid of both
signs around the linear GLR's estimate at the decision's onset, refined
(``scipy.optimize.minimize_scalar``); then the onset over the steps from two updates before the
decision's best and rival's linear onsets to one after (at most ``MAX_ONSETS``), and the
magnitude refined again at the onset found.

**The check** (``confirm``, called by ``analysis.analyze_ins3d`` when the decision's best or
rival is a gyro hypothesis whose linear estimate turns the attitude by more than
``SMALL_ANGLE_RAD`` by the end of the flight): the decision's best and rival and the gyro steps
of the three axes are each fitted by exact removal; the best fit (least -2 ln L) and the
runner-up are the decision's new best and rival (reason ``nonlinear``), ``single`` when the
runner-up's -2 ln L exceeds the best's by more than the margin plus the model's error allowance
(``glr3d.settle``'s rule: 9.21 + L sin^2(eps), L the best fit's likelihood ratio against no
fault), else ``ambiguous``; the fault's onset and magnitude are the fit's. Two hypotheses of the
same parameter count (onset, magnitude): the -2 ln L difference is their likelihood ratio, as
the linear GLR gap. The check is evaluated on the flight from two updates before the earlier
linear onset (``Window``: the forward filter's priors there), so it costs about 45 forward
passes of that window per hypothesis (two hypotheses at a time on two cores).

**On a relinearised flight** (``relinearize``: a MEMS INS 5-20 deg off without any fault) the
fits above compare hypotheses with the model linear about the flight as recorded, which misfits
the fault-free flight itself; a yaw fault of thousands of deg/h, rotating the INS's own tilt
error, absorbs that misfit and beat the true horizontal gyro step (2 of 4 gyro x steps of
200 deg/h on 5-min MEMS flights were named gyro z at ~4000 deg/h). So the fits are refitted
(``refit``: the magnitude at the fit's onset) and compared -- with the no-fault cost0 -- by
``relinearized_cost``: the corrected flight relinearised about its own smoothed errors, **on
the whole flight from its first update** (the analysis' prior; session 18). Started at the
check's window from the prior of the analysis' relinearised pass, the refits inherited that
pass's linearisation point -- the smoothed errors of the *faulty* flight, which the fault moved
before its own onset: on a real straight leg a gyro y step of 3000 deg/h was named its tilt
twin, the accelerometer x ramp, by a gap of 29 (the two within 2.3 as linear fits; the gyro's
refit 30 worse than its own linear fit) -- docs/ins3d_relinearize.md, "Session 18". All of
them (``REFITTED``), not the best few as recorded: that ranking is the biased one (a 20-mg
accelerometer x step, the truth, ranked last of four and a 27 500-deg/h yaw step was named).
About 5 x 5 relinearised evaluations (3 forward passes and 2 backward sweeps of the flight
each; the magnitude by ``_parabola_min``) more. On such a flight every confident (``single``)
decision whose best or rival is a gyro is checked (``analysis``: limit 0), not only those
turning by ``SMALL_ANGLE_RAD``: the linear signatures were taken about an estimate the fault
itself moved (a gyro step of 200 deg/h 75 s before the end of a 5-min flight, 4 deg, was named
an accelerometer ramp). An ambiguous decision stays so: on the real vertical flights a
1000-deg/h gyro step found 4 s late by the 1-Hz reference was checked from the late onset and
named an accelerometer.
"""
from __future__ import annotations

import math
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from ..threads import usable_threads
from .data import NavSteps, RefRows
from .filter import run_forward
from .glr3d import AMBIGUITY_MARGIN, GlrCurve, Isolation
from .postflight import smoothed_states
from .relinearize import MAX_PASSES, relinearized
from ..rotation import qdcm, qexp
from .model import IV, Ins3dModel
from .dynamics import fill_F, transition

#: the attitude a named gyro fault may turn over the flight (rad, |b| (T - onset), a ramp
#: |b| (T - onset)^2 / 2) before the decision is checked nonlinearly: the linear signature's
#: relative error is about half the angle (5 % here)
SMALL_ANGLE_RAD = 0.1
#: the magnitude grid: the linear estimate times 10^(-GRID_DECADES .. +GRID_DECADES), both signs
GRID_DECADES = 1.5
GRID_POINTS = 9
#: at most this many onsets (steps) scanned per hypothesis
MAX_ONSETS = 16
#: on a relinearised flight: the best this many fits are refitted relinearised (``refit``);
#: every tested fit (``tested``: at most 5): ranked as recorded, the true accelerometer x step
#: of a 5-min MEMS flight was the worst of four and was not refitted (docs/ins3d_relinearize.md)
REFITTED = 5
#: a refit (``_parabola_min``): the first three magnitudes b0 (1 -+ spread), at most this many
#: parabola vertices after them, none closer than ``REFIT_TOL`` b0 to a point already costed
REFIT_SPREAD = 0.1
REFIT_STEPS = 3
REFIT_TOL = 1e-3


@njit(cache=True, nogil=True)
def _effect(C, f_n, w_b, v, lat, h, dt, t, bias, k0, gyro, axis, ramp, mag, x_out, D_mid):
    """x_out[k] (K+1, n): the error state the fault leaves at boundary k; D_mid[k] (K, 3, 3):
    the body-frame correction at mid-step k (module docstring)."""
    n = x_out.shape[1]
    K = dt.size
    F, Phi, F2 = np.empty((n, n)), np.empty((n, n)), np.empty((n, n))
    x = np.zeros(n)             # the bias states get no input: they stay zero
    D = np.eye(3)
    A, B = np.empty((3, 3)), np.empty((3, 3))
    u_g, u_a = np.zeros(3), np.zeros(3)
    u = u_g if gyro else u_a
    for k in range(K):
        x_out[k] = x
        if k < k0:
            D_mid[k] = D
            continue
        u[axis] = mag * (0.5 * (t[k] + t[k + 1]) - t[k0]) if ramp else mag
        f_b = C[k].T @ f_n[k]
        a = -w_b[k] * dt[k]
        qdcm(*qexp(a[0], a[1], a[2]), A)                    # exp([-w dt x])
        a = (w_b[k] - u_g) * dt[k]
        qdcm(*qexp(a[0], a[1], a[2]), B)                    # exp([(w - u_g) dt x])
        D1 = A @ D @ B
        Dm = 0.5 * (D + D1)
        g = C[k] @ (f_b - Dm @ (f_b - u_a))
        fill_F(F, C[k], f_n[k], v[k], lat[k], h[k], bias)
        transition(F, dt[k], Phi, F2)
        x = Phi @ x
        for i in range(3):
            x[IV + i] += g[i] * dt[k]
        D_mid[k] = Dm
        D = D1
    x_out[K] = x


def _orthonormal(M: np.ndarray) -> np.ndarray:
    U, _, Vt = np.linalg.svd(M)
    return U @ Vt


def corrected(model: Ins3dModel, steps: NavSteps, refs: RefRows, sensor: str, axis: str,
              kind: str, k0: int, magnitude: float) -> tuple[NavSteps, RefRows]:
    """The flight without the fault (``sensor`` accelerometer / gyro, body ``axis`` x/y/z,
    ``kind`` step / ramp from boundary ``k0``, ``magnitude`` SI), module docstring."""
    K = len(steps)
    x = np.empty((K + 1, model.n))
    D = np.empty((K, 3, 3))
    gyro = sensor == "gyro"
    i = "xyz".index(axis)
    _effect(steps.C, steps.f_n, steps.w_b, steps.v, steps.lat, steps.h, steps.dt, steps.t,
            model.kernel_params(), int(k0), gyro, i, kind == "ramp", float(magnitude), x, D)
    tm = 0.5 * (steps.t[1:] + steps.t[:-1]) - steps.t[min(k0, K)]
    u = np.zeros((K, 3))
    u[k0:, i] = magnitude * (tm[k0:] if kind == "ramp" else 1.0)
    Cc = steps.C @ _orthonormal(D)
    f_b = np.einsum("kji,kj->ki", steps.C, steps.f_n)
    f_c = np.einsum("kij,kj->ki", Cc, f_b - (0.0 if gyro else u))
    xm = 0.5 * (x[1:] + x[:-1])
    h = steps.h - xm[:, model.ih] if model.ih >= 0 else steps.h
    out = NavSteps(steps.t, steps.dt, np.ascontiguousarray(Cc), f_c,
                   steps.w_b - (u if gyro else 0.0), steps.v - xm[:, IV:IV + 3], steps.lat, h)
    z = refs.z - x[refs.step][:, model.row_states]
    return out, RefRows(refs.t, np.ascontiguousarray(z), refs.r, refs.step, refs.a)


def neg2_log_likelihood(model: Ins3dModel, steps: NavSteps, refs: RefRows,
                        P0: np.ndarray, x0: np.ndarray | None = None) -> float:
    """-2 ln L (up to a constant) of the no-fault forward filter: sum nu' S^-1 nu + ln det S."""
    return run_forward(model, steps, refs, x0=x0, P0=P0, threads=1).neg2_log_likelihood()


@dataclass
class Window:
    """The flight from update ``j`` on (its steps from that update's boundary), with the
    forward filter's state and covariance before that update: the likelihood of a fault that
    starts later, without filtering the part of the flight it leaves unchanged again."""

    steps: NavSteps
    refs: RefRows
    x0: np.ndarray
    P0: np.ndarray

    @classmethod
    def of(cls, steps: NavSteps, refs: RefRows, fwd, j: int) -> "Window":
        k = int(refs.step[j])
        w = NavSteps(steps.t[k:], steps.dt[k:], steps.C[k:], steps.f_n[k:], steps.w_b[k:],
                     steps.v[k:], steps.lat[k:], steps.h[k:])
        r = RefRows(refs.t[j:], refs.z[j:], refs.r[j:], refs.step[j:] - k, refs.a[j:])
        return cls(w, r, *fwd.prior(j))


@dataclass
class Fit:
    """One hypothesis fitted by exact removal (``fit``)."""

    name: str
    sensor: str
    axis: str
    kind: str
    onset: float               # s (the step grid's time)
    magnitude: float           # SI
    cost: float                # -2 ln L of the corrected flight (on the check's window)


def fit(model: Ins3dModel, win: Window, curve: GlrCurve, k_range: tuple[int, int],
        t_first: float) -> Fit:
    """Onset (a step boundary of the window in ``k_range``) and magnitude of ``curve``'s
    hypothesis by exact removal (module docstring, "The fit"), the magnitude first searched at
    the onset ``t_first`` (the decision's best's: where the data change)."""
    from scipy.optimize import minimize_scalar    # (0.4 s to import: only when a check runs)
    h = curve.hypothesis

    def cost(k: int, b: float) -> float:
        return neg2_log_likelihood(model, *corrected(model, win.steps, win.refs, h.sensor,
                                                     h.axis, h.kind, k, b), win.P0, win.x0)

    def magnitude(k: int, b0: float) -> tuple[float, float]:
        scale = max(abs(b0), 3.0 * float(curve.sd[curve.best]), 1e-12)
        grid = scale * 10.0 ** np.linspace(-GRID_DECADES, GRID_DECADES, GRID_POINTS)
        grid = np.concatenate([-grid[::-1], [0.0], grid])
        vals = np.array([cost(k, b) for b in grid])
        j = int(np.argmin(vals))
        lo, hi = grid[max(j - 1, 0)], grid[min(j + 1, grid.size - 1)]
        if hi > lo:
            r = minimize_scalar(lambda b: cost(k, b), bounds=(lo, hi), method="bounded",
                                options={"xatol": 3e-3 * max(abs(grid[j]), 1e-12)})
            if r.fun < vals[j]:
                return float(r.x), float(r.fun)
        return float(grid[j]), float(vals[j])

    k = int(np.clip(np.searchsorted(win.steps.t, t_first), *k_range))
    b, c = magnitude(k, float(curve.mag[curve.best]))
    ks = np.unique(np.round(np.linspace(k_range[0], k_range[1],
                                        min(MAX_ONSETS, k_range[1] - k_range[0] + 1))))
    scan = np.array([cost(int(j), b) for j in ks])
    if scan.min() < c:
        k = int(ks[np.argmin(scan)])
        lo, hi = sorted((0.5 * b, 2.0 * b))
        r = minimize_scalar(lambda x: cost(k, x), bounds=(lo, hi), method="bounded",
                            options={"xatol": 3e-3 * abs(b) + 1e-15})
        b, c = (float(r.x), float(r.fun)) if r.fun < scan.min() else (b, float(scan.min()))
    return Fit(h.name, h.sensor, h.axis, h.kind, float(win.steps.t[k]), b, c)


def implied_angle(curve: GlrCurve, t_end: float) -> float:
    """The attitude a gyro hypothesis' linear estimate turns by ``t_end`` (rad; 0 otherwise)."""
    h = curve.hypothesis
    if h.sensor != "gyro":
        return 0.0
    span = max(t_end - float(curve.t[curve.best]), 0.0)
    b = abs(float(curve.mag[curve.best]))
    return b * span if h.kind == "step" else 0.5 * b * span * span


def needs_check(cv: dict[str, GlrCurve], iso: Isolation, t_end: float,
                limit: float = SMALL_ANGLE_RAD) -> bool:
    """Whether the decision's best or rival (single or ambiguous) is a gyro hypothesis whose
    linear estimate turns the attitude by more than ``limit``."""
    if iso.isolation not in ("single", "ambiguous"):
        return False
    return any(implied_angle(cv[n], t_end) > limit for n in (iso.best, iso.rival) if n)


@dataclass
class NonlinearCheck:
    """What ``confirm`` tested and decided."""

    fits: list[Fit] = field(default_factory=list)
    #: on a relinearised flight: the best ``REFITTED`` fits refitted under the relinearised
    #: model (``refit``) -- what the decision is then made on (``cost0`` too)
    refits: list[Fit] = field(default_factory=list)
    before: str = ""             # the decision before: "single gyro_x_step", ...
    after: str = ""
    cost0: float = 0.0           # -2 ln L of the flight as it is (no fault)
    statistic: float = 0.0       # cost0 - the best fit's: the likelihood ratio of the best
    gap: float = 0.0             # the runner-up's cost - the best's
    allowance: float = 0.0       # the gap a single answer needs: margin + statistic sin^2(eps)

    def fit_of(self, name: str | None) -> Fit | None:
        """The fit the decision used: the refit when there is one."""
        return next((f for f in self.refits + self.fits if f.name == name), None)

    def record(self, t0: float = 0.0) -> dict:
        """The result's ``nonlinear`` section."""
        def fits(fs: list[Fit]) -> list[dict]:
            return [{"hypothesis": f.name, "onset_s": f.onset - t0, "magnitude": f.magnitude,
                     "neg2_log_likelihood": f.cost} for f in fs]
        return {"before": self.before, "after": self.after, "statistic": self.statistic,
                "gap": self.gap, "allowance": self.allowance, "fits": fits(self.fits),
                "relinearized_fits": fits(self.refits) if self.refits else None}


def tested(cv: dict[str, GlrCurve], iso: Isolation) -> list[str]:
    """The decision's best and rival, and the gyro steps of the three axes."""
    names = [iso.best, iso.rival] + [f"gyro_{a}_step" for a in "xyz"]
    return [n for i, n in enumerate(names) if n and n in cv and n not in names[:i]
            and cv[n].hypothesis.kind in ("step", "ramp")]


def relinearized_cost(model: Ins3dModel, steps: NavSteps, refs: RefRows, x0: np.ndarray,
                      P0: np.ndarray, rank_tol: float) -> float:
    """-2 ln L of the no-fault forward filter on the flight relinearised about its own smoothed
    errors (``relinearize``): passes kept while they lower it, at most ``MAX_PASSES`` (the
    analysis' rule); the linear pass's when none does."""
    fwd = run_forward(model, steps, refs, x0=x0, P0=P0, keep_prior=True, threads=1)
    best, cur = fwd.neg2_log_likelihood(), (steps, refs, fwd)
    for _ in range(MAX_PASSES):
        x_s = smoothed_states(model, *cur, rank_tol)
        s2, r2 = relinearized(model, steps, refs, x_s)
        f2 = run_forward(model, s2, r2, x0=x0, P0=P0, keep_prior=True, threads=1)
        cost = f2.neg2_log_likelihood()
        if cost >= best:
            break
        best, cur = cost, (s2, r2, f2)
    return best


def refit(model: Ins3dModel, win: Window, f: Fit, rank_tol: float) -> Fit:
    """``f``'s magnitude refitted (its onset kept) by ``relinearized_cost`` of the corrected
    flight: on a flight whose no-fault errors leave small angles the fits must be compared with
    the model the analysis uses there -- linear about zero, the fault-free MEMS flight's own
    5-10 deg of attitude error leave a misfit that a large yaw fault absorbs
    (docs/ins3d_relinearize.md). The cost is close to quadratic in the magnitude (exactly so
    for a linear model): three points around the fit's magnitude, then the vertex of the
    parabola through the best three, at most ``REFIT_STEPS`` times (``_parabola_min``)."""
    k = int(np.searchsorted(win.steps.t, f.onset))

    def cost(b: float) -> float:
        return relinearized_cost(model, *corrected(model, win.steps, win.refs, f.sensor, f.axis,
                                                   f.kind, k, b), win.x0, win.P0, rank_tol)

    b, c = _parabola_min(cost, f.magnitude)
    return Fit(f.name, f.sensor, f.axis, f.kind, f.onset, b, c)


def _parabola_min(cost, b0: float) -> tuple[float, float]:
    """(b, cost(b)): the least of ``cost`` near ``b0`` (within 0.5 .. 2 times it): ``cost`` at
    b0 and b0 (1 -+ REFIT_SPREAD), then at the vertex of the parabola through the three least
    points while it is a minimum, moves by more than ``REFIT_TOL`` of b0 and the steps last.
    A fit of magnitude 0 (its hypothesis explains nothing: the linear fit's grid holds 0) is
    the no-fault flight's cost, with no bracket to search."""
    if b0 == 0.0:
        return 0.0, float(cost(0.0))
    lo, hi = sorted((0.5 * b0, 2.0 * b0))
    pts = {b: cost(b) for b in (b0 * (1.0 - REFIT_SPREAD), b0, b0 * (1.0 + REFIT_SPREAD))}
    for _ in range(REFIT_STEPS):
        (x1, y1), (x2, y2), (x3, y3) = sorted(sorted(pts.items(), key=lambda p: p[1])[:3])
        den = (x2 - x1) * (y2 - y3) - (x2 - x3) * (y2 - y1)
        num = (x2 - x1) ** 2 * (y2 - y3) - (x2 - x3) ** 2 * (y2 - y1)
        if den == 0.0 or (y3 - y2) / (x3 - x2) <= (y2 - y1) / (x2 - x1):
            break                                   # not convex: no vertex to go to
        x = float(np.clip(x2 - 0.5 * num / den, lo, hi))
        if min(abs(x - p) for p in pts) <= REFIT_TOL * abs(b0):
            break
        pts[x] = cost(x)
    b = min(pts, key=pts.get)
    return float(b), float(pts[b])


def confirm(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd,
            cv: dict[str, GlrCurve], iso: Isolation, eps: float,
            margin: float = AMBIGUITY_MARGIN,
            rank_tol: float | None = None) -> NonlinearCheck:
    """The nonlinear check (module docstring); ``fwd`` the flight's forward pass (with the
    priors: ``run_forward(keep_prior=True)``), ``eps`` the model's relative signature error
    (``glr3d.settle``). When the analysis relinearised the flight, ``rank_tol`` = the backward
    sweep's (None: not relinearised): the best ``REFITTED`` fits are then refitted and compared
    relinearised (``refit``), on the whole flight from the analysis' prior. Changes ``iso`` in
    place."""
    j_of = {float(t): j for j, t in enumerate(refs.t)}
    own = [j_of.get(float(cv[n].t[cv[n].best]), 0) for n in (iso.best, iso.rival) if n]
    j0, j1 = max(min(own) - 2, 0), min(max(own) + 1, refs.t.size - 1)
    win = Window.of(steps, refs, fwd, j0)
    check = NonlinearCheck(before=f"{iso.isolation} {iso.best}",
                           cost0=neg2_log_likelihood(model, win.steps, win.refs, win.P0, win.x0))
    k_range = (0, int(refs.step[j1] - refs.step[j0]))
    t_first = float(cv[iso.best].t[cv[iso.best].best])
    with ThreadPoolExecutor(max_workers=max(1, min(2, usable_threads()))) as pool:
        check.fits = list(pool.map(lambda n: fit(model, win, cv[n], k_range, t_first),
                                   tested(cv, iso)))
        if rank_tol is not None and REFITTED > 0:
            rwin = Window.of(steps, refs, fwd, 0)
            top = sorted(check.fits, key=lambda f: f.cost)[:REFITTED]
            check.refits = list(pool.map(lambda f: refit(model, rwin, f, rank_tol), top))
            check.cost0 = relinearized_cost(model, rwin.steps, rwin.refs, rwin.x0, rwin.P0,
                                            rank_tol)
    best, rival = sorted(check.refits or check.fits, key=lambda f: f.cost)[:2]
    check.statistic = check.cost0 - best.cost
    check.gap = rival.cost - best.cost
    check.allowance = margin + max(check.statistic, 0.0) * math.sin(eps) ** 2
    iso.best, iso.rival, iso.reason = best.name, rival.name, "nonlinear"
    iso.isolation = "single" if check.gap > check.allowance else "ambiguous"
    iso.ambiguity_resolved_s = None
    check.after = f"{iso.isolation} {iso.best}"
    return check


__all__ = ["Fit", "NonlinearCheck", "REFITTED", "SMALL_ANGLE_RAD", "Window", "confirm",
           "corrected", "fit", "implied_angle", "needs_check", "neg2_log_likelihood", "refit",
           "relinearized_cost", "tested"]
