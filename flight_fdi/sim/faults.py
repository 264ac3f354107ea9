"""The fault catalogue (SPEC section 4, seed 002) and its compact command-line form.

Instrument faults (target ``accel`` or ``gyro``) add an error e(t) to the channel's instrument
error, i.e. to the truth of the model's ``accel_bias`` / ``gyro_drift`` state, over
[start, end) (end = the end of the flight when not given):

=========  ============================================  ======================================
type       e(t) for start <= t < end                     magnitude
=========  ============================================  ======================================
step       m                                             m/s^2 or rad/s
ramp       m (t - start)                                 per second (m/s^3 or rad/s^2)
sine       m sin(2 pi f (t - start))                     amplitude
square     +m for the first half of each period of       amplitude
           1/f from start, -m for the second half
stuck      m - true input (output stuck at m)            the stuck output value
scale      m * true input (scale-factor change)          dimensionless (1 = doubled output)
=========  ============================================  ======================================

The true input is the specific force along the channel (accel) or the angular rate sensed by
the channel's gyro (see ``profile``). Reference faults (target ``ref``) act on the reference
velocity: ``jump`` adds m (m/s) over [start, end); ``outliers`` adds isolated spikes of +-m at
random reference samples, f per second on average; ``dropout`` removes every reference message
over [start, end) (end required).

Command-line form, one fault per ``--fault``::

    TARGET:TYPE:key=value[,key=value...]
    keys: t (start, s), end (s), mag (magnitude), freq (Hz, or outliers per second), axis (x|y)

    accel:step:t=500,mag=0.015          accelerometer bias step of 0.015 m/s^2 at 500 s
    accel:step:t=500,mag=1.5mg          the same in milli-g
    gyro:square:t=20,mag=20deg/h,freq=1 square-wave gyro drift of +-20 deg/h at 1 Hz
    gyro:stuck:t=300,mag=0              gyro output stuck at zero
    accel:scale:t=300,mag=1             doubled accelerometer output
    ref:outliers:t=100,end=900,mag=3,freq=0.05
    ref:dropout:t=300,end=330

Magnitude units (optional suffix): accel m/s^2 (default), mg, ug; gyro rad/s (default), deg/h,
deg/s; ref m/s; scale: none (default), ppm, %. For a ramp the unit is per second.

The 3-D simulator (``ins3d``) uses ``FaultSpec3D``: body axes x, y, z for the instruments, ENU
axes x (East), y (North), z (Up) for the reference, and one more reference fault, ``latency``:
the reference reports the velocity of m seconds earlier than its stamp over [start, end)
(added to the nominal latency; units s (default) or ms). Parse with
``parse_fault(text, FaultSpec3D)``.
"""
from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from .errors import SimError

G0 = 9.80665
DEG_PER_HOUR = math.pi / 180.0 / 3600.0

INSTRUMENT_TYPES = ("step", "ramp", "sine", "square", "stuck", "scale")
REFERENCE_TYPES = ("jump", "outliers", "dropout")
TARGETS = {"accel": INSTRUMENT_TYPES, "gyro": INSTRUMENT_TYPES, "ref": REFERENCE_TYPES}
AXES = ("x", "y")
TARGETS_3D = {**TARGETS, "ref": REFERENCE_TYPES + ("latency",)}
AXES_3D = ("x", "y", "z")
ELEMENTS = {"accel": "accel_bias", "gyro": "gyro_drift", "ref": "reference"}
#: the GLR hypothesis that describes each fault exactly (None: no exact hypothesis)
HYPOTHESES = {("accel", "step"): "accel_bias_step", ("gyro", "step"): "gyro_drift_step",
              ("ref", "jump"): "reference_jump"}

