"""The INS height loop of the ins3d model's ``vertical="loop"`` channel (``core.ins3d.model``):
the third-order loop on the aiding height that the simulator's INS (``sim.strapdown``; Widnall &
Sinha) and many real ones mechanize, with the aiding height's error model.

On e = h_INS - h_aid, with the aiding error b (baro or reference height error), per step the INS
adds -k1 e dt to h and -(k2 e + k3 int e) dt to v_U, so the error states dh, s = int (dh - b), b
(after the core states; with ``position=True`` dh is dp_U) obey::

    dh'   = dv_U - k1 (dh - b)
    dv_U' = (f x phi + C ba + ...)_U - dg/dh dh - k2 (dh - b) - k3 s
    s'    = dh - b,        b' = -b / tau_c + w_b   (turn-on bias + Gauss-Markov, as the IMU biases)

with the white part of the aiding height (sigma_w per sample at the INS rate) as process noise
on dh, dv_U, s (k1^2, k2^2, 1 times its density sigma_w^2 dt_ins; the correlations dropped).
A vertical accelerometer bias then shows in dv_U as a transient of some b tau (the loop's
integrator absorbs it after a few tau). Known answer (test/ins3d/test_model.py): with the true
sensor and baro errors as inputs the model reproduces the simulator's dv_U and dh to 0.1 %.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from numba import njit

from ..earth import gravity, radii
from ..errors import CoreError


def loop_gains(tau_s: float, lat: float = 0.7, h: float = 0.0) -> tuple[float, float, float]:
    """(k1, k2, k3) of the INS's third-order height loop with a triple pole at -1/tau_s (the
    simulator's ``sim.strapdown.vertical_gains``: k2 includes the 2 g / R of free height)."""
    r_n, r_m = radii(float(lat))
    two_w2 = 2.0 * float(gravity(float(lat), float(h))) / (math.sqrt(r_n * r_m) + h)
    return 3.0 / tau_s, 3.0 / tau_s**2 + two_w2, 1.0 / tau_s**3


@dataclass(frozen=True)
class VerticalLoop:
    """The INS height loop (``vertical="loop"``): its time constant, the latitude and height its
    gains were computed at, and the aiding height's error model (m; the simulator's baro by
    default, ``sim.gnss.BaroConfig``): turn-on bias, Gauss-Markov sigma and tau, white sigma
    per sample at ``aid_rate_hz``."""

    tau_s: float = 100.0
    lat: float = 0.7
    h: float = 0.0
    bias: float = 5.0
    instability: float = 2.0
    aid_tau_s: float = 600.0
    white: float = 0.5
    aid_rate_hz: float = 100.0

    def __post_init__(self) -> None:
        vals = (self.tau_s, self.lat, self.h, self.bias, self.instability, self.aid_tau_s,
                self.white, self.aid_rate_hz)
        if not all(math.isfinite(float(v)) for v in vals) or self.tau_s <= 0 \
                or self.aid_tau_s <= 0 or self.aid_rate_hz <= 0 or min(
                    self.bias, self.instability, self.white) < 0:
            raise CoreError(f"ins3d: invalid vertical loop {self!r}")

    @classmethod
    def from_description(cls, doc: dict, lat: float = 0.7, h: float = 0.0
                         ) -> "VerticalLoop | None":
        """From the simulator's flight description (bag metadata ``flight_fdi.sim3d``,
        ``Flight3D.description()``); None when its INS has no baro loop."""
        if doc.get("vertical") != "baro":
            return None
        b = doc.get("baro", {})
        rate = float(doc.get("trajectory", {}).get("rate_hz", 100.0))
        return cls(float(doc.get("tau_vertical_s", 100.0)), lat, h,
                   float(b.get("bias", 5.0)), float(b.get("instability", 2.0)),
                   float(b.get("tau_s", 600.0)), float(b.get("white", 0.5)), rate)

    def gains(self) -> tuple[float, float, float]:
        return loop_gains(self.tau_s, self.lat, self.h)



@njit(cache=True)
def fill_loop(F, bias, iu, dg, pos):
    """The loop's rows and columns of F (module docstring); ``bias`` = the model's
    ``kernel_params()`` (k1, k2, k3 at 7-9, 1/tau_c of b at 10, the indices of dh, s, b at
    11-13), ``iu`` the index of dv_U, ``dg`` = -dg/dh, ``pos``: dh is the position state dp_U
    (its dh' = dv_U and gravity terms are already in F)."""
    k1, k2, k3 = bias[7], bias[8], bias[9]
    ih, js, jb = int(bias[11]), int(bias[12]), int(bias[13])
    if not pos:
        F[ih, iu] = 1.0
        F[iu, ih] += dg
    F[ih, ih] += -k1
    F[ih, jb] += k1
    F[iu, ih] += -k2
    F[iu, jb] += k2
    F[iu, js] += -k3
    F[js, ih] = 1.0
    F[js, jb] = -1.0
    F[jb, jb] = -bias[10]


__all__ = ["VerticalLoop", "fill_loop", "loop_gains"]
