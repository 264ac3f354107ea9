"""An optional height reference in the 3-D input (docs/ins3d.md, "A height reference"): one more
topic, read with the contract topics (``ins3d_input.read_ins3d(..., height=HeightSpec(topic))``),
that becomes the third reference row (``core.ins3d.data.with_height``: z = h_INS - h_ref, m).

Types (``HEIGHT_TYPES``):

* ``sensor_msgs/msg/NavSatFix``: ``altitude`` (m); its variance ``position_covariance[8]`` (the
  Up variance of the ENU covariance) when ``position_covariance_type`` is not UNKNOWN (0), else
  the configured one; a message with ``status.status`` NO_FIX (-1) is dropped (``no_fix``);
* ``sensor_msgs/msg/FluidPressure``: a barometer. ``fluid_pressure`` (Pa) becomes the pressure
  altitude of the ICAO standard atmosphere's troposphere (``pressure_altitude``:
  h = T0/L (1 - (p/p0)^(R L / g0 M)), p0 = 101325 Pa, T0 = 288.15 K, L = 6.5 K/km); its
  ``variance`` (Pa^2; 0 means unknown in ROS) is converted by (dh/dp)^2 at that pressure;
* ``geometry_msgs/msg/PointStamped``: ``point.z`` (m); no variance (the configured one).

A message whose variance is unknown or not a finite number > 0 gets the configured one,
``HeightSpec.variance()`` = sigma^2 + markov_sigma^2 (the published variance of a reference is
its whole noise; the filter takes the Markov part out: ``core.ins3d.filter.white_variance``).

**Datum.** A barometric or pressure altitude is relative (the day's QNH, the geoid): with
``datum="first"`` (the default) the reference is offset so that its first sample inside the IMU
record equals the INS height (/ins/fix, interpolated) at that stamp; the INS height error the
analysis then estimates is relative to that datum, and its prior sigma (``h0_sigma``) is the
reference's own error at that sample (the square root of its variance), not the model's 5 m.
``datum="absolute"``: the heights as published (an ellipsoidal height like the INS's, or a
height whose datum the INS shares), the model's prior (5 m).

**Stamps.** The reference rows share one set of stamps (``core.ins3d.data.RefRows``: the
filter, the backward sweep and the GLR update all rows at once), so the height is linearly
interpolated at each reference velocity stamp from the two height samples around it (an exact
stamp is taken as it is), and so is its variance. A reference velocity stamp with no height
sample at or before and at or after it within ``max_gap_s`` (default 2 s) loses its row: it is
counted on the reference topic as ``no_height``. Height messages are cleaned as the single-axis
inputs are (``bagio.inputs.clean_series``: non-finite, zero stamps, a stamp more than
``REORDER_WINDOW_S`` older than the newest before it, repeated stamps: dropped and counted;
shuffled ones sorted), and those outside the IMU record are dropped (``outside_imu_record``).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from ..core.ins3d.defaults import DATUMS, HEIGHT_DEFAULTS, HEIGHT_TYPES
from . import cdr
from .errors import BagError

#: the defaults: setting (i) of the real-data evaluation (``core.ins3d.defaults``)
DEFAULT_SIGMA_M = HEIGHT_DEFAULTS["sigma"]
DEFAULT_MARKOV = HEIGHT_DEFAULTS["markov"]
DEFAULT_V0_SIGMA_UP = HEIGHT_DEFAULTS["v0_sigma_up"]
MAX_GAP_S = HEIGHT_DEFAULTS["max_gap_s"]
#: the largest shuffle of height stamps that is sorted (the single-axis inputs' default)
REORDER_WINDOW_S = 10.0
#: the Markov sigma of the rows the user gave none for, when the other rows have one: the
#: model's reference Markov states are all rows' or none (m/s horizontally, m for the height)
NEGLIGIBLE_MARKOV = 1e-3
#: NavSatFix status NO_FIX, covariance type UNKNOWN
NO_FIX, COVARIANCE_UNKNOWN = -1, 0
#: why a height message is not used (``input_section3d``)
HEIGHT_REASONS = ("non_finite", "zero_stamp", "out_of_order", "duplicate_stamp", "no_fix",
                  "outside_imu_record")

# the ICAO standard atmosphere (troposphere)
P0_PA, T0_K, LAPSE_K_M = 101325.0, 288.15, 0.0065
G0, MOLAR_MASS, GAS_CONSTANT = 9.80665, 0.0289644, 8.31432    # US Standard Atmosphere 1976
EXPONENT = G0 * MOLAR_MASS / (GAS_CONSTANT * LAPSE_K_M)      # 5.25588


def pressure_altitude(p_pa: np.ndarray) -> np.ndarray:
    """The ISA pressure altitude (m) of pressures (Pa); NaN for a pressure not > 0."""
    p = np.asarray(p_pa, dtype=float)
    with np.errstate(invalid="ignore", divide="ignore"):
        h = T0_K / LAPSE_K_M * (1.0 - np.power(np.where(p > 0, p, np.nan) / P0_PA,
                                               1.0 / EXPONENT))
    return h


def isa_pressure(h_m: np.ndarray) -> np.ndarray:
    """The ISA pressure (Pa) at pressure altitudes (m): the inverse of ``pressure_altitude``."""
    return P0_PA * np.power(1.0 - LAPSE_K_M * np.asarray(h_m, dtype=float) / T0_K, EXPONENT)


def dh_dp(p_pa: np.ndarray) -> np.ndarray:
    """d(pressure altitude)/dp (m/Pa, negative) at pressures (Pa)."""
    p = np.asarray(p_pa, dtype=float)
    return -T0_K / (LAPSE_K_M * EXPONENT * P0_PA) * np.power(p / P0_PA, 1.0 / EXPONENT - 1.0)


@dataclass(frozen=True)
class HeightSpec:
    """Where the height reference is and how the analysis models it (module docstring):
    ``sigma`` the white sigma (m) of a message without a known variance, ``markov`` (sigma m,
    tau s) its Markov error or None, ``datum`` first or absolute, ``v0_sigma_up`` the initial
    vertical velocity error's sigma (m/s), ``max_gap_s`` the widest interpolation."""

    topic: str
    sigma: float = DEFAULT_SIGMA_M
    markov: tuple[float, float] | None = DEFAULT_MARKOV
    datum: str = "first"
    v0_sigma_up: float = DEFAULT_V0_SIGMA_UP
    max_gap_s: float = MAX_GAP_S

    def __post_init__(self) -> None:
        if not isinstance(self.topic, str) or not self.topic.strip():
            raise BagError(f"height reference: the topic must be a non-empty name, got "
                           f"{self.topic!r}")
        for name in ("sigma", "v0_sigma_up", "max_gap_s"):
            if not _positive(getattr(self, name)):
                raise BagError(f"height reference: {name} must be a number > 0, got "
                               f"{getattr(self, name)!r}")
        if self.markov is not None:
            if not (isinstance(self.markov, (tuple, list)) and len(self.markov) == 2
                    and all(_positive(v) for v in self.markov)):
                raise BagError("height reference: markov must be None or (sigma m, tau s), "
                               f"both > 0, got {self.markov!r}")
            object.__setattr__(self, "markov", (float(self.markov[0]), float(self.markov[1])))
        if self.datum not in DATUMS:
            raise BagError(f"height reference: datum must be one of {', '.join(DATUMS)}, got "
                           f"{self.datum!r}")

    def variance(self) -> float:
        """The configured (published-style) variance: white^2 + Markov sigma^2 (m^2)."""
        return self.sigma**2 + (self.markov[0] ** 2 if self.markov else 0.0)

    def ref_markov(self, velocity: tuple[float, float, float] | None
                   ) -> tuple[float, ...] | None:
        """The model's reference Markov noise (``Ins3dModel.ref_markov``: sigma_h m/s, the
        third row's sigma -- here m --, tau, the third row's tau) of the velocity reference's
        ``velocity`` (sigma_h, sigma_v, tau) and this height's (sigma, tau): each row keeps its
        own sigma and tau; a side without Markov noise gets ``NEGLIGIBLE_MARKOV`` (with the
        other side's tau); None when neither has any."""
        if self.markov is None:
            return None if velocity is None else \
                (float(velocity[0]), NEGLIGIBLE_MARKOV, float(velocity[2]))
        if velocity is None:
            return NEGLIGIBLE_MARKOV, self.markov[0], self.markov[1]
        return float(velocity[0]), self.markov[0], float(velocity[2]), self.markov[1]

    def describe(self) -> dict:
        """The plain-data form a result's ``source.height`` records (``from_source``)."""
        return {"topic": self.topic, "sigma_m": float(self.sigma),
                "markov": None if self.markov is None else list(self.markov),
                "datum": self.datum, "v0_sigma_up": float(self.v0_sigma_up),
                "max_gap_s": float(self.max_gap_s)}


