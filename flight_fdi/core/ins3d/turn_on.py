"""A turn-on bias told apart from an in-flight step (docs/ins3d.md, "Turn-on bias").

A bias step whose most likely onset is the flight's **first reference update** is a bias that
was there from the start: the data cannot tell it from a residual turn-on bias beyond the
grade's prior (the fault column at the first onset and the bias state are the same error, the
step's GLR measures how far the bias is beyond its prior). It is information (which sensor and
body axis, how large, how many prior sigmas), but not an in-flight failure with an onset, and
it must not hide the in-flight fault: on real MEMS recordings (docs/ins3d_real.md) such a step
beat the injected in-flight fault on 8 of 1296 runs, and the pair test (``glr3d.settle``) never
saw the right one, which was not the runner-up.

``decide``: when IMU step hypotheses above their thresholds have their best onset at the
first update (the turn-on candidates; the *best* onset, not the onset interval reaching it: an
in-flight step with a wide interval stays an in-flight step -- it must not be hidden -- and a
turn-on bias whose best onset is a later update is reported as an in-flight step with its
interval, as before), the largest is taken as present (``Given``) and every hypothesis is
fitted together with it, **its onset searched again**: the conditional GLR of h at onset theta
given the turn-on biases S,

    e_c = e_h - X' D_S^+ e_S,   d_c = d_h - X' D_S^+ X,   GLR = e_c^2 / d_c

(X the cross information of h at theta with the signatures of S, for every onset and hypothesis
in one backward sweep per turn-on bias: ``postflight.fault_information``; e_S, D_S the turn-on
biases' statistics from their forward signatures: the Schur complement, i.e. the joint fit with
S profiled out). A conditional step still best at the first onset is a further turn-on bias
(up to ``MAX_TURN_ON``). The in-flight fault is then decided by ``glr3d.isolate`` on the
conditional curves (the same thresholds and margin; the outlier curves are the unconditional
ones: a bias from the start does not change one update's outlier statistic), and its pair test
(``postflight.resolve``) with S profiled out as well.

When the unconditional decision names a hypothesis that is not a turn-on candidate (an
in-flight fault), a turn-on bias must stay above its threshold with the strongest
in-flight hypothesis given it (the conditional in-flight fault, or the top conditional curve
when none is above its threshold) fitted beside it (its GLR given all the others); otherwise
it was that in-flight fault seen through a step at the first update, and the unconditional
decision stands. When the unconditional decision names a turn-on candidate itself (the old
answer: an in-flight failure at the first update), the decision given the turn-on biases is
taken in any case. The turn-on magnitudes are from the joint fit (with a ``single`` in-flight
fault beside them).
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..result import ENGINEERING, _num
from .backward import GROUP_SIZE, GROUP_START
from .data import NavSteps, RefRows
from .filter import Ins3dForward
from .glr3d import AMBIGUITY_MARGIN, GlrCurve, Isolation, isolate, threshold_of
from .model import Ins3dModel
from .postflight import (Ins3dBackward, fault_information, fused_forward, glr_curves, resolve,
                         signature)

#: the most turn-on biases taken as present at once
MAX_TURN_ON = 3
#: a conditional onset whose information is below this fraction of the unconditional one is
#: the given fault itself (nothing left to test)
_DEGENERATE = 1e-6


def _pinv(D: np.ndarray) -> np.ndarray:
    return np.linalg.pinv(D, rcond=1e-10, hermitian=True)


@dataclass
class Given:
    """Faults taken as present at fixed onsets: their forward signatures rho (k, M, rows) and
    their statistics with the data up to every update: e (M, k), information D (M, k, k), cross
    terms included."""

    names: list[str]
    rho: np.ndarray
    e: np.ndarray
    D: np.ndarray
    Sr: np.ndarray              # (k, M, rows) S^-1 rho

    @classmethod
    def of(cls, names: list[str], sigs: list[tuple], S_inv: np.ndarray) -> Given:
        """From the ``postflight.signature`` (e, d, rho) of each and the forward S^-1."""
        rho = np.stack([s[2] for s in sigs])
        Sr = np.einsum("mij,kmj->kmi", S_inv, rho)
        D = np.cumsum(np.einsum("kmi,lmi->mkl", rho, Sr), axis=0)
        return cls(list(names), rho, np.stack([s[0] for s in sigs], axis=1), D, Sr)

    def fit(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """With all the data: the joint estimate b (k,) in scaled units, its covariance and
        each one's GLR given all the others, b_i^2 / cov_ii."""
        P = _pinv(self.D[-1])
        b = P @ self.e[-1]
        var = np.diag(P)
        return b, P, np.where(var > 0, b * b / np.where(var > 0, var, 1.0), 0.0)

    def condition(self, e: np.ndarray, D: np.ndarray, rho: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
        """Statistics e (M, p), D (M, p, p) of p other faults (signatures rho (p, M, rows)) with
        the given ones profiled out, at every update."""
        X = np.cumsum(np.einsum("pmi,kmi->mpk", rho, self.Sr), axis=0)
        XP = X @ _pinv(self.D)
        return e - np.einsum("mpk,mk->mp", XP, self.e), D - XP @ X.transpose(0, 2, 1)


def candidates(cv: dict[str, GlrCurve], thresholds: dict[str, float],
               exclude: tuple = ()) -> list[str]:
    """The IMU step and reference jump hypotheses whose best onset is the first update and
    whose GLR is above their own threshold (``glr3d.threshold_of``), largest first
    (``exclude``: (sensor, axis) pairs left out)."""
    out = [c for c in cv.values() if c.hypothesis.kind in ("step", "jump") and c.best == 0 and
           c.statistic > threshold_of(thresholds, c.hypothesis) and
           (c.hypothesis.sensor, c.hypothesis.axis) not in exclude]
    return [c.hypothesis.name for c in sorted(out, key=lambda c: -c.statistic)]


def conditional_curves(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
                       bwd: Ins3dBackward, cv: dict[str, GlrCurve], given: Given
                       ) -> dict[str, GlrCurve]:
    """Every hypothesis' GLR curve given the faults ``given`` (module docstring): the sweep's
    eta and group blocks of I corrected by the cross information X (one sweep per given
    fault), e_c = e - X D^+ e_S, I_c = I - X D^+ X' in each group, then ``glr3d.curves``."""
    at = bwd.at_onsets
    X = np.stack([at(fault_information(model, steps, refs, fwd, r)) for r in given.rho])
    P = _pinv(given.D[-1])
    eta = at(bwd.eta) - np.einsum("kup,k->up", X, P @ given.e[-1])
    I3 = at(bwd.I3).copy()
    for g, m in enumerate((GROUP_SIZE, GROUP_SIZE, model.rows)):
        Xg = X[:, :, GROUP_START[g]:GROUP_START[g] + m]
        I3[:, g, :m, :m] -= np.einsum("kua,kl,lub->uab", Xg, P, Xg)
    out = glr_curves(model, steps, bwd, eta, I3)
    for name, c in out.items():
        if c.hypothesis.kind == "outliers":
            out[name] = cv[name]
            continue
        with np.errstate(invalid="ignore", divide="ignore"):
            left = (cv[name].sd / c.sd) ** 2        # I_c / I at each onset
        gone = ~(left >= _DEGENERATE)
        c.stat[gone], c.mag[gone], c.sd[gone] = 0.0, np.nan, np.nan
    return out


@dataclass
class TurnOn:
    """The turn-on biases and the in-flight decision given them."""

    names: list[str]                   # the turn-on step hypotheses (onset: the first update)
    curves: dict[str, GlrCurve]        # every hypothesis given them (the in-flight decision's)
    isolation: Isolation               # the in-flight decision
    magnitude: np.ndarray              # (k,) SI, fitted jointly (with the in-flight fault)
    sd: np.ndarray                     # (k,) its sd
    prior_sd: np.ndarray               # (k,) the grade's turn-on bias sd (SI; reference: nan)
    statistic: np.ndarray              # (k,) GLR of each given all the others
    unconditional: dict[str, float] = field(default_factory=dict)   # GLR at the first onset
    alike: dict[str, list[str]] = field(default_factory=dict)   # other first-onset steps within
    onset: float = 0.0                                          # the margin; the first update

    def records(self, cv: dict[str, GlrCurve], thresholds: dict[str, float],
                t0: float = 0.0) -> list[dict]:
        """The ``post_flight.turn_on_bias`` list (times relative to ``t0``)."""
        out = []
        for i, name in enumerate(self.names):
            h = cv[name].hypothesis
            unit_eng, factor = ENGINEERING[(h.sensor, h.kind)]
            sign = -1.0 if h.sensor == "reference" else 1.0     # the reference's error
            m, sd = sign * float(self.magnitude[i]), float(self.sd[i])
            out.append({
                "sensor": h.sensor, "axis": h.axis, "hypothesis": name,
                "onset_s": _num(self.onset - t0), "magnitude": _num(m), "unit": h.unit,
                "magnitude_eng": _num(m * factor), "unit_eng": unit_eng,
                "magnitude_std": _num(sd), "prior_std": _num(self.prior_sd[i]),
                "prior_sigmas": _num(abs(m) / self.prior_sd[i]),   # reference: None
                "statistic": _num(self.unconditional[name]),
                "statistic_given_others": _num(self.statistic[i]),
                "threshold": threshold_of(thresholds, h), "alike": self.alike.get(name, [])})
        return out


def describe_turn_on(r: dict) -> str:
    """"accelerometer y turn-on bias of +52.1 mg (0.511 m/s^2) +- 4.2, 1.0 prior sigmas, from
    the start"."""
    alike = " (or " + ", ".join(a.rsplit("_", 1)[0].replace("_", " ") for a in r["alike"]) \
        + ")" if r["alike"] else ""
    if r["sensor"] == "reference":
        return (f"{r['sensor']} {r['axis']}{alike} offset of {r['magnitude']:+.3g} {r['unit']} "
                f"+- {r['magnitude_std']:.2g}, from the start")
    sd = r["magnitude_std"] * r["magnitude_eng"] / r["magnitude"] if r["magnitude"] else 0.0
    return (f"{r['sensor']} {r['axis']}{alike} turn-on bias of {r['magnitude_eng']:+.3g} "
            f"{r['unit_eng']} ({r['magnitude']:.3g} {r['unit']}) +- {abs(sd):.2g}, "
            f"{r['prior_sigmas']:.1f} prior sigmas, from the start")


def _signatures(model, steps, refs, fwd, cv: dict[str, GlrCurve], names: list[str]) -> list:
    return [signature(model, steps, refs, fwd, cv[n]) for n in names]


def decide(model: Ins3dModel, steps: NavSteps, refs: RefRows, fwd: Ins3dForward,
           bwd: Ins3dBackward, cv: dict[str, GlrCurve], unconditional: Isolation,
           thresholds: dict[str, float], signature_error: float | None = None
           ) -> TurnOn | None:
    """The turn-on biases and the in-flight decision given them (module docstring); None when
    no step is best at the first update above its threshold, or when the ``unconditional``
    decision (``glr3d.isolate`` of ``cv``) names an in-flight hypothesis and a turn-on bias is
    not significant beside it (that decision stands)."""
    first = candidates(cv, thresholds)
    if not first:
        return None
    fwd = fused_forward(model, steps, refs, fwd)
    names, sigs = [first[0]], _signatures(model, steps, refs, fwd, cv, first[:1])
    while True:
        given = Given.of(names, sigs, fwd.S_inv)
        ccv = conditional_curves(model, steps, refs, fwd, bwd, cv, given)
        more = candidates(ccv, thresholds, tuple((cv[n].hypothesis.sensor,
                                                  cv[n].hypothesis.axis) for n in names))
        if not more or len(names) == MAX_TURN_ON:
            break
        names.append(more[0])
        sigs += _signatures(model, steps, refs, fwd, ccv, more[:1])
    iso = isolate(ccv, thresholds)
    top = iso.best if iso.best is not None and ccv[iso.best].hypothesis.kind != "outliers" \
        else max((c for c in ccv.values() if c.hypothesis.kind != "outliers"),
                 key=lambda c: c.statistic).hypothesis.name
    beside = Given.of(names + [top], sigs + _signatures(model, steps, refs, fwd, ccv, [top]),
                      fwd.S_inv)
    if unconditional.best not in first and \
            np.any(beside.fit()[2][:len(names)] <= [threshold_of(thresholds, cv[n].hypothesis)
                                                     for n in names]):
        return None                     # an in-flight fault seen through a first-onset step
    fit = beside if iso.isolation == "single" and top == iso.best else given
    resolve(model, steps, refs, fwd, ccv, iso, signature_error, given)
    b, P, stat = fit.fit()
    k = len(names)
    scale = np.array([bwd.sB[cv[n].hypothesis.column] for n in names])
    unc = {n: float(cv[n].stat[0]) for n in names}
    alike = {n: [a for a in first if a not in names and
                 cv[a].statistic > cv[n].statistic - AMBIGUITY_MARGIN] for n in names[:1]}
    prior = np.array([np.nan if cv[n].hypothesis.sensor == "reference" else scale[i]
                      for i, n in enumerate(names)])
    return TurnOn(names, ccv, iso, b[:k] * scale, np.sqrt(np.diag(P)[:k]) * scale, prior,
                  stat[:k], unc, alike, float(cv[names[0]].t[0]))


__all__ = ["Given", "MAX_TURN_ON", "TurnOn", "candidates", "conditional_curves", "decide",
           "describe_turn_on"]
