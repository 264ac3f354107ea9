"""A reference glitch and a sensor fault in the same flight: sequential isolation.

``glr3d.isolate`` decides one fault. Reference *outliers* above their threshold whose largest
statistic is at least that of every detected step / ramp / jump are named (verdict
``glitch``), and the step / ramp / jump is then not reported at all; outliers above their
threshold beside a larger step / ramp / jump are only counted. A GNSS glitch and an IMU fault
can happen in the same flight, and a user needs both (docs/ins3d.md, "A glitch and a fault in
the same flight").

The rule (``sequential``), one update per round, at most ``MAX_ROUNDS`` rounds:

* **outliers named**: the update with the largest outlier statistic (over the rows) is
  removed -- the whole update, all its rows -- and the flight decided again on the rest by
  the analysis' own path (``redo``: forward filter, backward sweep, relinearisation, GLR
  curves, ``isolate``, the turn-on bias, the pair test, the nonlinear check;
  ``analysis._decide_without``);
* **a single IMU step / ramp named, outliers above their threshold beside it**: those outliers
  are judged with that fault removed exactly from the flight (``given``:
  ``analysis._curves_given_fault``, ``nonlinear.corrected``). An update still above the
  threshold there is a glitch of its own and is removed as above; none left -> the outliers
  were the fault's own effect (its first updates, the no-fault smoother not following it),
  nothing is removed and the decision stands untouched;
* the rest names outliers again (or, beside a fault, a glitch given the rest's fault): the
  next round;
* the rest names a fault (``single`` or ``ambiguous``, not outliers): that is the decision,
  the removed glitches reported beside it (``post_flight.glitches``; the headline says both);
  it names nothing: the first decision stands, its glitches listed too.

One update per round (Baarda's data snooping): a large spike pulls the smoothed states, so the
updates next to it exceed the threshold too (a 3-m/s spike on the real 1-Hz excerpt: 2048 at
the spike, 55-98 on four neighbours); removing them all would remove the fault's evidence
around it, removing the spike alone leaves them at their nominal size.

Why the whole update and not only the row: the rest is then a flight the analysis already
handles (one reference message fewer), with no pseudo-infinite variance in the scaled filter
and no row counted as a degree of freedom of the seed method's chi^2 without data in it; a
receiver's velocity glitch (multipath, a bad Doppler epoch) is an event of the fix, so its
other rows are not known to be clean because they stay below the threshold; and the cost is
one update of the other rows (0.1 s at 10 Hz; 1 of 10-37 on the real 1-Hz contracts).

Why outliers beside a decision are judged given the fault and not removed as they are: on the
real recordings 184 fault runs (setting d) had outliers above their threshold beside a named
fault, 162 of them right answers; with the named fault removed exactly (160 name a single IMU
step) none stayed above it -- they were the fault's own effect, and removing them would have
reported false glitches on most right answers and removed the fault's evidence; in setting
(i) only vertical/path_14's own glitch stayed (docs/ins3d_real.md). Not done beside an ``ambiguous``
decision, a reference jump, or a decision given a turn-on bias (the bias would stay in the
flight).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Callable

import numpy as np

from ..result import _num, describe
from .data import RefRows
from .glr3d import HEIGHT, GlrCurve

#: removal rounds at most: one update each (the largest outlier statistic), then a new
#: decision on the rest. A GNSS glitch is often a burst of epochs: with 3, bursts of 4-6
#: spikes on the simulator hid 9 of 40 accelerometer steps (docs/ins3d.md, "Measured on the
#: strapdown simulator"); a round costs one analysis of the rest
MAX_ROUNDS = 12


def names_outliers(analysis: Any) -> bool:
    """Whether the analysis' decision names reference outliers (verdict ``glitch``)."""
    iso = analysis.isolation
    return iso is not None and iso.isolation == "single" and iso.best is not None and \
        analysis.decision_glr[iso.best].hypothesis.kind == "outliers"


def names_a_fault(analysis: Any) -> bool:
    """Whether the decision names a sensor fault: ``single`` or ``ambiguous``, not outliers, on
    enough data (the seed method's ``insufficient_data`` names nothing)."""
    iso = analysis.isolation
    return iso is not None and iso.isolation in ("single", "ambiguous") and \
        not names_outliers(analysis) and analysis.seed.verdict != "insufficient_data"


def outlier_curves(cv: dict[str, GlrCurve]) -> list[GlrCurve]:
    return [c for c in cv.values() if c.hypothesis.kind == "outliers"]


def without(refs: RefRows, drop: int) -> RefRows:
    """``refs`` without the update ``drop`` (an index)."""
    keep = np.ones(refs.t.size, dtype=bool)
    keep[drop] = False
    return RefRows(refs.t[keep], np.ascontiguousarray(refs.z[keep]),
                   np.ascontiguousarray(refs.r[keep]), refs.step[keep],
                   np.ascontiguousarray(refs.a[keep]))


@dataclass(frozen=True)
class Removal:
    """One removed update: the round, its index among that round's updates, its time, the row
    with the largest outlier statistic there and that row's statistic, the offset of
    z = v_INS - v_ref (``GlrCurve.mag``) and its sd, the threshold, and every row above it."""

    round: int
    index: int
    t: float
    axis: str
    hypothesis: str
    statistic: float
    offset: float
    offset_std: float
    threshold: float
    rows_above: tuple[str, ...]

    @classmethod
    def top(cls, rnd: int, cv: dict[str, GlrCurve], threshold: float) -> "Removal":
        """The update with the largest outlier statistic over the rows of ``cv``."""
        c = max(outlier_curves(cv), key=lambda o: o.statistic)
        j = c.best
        above = tuple(o.hypothesis.axis for o in outlier_curves(cv) if o.stat[j] > threshold)
        return cls(rnd, j, float(c.t[j]), c.hypothesis.axis, c.hypothesis.name,
                   float(c.stat[j]), float(c.mag[j]), float(c.sd[j]), threshold, above)


