"""How wrong the ins3d model's fault signatures are on the real recordings (docs/ins3d_real.md,
"Model error"): what ``glr3d.settle``'s ``signature_error`` allows for, measured two ways.

* ``model_error_angle``: in a fault run whose true sensor and axis is the best or the runner-up,
  the angle by which the true hypothesis misses the data in the plane of the pair beyond noise
  (what ``Settings.signature_error`` is calibrated from);
* ``signature_error``: the injected fault's real effect on the forward innovations (the same
  samples with and without it) against the model's signature of it.
"""
from __future__ import annotations

import math

import numpy as np

from ..core.ins3d.glr3d import AMBIGUITY_MARGIN, GlrCurve, hypotheses
from ..core.ins3d.postflight import signature
from .real3d import Fault, Recording, Settings, analyze


def model_error_angle(rec_out: dict, fault: Fault) -> float | None:
    """When the fault's sensor and axis is the best or the runner-up of a run (``record``)
    and the pair was fitted: the angle (rad) by which the true hypothesis's signature misses
    the data in the pair's plane beyond noise -- the signature error ``glr3d.settle`` must allow
    for the true one to stay a candidate were it the runner-up: asin sqrt(max(L2 - L_true - o -
    9.21, 0) / L2), o the other one's threshold minus the true one's (``settle`` takes the gap
    net of it: ``Isolation.offset`` = the best's minus the rival's). None otherwise."""
    L2 = rec_out.get("pair")
    if not L2 or L2 <= 0:
        return None
    offset = rec_out.get("offset", 0.0)
    for key, o in (("best", -offset), ("rival", offset)):
        name = rec_out[key] or ""
        if name.startswith(f"{fault.sensor}_{fault.axis}_"):
            miss = max(L2 - rec_out[f"{key}_statistic"] - o - AMBIGUITY_MARGIN, 0.0)
            return math.asin(math.sqrt(min(miss / L2, 1.0)))
    return None


def signature_error(rec: Recording, fault: Fault, bg: np.ndarray, ba: np.ndarray,
                    settings: Settings = Settings()) -> tuple[float, float]:
    """How far the linearised signature of an injected bias step is from its real effect:
    (psi, eps) with psi the attitude error a gyro step builds up by the end of the flight (rad;
    0 for an accelerometer step) and eps = |d nu - rho b| / |rho b| in the faulty run's S^-1
    norm, where d nu is the change of the forward innovations the fault makes (the same samples
    with and without it: the noise cancels) and rho b the model's signature of the true
    hypothesis (true onset and size, ``postflight.signature``): the relative error of the
    signature in the whole innovation space (``model_error_angle`` is its part in the plane
    that decides)."""
    a1, a0 = analyze(fault.apply(rec), bg, ba, settings), analyze(rec, bg, ba, settings)
    name = f"{fault.sensor}_{fault.axis}_step"
    h = next(x for x in hypotheses(a1.model.rows, a1.model.height_row) if x.name == name)
    t_on = float(rec.t[0] + fault.onset_s)
    one = np.ones(1)
    cv = GlrCurve(h, np.array([t_on]), one, np.array([fault.magnitude]), one)
    rho = signature(a1.model, a1.steps, a1.refs, a1.forward, cv)[2]
    pred = rho * (fault.magnitude / a1.backward.sB[h.column])
    dnu = a1.forward.nu - a0.forward.nu

    def norm2(x: np.ndarray) -> float:
        return float(np.einsum("mi,mij,mj->", x, a1.forward.S_inv, x))
    psi = abs(fault.magnitude) * float(a1.steps.t[-1] - t_on) if fault.sensor == "gyro" else 0.0
    p2 = norm2(pred)
    return psi, math.sqrt(norm2(dnu - pred) / p2) if p2 > 0 else float("nan")


__all__ = ["model_error_angle", "signature_error"]
