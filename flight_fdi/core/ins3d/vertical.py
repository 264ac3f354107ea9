"""The INS height loop of the ins3d model's ``vertical="loop"`` channel (``core.ins3d.model``):
the third-order loop on the aiding height that the simulator's INS (``sim.strapdown``) and
many real ones mechanize, with the aiding height's error model."""
from __future__ import annotations

import math
from dataclasses import dataclass

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


__all__ = ["VerticalLoop", "loop_gains"]