def _positive(v) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v > 0


@dataclass
class HeightInput:
    """What the height topic gave an ``Ins3dInput``: the spec, the message type, the counts
    (``section``), the datum offset added (m) and the prior sigma of the height error."""

    spec: HeightSpec
    msgtype: str
    messages: int
    dropped: dict
    reordered: int
    ref_no_height: int
    offset_m: float
    h0_sigma: float | None
    from_message: int          # used heights whose variance came from the message

    def section(self) -> dict:
        """The height topic's entry of the result's ``input`` section."""
        used = self.messages - sum(self.dropped.values())
        return {"role": "height", "type": self.msgtype, "messages": int(self.messages),
                "used": int(used), "dropped": {k: int(self.dropped.get(k, 0))
                                               for k in HEIGHT_REASONS},
                "reordered": int(self.reordered),
                "variance": {"message": int(self.from_message),
                             "configured": int(used - self.from_message)},
                "datum": self.spec.datum, "offset_m": float(self.offset_m)}

    def options(self, ref_markov: tuple[float, float, float] | None) -> dict:
        """The ``analyze_ins3d`` options of the height row, given the velocity reference's
        Markov noise ``ref_markov`` (``HeightSpec.ref_markov``)."""
        return {"rows": 3, "position": True, "height_row": True,
                "v0_sigma_up": self.spec.v0_sigma_up, "h0_sigma": self.h0_sigma,
                "ref_markov": self.spec.ref_markov(ref_markov)}