_UNITS = {
    "accel": {"": 1.0, "m/s^2": 1.0, "m/s2": 1.0, "mg": 1e-3 * G0, "ug": 1e-6 * G0},
    "gyro": {"": 1.0, "rad/s": 1.0, "deg/h": DEG_PER_HOUR, "dph": DEG_PER_HOUR,
             "deg/s": math.pi / 180.0},
    "ref": {"": 1.0, "m/s": 1.0},
    "scale": {"": 1.0, "ppm": 1e-6, "%": 1e-2},
    "latency": {"": 1.0, "s": 1.0, "ms": 1e-3},
}
_NUMBER = re.compile(r"^([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)(.*)$")
SI_UNITS = {"accel": "m/s^2", "gyro": "rad/s", "ref": "m/s"}


@dataclass(frozen=True)
class FaultSpec:
    """One injected fault. Magnitudes in SI units (see the module docstring)."""

    target: str                    # accel | gyro | ref
    type: str                      # see TARGETS
    start_s: float
    end_s: float | None = None     # None: until the end of the flight
    magnitude: float = 0.0
    freq_hz: float | None = None   # sine/square frequency; outliers per second
    axis: str | None = None        # x | y; None: the simulation's channel

    #: the axes and fault types this kind of fault accepts (class attributes, not fields)
    _axes = AXES
    _targets = TARGETS

    def __post_init__(self) -> None:
        targets = self._targets
        if self.target not in targets:
            raise SimError(f"fault target must be one of {', '.join(targets)}, got {self.target!r}")
        if self.type not in targets[self.target]:
            raise SimError(f"fault type {self.type!r} does not apply to {self.target}; choose "
                           f"one of {', '.join(targets[self.target])}")
        if self.axis is not None and self.axis not in self._axes:
            raise SimError(f"fault axis must be {', '.join(self._axes[:-1])} or "
                           f"{self._axes[-1]}, got {self.axis!r}")
        if not math.isfinite(self.start_s) or self.start_s < 0:
            raise SimError(f"{self.label}: start must be a time >= 0 s, got {self.start_s!r}")
        if self.end_s is not None and (not math.isfinite(self.end_s)
                                       or self.end_s <= self.start_s):
            raise SimError(f"{self.label}: end ({self.end_s!r} s) must be after the start "
                           f"({self.start_s:g} s)")
        if self.type == "dropout" and self.end_s is None:
            raise SimError(f"{self.label}: a dropout needs an end time (end=...)")
        if not math.isfinite(self.magnitude):
            raise SimError(f"{self.label}: magnitude must be a finite number")
        if self.type == "dropout":
            if self.magnitude != 0:
                raise SimError(f"{self.label}: a dropout has no magnitude")
        elif self.type != "stuck" and self.magnitude == 0:
            raise SimError(f"{self.label}: magnitude must be non-zero")
        needs_freq = self.type in ("sine", "square", "outliers")
        if needs_freq:
            if self.freq_hz is None or not math.isfinite(self.freq_hz) or self.freq_hz <= 0:
                raise SimError(f"{self.label}: needs a positive frequency (freq=...)")
        elif self.freq_hz is not None:
            raise SimError(f"{self.label}: freq applies only to sine, square and outliers")

    @property
    def label(self) -> str:
        return f"fault {self.target}:{self.type}"

    @property
    def element(self) -> str:
        """The model state (or the reference) the fault acts on."""
        return ELEMENTS[self.target]

    @property
    def hypothesis(self) -> str | None:
        """The GLR hypothesis that matches this fault exactly, if there is one."""
        return HYPOTHESES.get((self.target, self.type))

    def end(self, duration_s: float) -> float:
        return duration_s if self.end_s is None else self.end_s

    def check_against(self, duration_s: float, ins_rate_hz: float, ref_rate_hz: float) -> None:
        """Validate against the flight it is injected into."""
        if self.start_s >= duration_s:
            raise SimError(f"{self.label}: starts at {self.start_s:g} s, after the end of the "
                           f"{duration_s:g}-s flight")
        if self.end_s is not None and self.end_s > duration_s:
            raise SimError(f"{self.label}: ends at {self.end_s:g} s, after the end of the "
                           f"{duration_s:g}-s flight")
        if self.type in ("sine", "square") and self.freq_hz >= ins_rate_hz / 2:  # type: ignore
            raise SimError(f"{self.label}: frequency {self.freq_hz:g} Hz must be below half the "
                           f"INS rate ({ins_rate_hz / 2:g} Hz)")
        if self.type == "outliers" and self.freq_hz > ref_rate_hz:  # type: ignore[operator]
            raise SimError(f"{self.label}: {self.freq_hz:g} outliers per second exceeds the "
                           f"reference rate ({ref_rate_hz:g} Hz)")

    def active(self, t: np.ndarray, duration_s: float) -> np.ndarray:
        """Mask of the times (s from the flight start) inside [start, end)."""
        return (t >= self.start_s) & (t < self.end(duration_s))

    def instrument_error(self, t: np.ndarray, true_input: np.ndarray,
                         duration_s: float) -> np.ndarray:
        """e(t) added to the instrument error (accel/gyro faults), zero outside [start, end)."""
        if self.target == "ref":
            raise SimError(f"{self.label}: not an instrument fault")
        t = np.asarray(t, dtype=float)
        m = self.magnitude
        tau = t - self.start_s
        if self.type == "step":
            e = np.full_like(t, m)
        elif self.type == "ramp":
            e = m * tau
        elif self.type == "sine":
            e = m * np.sin(2.0 * np.pi * self.freq_hz * tau)  # type: ignore[operator]
        elif self.type == "square":
            phase = np.mod(self.freq_hz * tau, 1.0)  # type: ignore[operator]
            e = np.where(phase < 0.5, m, -m)
        elif self.type == "stuck":
            e = m - np.asarray(true_input, dtype=float)
        else:  # scale
            e = m * np.asarray(true_input, dtype=float)
        return np.where(self.active(t, duration_s), e, 0.0)

    def to_dict(self, default_axis: str = "x") -> dict[str, Any]:
        """Plain data (JSON) with the derived element, hypothesis and unit."""
        d = asdict(self)
        d["axis"] = self.axis or default_axis
        d["element"] = self.element
        d["hypothesis"] = self.hypothesis
        d["unit"] = ("1" if self.type == "scale" else "s" if self.type == "latency" else
                     SI_UNITS[self.target] + ("/s" if self.type == "ramp" else ""))
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "FaultSpec":
        try:
            return cls(target=d["target"], type=d["type"], start_s=float(d["start_s"]),
                       end_s=None if d.get("end_s") is None else float(d["end_s"]),
                       magnitude=float(d.get("magnitude", 0.0)),
                       freq_hz=None if d.get("freq_hz") is None else float(d["freq_hz"]),
                       axis=d.get("axis"))
        except (KeyError, TypeError, ValueError) as exc:
            raise SimError(f"fault description {d!r} is incomplete or invalid ({exc})") from None

    def describe(self, default_axis: str = "x") -> str:
        """Short human-readable form, e.g. 'accel step on x at 500 s, 0.015 m/s^2'."""
        unit = self.to_dict(default_axis)["unit"]
        span = f"at {self.start_s:g} s"
        if self.end_s is not None:
            span += f" to {self.end_s:g} s"
        mag = ("" if self.type == "dropout" else f", latency +{self.magnitude:.6g} s"
               if self.type == "latency" else f", scale-factor change {self.magnitude:.6g}"
               if self.type == "scale" else f", {self.magnitude:.6g} {unit}")
        if self.type not in ("dropout", "scale") and self.target != "ref":
            unit_name, factor = ("mg", 1e-3 * G0) if self.target == "accel" else ("deg/h",
                                                                                  DEG_PER_HOUR)
            per_s = "/s" if self.type == "ramp" else ""
            mag += f" ({self.magnitude / factor:.4g} {unit_name}{per_s})"
        freq = "" if self.freq_hz is None else f", {self.freq_hz:g} Hz"
        return f"{self.target} {self.type} on {self.axis or default_axis} {span}{mag}{freq}"