def glitch_records(removals: list[Removal], t0: float = 0.0) -> list[dict]:
    """``post_flight.glitches``: per reference row, the removed updates whose largest outlier
    statistic is on it, as a fault record (``$defs/fault``, kind ``outliers``: first and last
    time, count, the largest statistic with its magnitude, signed as the reference's error:
    -offset) with every time (``times_s``), the removal rounds and the rows above the
    threshold at those updates."""
    out = []
    for axis in dict.fromkeys(r.axis for r in removals):
        rs = [r for r in removals if r.axis == axis]
        top = max(rs, key=lambda r: r.statistic)
        mag = _num(-top.offset)
        out.append({
            "sensor": "reference", "axis": axis, "kind": "outliers",
            "hypothesis": top.hypothesis, "onset_s": _num(min(r.t for r in rs) - t0),
            "onset_interval_s": None, "end_s": _num(max(r.t for r in rs) - t0),
            "count": len(rs), "magnitude": mag, "unit": "m" if axis == HEIGHT else "m/s",
            "magnitude_eng": mag, "unit_eng": "m" if axis == HEIGHT else "m/s",
            "magnitude_std": _num(top.offset_std), "statistic": top.statistic,
            "threshold": top.threshold, "runner_up": None,
            "times_s": [_num(r.t - t0) for r in sorted(rs, key=lambda r: r.t)],
            "rounds": [r.round for r in sorted(rs, key=lambda r: r.t)],
            "rows_above": sorted({a for r in rs for a in r.rows_above})})
    return out


@dataclass
class Sequential:
    """The removed updates and the decision on the rest (module docstring)."""

    removals: list[Removal]
    rest: Any                      # the Ins3dAnalysis of the flight without them
    found: bool                    # the rest names a fault: it is the decision
    outliers_left: bool = False    # the rest named outliers again after the last round
    beside: bool = False           # the first decision named a fault, the glitch beside it

    def records(self, t0: float = 0.0) -> list[dict]:
        return glitch_records(self.removals, t0)

    def post_flight(self, original: dict | None, t0: float = 0.0) -> dict:
        """The ``post_flight`` dict: the rest's decision with the glitches beside it when it
        names a fault, else ``original`` (the first decision); ``glitches`` added."""
        recs = self.records(t0)
        told = "; ".join(describe(r) for r in recs)
        if self.found:
            out = self.rest.post_flight_dict(t0)
            out["headline"] = (f"{out['headline']}; and a reference glitch, removed before "
                               f"this decision: {told}")
        else:
            out = dict(original)
            out["headline"] = original["headline"] + (
                f"; and a reference glitch: {told} (without it the flight names no fault: the "
                "decision with it stands)" if self.beside else
                f" (outliers left after removing {len(self.removals)} updates: not searched "
                "further)" if self.outliers_left else
                " (no other fault without the glitch's updates)")
        out["glitches"] = recs
        return out


def _glitch_curves(analysis: Any, given: Callable[[Any], dict | None] | None
                   ) -> dict[str, GlrCurve] | None:
    """The outlier curves a glitch is removed by: the decision's when it names outliers; when
    it names a fault with outliers above their threshold beside it, those of the flight with
    that fault removed exactly (``given``), if an update stays above the threshold there (else
    the outliers were the fault's own effect); None: no glitch."""
    if names_outliers(analysis):
        return analysis.glr
    if given is None or not names_a_fault(analysis):
        return None
    cv = given(analysis)
    thr = analysis.thresholds["outliers"]
    if cv is None or not any(c.statistic > thr for c in outlier_curves(cv)):
        return None
    return cv


def sequential(analysis: Any, redo: Callable[[RefRows], Any], refs: RefRows,
               given: Callable[[Any], dict | None] | None = None,
               max_rounds: int = MAX_ROUNDS) -> Sequential | None:
    """The sequential decision of ``analysis`` (module docstring); None when no glitch is
    found (nothing changes) or ``max_rounds`` is 0. ``refs``: the updates as recorded
    (``Ins3dAnalysis.as_recorded``), in the analysis' order; ``redo(refs)``: the analysis of
    the same flight with these updates; ``given(a)``: the GLR curves of ``a``'s flight with
    its named fault removed exactly (None: not such a decision; None for ``given``: only
    named outliers are removed)."""
    if max_rounds <= 0:
        return None
    removals, cur, beside = [], analysis, not names_outliers(analysis)
    for r in range(1, max_rounds + 1):
        cv = _glitch_curves(cur, given) if refs.t.size > 1 else None
        if cv is None:
            break
        removals.append(Removal.top(r, cv, cur.thresholds["outliers"]))
        refs = without(refs, removals[-1].index)
        cur = redo(refs)
    if not removals:
        return None
    return Sequential(removals, cur, names_a_fault(cur), names_outliers(cur), beside)


__all__ = ["MAX_ROUNDS", "Removal", "Sequential", "glitch_records", "names_a_fault",
           "names_outliers", "sequential", "without"]