def decode_height(msgtype: str, payloads, what: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(stamps ns, heights m, variances m^2 (NaN: unknown or invalid), no-fix mask) of the
    messages of one height topic."""
    n = len(payloads)
    no_fix = np.zeros(n, dtype=bool)
    if msgtype == cdr.NAVSATFIX:
        stamps, vals = cdr.decode_doubles(msgtype, payloads, (2, 11), what)
        status, kind = cdr.decode_navsatfix_flags(payloads, what)
        h, var = vals[:, 0], np.where(kind != COVARIANCE_UNKNOWN, vals[:, 1], np.nan)
        no_fix = status == NO_FIX
    elif msgtype == cdr.FLUID_PRESSURE:
        stamps, vals = cdr.decode_doubles(msgtype, payloads, (0, 1), what)
        h = pressure_altitude(vals[:, 0])
        with np.errstate(invalid="ignore"):
            var = vals[:, 1] * dh_dp(vals[:, 0]) ** 2
    elif msgtype == cdr.POINT_STAMPED:
        stamps, vals = cdr.decode_doubles(msgtype, payloads, (2,), what)
        h, var = vals[:, 0], np.full(n, np.nan)
    else:
        raise BagError(f"{what}: carries {msgtype}, expected one of {', '.join(HEIGHT_TYPES)}")
    var = np.where(np.isfinite(var) & (var > 0), var, np.nan)
    return stamps, h, var, no_fix


def attach_height(inp, raw, msgtype: str, spec: HeightSpec, t_fix: np.ndarray,
                  h_fix: np.ndarray, t_vel: np.ndarray, v_up: np.ndarray, path) -> None:
    """Make the third row of ``inp`` (an ``ins3d_input.Ins3dInput`` read from a bag, times
    relative to ``inp.t0_ns``) the height of the raw messages ``raw`` (``reader.RawSeries``)
    of ``spec.topic`` (module docstring); ``inp.height`` records what it did. BagError when no
    reference row keeps a height."""
    from ..core.ins3d.data import RefRows, interpolate_height, with_height
    from .inputs import clean_series

    what = f"bag '{path}' {spec.topic}"
    stamps, h, var, no_fix = decode_height(msgtype, raw.payloads, what)
    n = int(stamps.size)
    keep = ~no_fix
    s = clean_series(spec.topic, msgtype, stamps[keep], h[keep], var[keep], REORDER_WINDOW_S)
    dropped = {**s.dropped, "no_fix": int(no_fix.sum())}
    t_h = (s.stamp - inp.t0_ns) * 1e-9
    t_steps = inp.steps.t
    inside = (t_h >= t_steps[0]) & (t_h <= t_steps[-1])
    dropped["outside_imu_record"] = int((~inside).sum())
    t_h, h_ref, r_h = t_h[inside], s.v[inside], s.r[inside]
    if t_h.size == 0:
        raise BagError(f"{what}: no usable height message inside the IMU record "
                       f"({n} messages; {_reasons(dropped)})")
    known = np.isfinite(r_h)
    r_h = np.where(known, r_h, spec.variance())
    offset, h0 = 0.0, None
    if spec.datum == "first":
        offset = float(np.interp(t_h[0], t_fix, h_fix) - h_ref[0])
        h0 = float(math.sqrt(r_h[0]))
    refs = inp.refs
    hz, rz, ok = interpolate_height(refs.t, t_h, h_ref + offset, r_h, spec.max_gap_s)
    if not ok.any():
        raise BagError(f"{what}: no reference velocity stamp has a height sample within "
                       f"{spec.max_gap_s:g} s (heights {t_h[0]:.1f}..{t_h[-1]:.1f} s, reference "
                       f"{refs.t[0]:.1f}..{refs.t[-1]:.1f} s from the first stamp)")
    kept = RefRows(refs.t[ok], refs.z[ok], refs.r[ok], refs.step[ok], refs.a[ok])
    inp.refs = with_height(kept, t_fix, h_fix, v_up, hz[ok], rz[ok], t_v=t_vel)
    inp.height = HeightInput(spec, msgtype, n, dropped, s.reordered, int((~ok).sum()), offset,
                             h0, int(known.sum()))


def _reasons(dropped: dict) -> str:
    gone = [f"{k} {v}" for k, v in dropped.items() if v]
    return "dropped: " + ", ".join(gone) if gone else "none dropped"


__all__ = ["DATUMS", "DEFAULT_MARKOV", "DEFAULT_SIGMA_M", "DEFAULT_V0_SIGMA_UP", "HEIGHT_REASONS",
           "HEIGHT_TYPES", "HeightInput", "HeightSpec", "MAX_GAP_S", "attach_height",
           "decode_height", "dh_dp", "isa_pressure", "pressure_altitude"]