@dataclass(frozen=True)
class FaultSpec3D(FaultSpec):
    """A fault of the 3-D simulator: axes x, y, z (body for accel/gyro, ENU for ref) and the
    reference ``latency`` fault (magnitude in s)."""

    _axes = AXES_3D
    _targets = TARGETS_3D


def _number(text: str, what: str) -> float:
    try:
        val = float(text)
    except ValueError:
        raise SimError(f"{what}: {text!r} is not a number") from None
    if not math.isfinite(val):
        raise SimError(f"{what}: {text!r} is not a finite number")
    return val


def _magnitude(text: str, target: str, ftype: str, what: str) -> float:
    table = _UNITS[ftype if ftype in ("scale", "latency") else target]
    match = _NUMBER.match(text.strip())
    if not match:
        raise SimError(f"{what}: magnitude {text!r} does not start with a number")
    number, unit = match.group(1), match.group(2).strip()
    if ftype == "ramp" and unit.endswith("/s") and unit[:-2] in table and unit not in table:
        unit = unit[:-2]  # "mg/s" for a ramp: the rate per second
    if unit not in table:
        choices = ", ".join(u for u in table if u) or "none"
        raise SimError(f"{what}: unknown unit {unit!r} for a {target} {ftype} magnitude "
                       f"(units: {choices})")
    return _number(number, what) * table[unit]


def parse_fault(text: str, cls: type[FaultSpec] = None) -> FaultSpec:  # type: ignore[assignment]
    """Parse ``TARGET:TYPE:key=value[,key=value...]`` (see the module docstring) into a ``cls``
    (default ``FaultSpec``; ``FaultSpec3D`` for the 3-D simulator)."""
    cls = FaultSpec if cls is None else cls
    TARGETS = cls._targets  # noqa: N806 -- the kind's own catalogue
    what = f"--fault {text!r}"
    parts = text.strip().split(":", 2)
    if len(parts) < 2 or not parts[0] or not parts[1]:
        raise SimError(f"{what}: expected TARGET:TYPE:key=value,... "
                       "(e.g. accel:step:t=500,mag=0.015)")
    target, ftype = parts[0].strip().lower(), parts[1].strip().lower()
    if target not in TARGETS:
        raise SimError(f"{what}: unknown target {target!r}; choose one of {', '.join(TARGETS)}")
    if ftype not in TARGETS[target]:
        raise SimError(f"{what}: unknown {target} fault type {ftype!r}; choose one of "
                       f"{', '.join(TARGETS[target])}")
    values: dict[str, str] = {}
    aliases = {"t": "t", "start": "t", "end": "end", "mag": "mag", "magnitude": "mag",
               "freq": "freq", "f": "freq", "axis": "axis"}
    if len(parts) == 3 and parts[2].strip():
        for item in parts[2].split(","):
            if "=" not in item:
                raise SimError(f"{what}: {item.strip()!r} is not key=value")
            key, val = (s.strip() for s in item.split("=", 1))
            key = aliases.get(key.lower(), "")
            if not key:
                raise SimError(f"{what}: unknown key {item.split('=', 1)[0].strip()!r}; keys are "
                               "t, end, mag, freq, axis")
            if key in values:
                raise SimError(f"{what}: {key} given twice")
            values[key] = val
    if "t" not in values:
        raise SimError(f"{what}: the start time t=... is required")
    freq = values.get("freq")
    if freq is not None and freq.lower().endswith("hz"):
        freq = freq[:-2]
    try:
        return cls(
            target=target, type=ftype,
            start_s=_number(values["t"].rstrip("s"), what),
            end_s=None if "end" not in values else _number(values["end"].rstrip("s"), what),
            magnitude=(0.0 if "mag" not in values
                       else _magnitude(values["mag"], target, ftype, what)),
            freq_hz=None if freq is None else _number(freq, what),
            axis=values["axis"].lower() if "axis" in values else None,
        )
    except SimError as exc:
        msg = str(exc)
        if msg.startswith(f"fault {target}:{ftype}: "):
            msg = msg[len(f"fault {target}:{ftype}: "):]
        raise SimError(f"{what}: {msg}") from None
