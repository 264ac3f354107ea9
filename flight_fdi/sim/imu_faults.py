"""The fault catalogue of the triple-IMU simulator (seed 002; :mod:`flight_fdi.sim.imu`'s module
docstring describes it): one fault of one IMU on one quantity, :class:`ImuFault`, and the
``--imu-fault`` text form, :func:`parse_imu_fault`. Output faults replace the output (zero, full
scale, doubled); parameter faults add an instrument error of the shapes of
:mod:`flight_fdi.sim.faults`."""
from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from flight_fdi.core.voting import QUANTITIES

from .errors import SimError
from .faults import DEG_PER_HOUR, G0, FaultSpec, parse_fault

OUTPUT_TYPES = ("zero", "full_scale", "doubled")
PARAMETER_TYPES = ("step", "scale", "ramp", "sine", "square", "square_onoff")
FAULT_TYPES = OUTPUT_TYPES + PARAMETER_TYPES


@dataclass(frozen=True)
class ImuFault:
    """One fault of one IMU on one quantity (see the module docstring's catalogue)."""

    imu: int                      # 1..3
    quantity: str                 # gyro_x ... accel_z
    type: str
    start_s: float
    end_s: float | None = None
    magnitude: float = 0.0
    freq_hz: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.imu, bool) or self.imu not in (1, 2, 3):
            raise SimError(f"IMU fault: imu must be 1, 2 or 3, got {self.imu!r}")
        if self.quantity not in QUANTITIES:
            raise SimError(f"IMU fault: quantity must be one of {', '.join(QUANTITIES)}, got "
                           f"{self.quantity!r}")
        if self.type not in FAULT_TYPES:
            raise SimError(f"IMU fault: type must be one of {', '.join(FAULT_TYPES)}, got "
                           f"{self.type!r}")
        if self.type in OUTPUT_TYPES:
            if self.freq_hz is not None:
                raise SimError(f"{self.label}: freq applies only to sine and square faults")
            if self.type != "full_scale" and self.magnitude != 0:
                raise SimError(f"{self.label}: an output fault has no magnitude")
            if self.type == "full_scale" and self.magnitude not in (0, 1, -1):
                raise SimError(f"{self.label}: magnitude must be +1 or -1 (the sign of the "
                               "full-scale output)")
        self.shapes()  # FaultSpec validates the times, magnitude and frequency

    @property
    def target(self) -> str:
        return self.quantity.split("_")[0]

    @property
    def column(self) -> int:
        return QUANTITIES.index(self.quantity)

    @property
    def label(self) -> str:
        return f"fault imu{self.imu}:{self.quantity}:{self.type}"

    def shapes(self) -> list[FaultSpec]:
        """The faults.py shapes whose sum is the parameter fault (the active-interval shape
        ``stuck`` for output faults)."""
        try:
            if self.type in OUTPUT_TYPES:
                return [FaultSpec(self.target, "stuck", self.start_s, self.end_s, 0.0)]
            if self.type == "square_onoff":
                half = 0.5 * self.magnitude
                return [FaultSpec(self.target, "step", self.start_s, self.end_s, half),
                        FaultSpec(self.target, "square", self.start_s, self.end_s, half,
                                  self.freq_hz)]
            return [FaultSpec(self.target, self.type, self.start_s, self.end_s, self.magnitude,
                              self.freq_hz)]
        except SimError as exc:
            msg = str(exc)
            msg = re.sub(r"^fault \w+:\w+: ", "", msg)
            raise SimError(f"{self.label}: {msg}") from None

    def check_against(self, duration_s: float, rate_hz: float) -> None:
        for spec in self.shapes():
            spec.check_against(duration_s, rate_hz, rate_hz)

    def active(self, t: np.ndarray, duration_s: float) -> np.ndarray:
        return self.shapes()[0].active(t, duration_s)

    def parameter_error(self, t: np.ndarray, true_input: np.ndarray,
                        duration_s: float) -> np.ndarray:
        """e(t) added to the IMU's error (zero for output faults)."""
        if self.type in OUTPUT_TYPES:
            return np.zeros(np.shape(t))
        return sum(s.instrument_error(t, true_input, duration_s) for s in self.shapes())

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["unit"] = ("1" if self.type in ("scale",) + OUTPUT_TYPES
                     else {"gyro": "rad/s", "accel": "m/s^2"}[self.target]
                     + ("/s" if self.type == "ramp" else ""))
        return d

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "ImuFault":
        try:
            return cls(imu=int(d["imu"]), quantity=d["quantity"], type=d["type"],
                       start_s=float(d["start_s"]),
                       end_s=None if d.get("end_s") is None else float(d["end_s"]),
                       magnitude=float(d.get("magnitude", 0.0)),
                       freq_hz=None if d.get("freq_hz") is None else float(d["freq_hz"]))
        except (KeyError, TypeError, ValueError) as exc:
            raise SimError(f"IMU fault description {d!r} is incomplete or invalid ({exc})") \
                from None

    def describe(self) -> str:
        span = f"from {self.start_s:g} s" + ("" if self.end_s is None else f" to {self.end_s:g} s")
        if self.type in OUTPUT_TYPES:
            mag = ""
        elif self.type == "scale":
            mag = f", scale-factor change {self.magnitude:.6g}"
        elif self.target == "gyro":
            per = "/s" if self.type == "ramp" else ""
            mag = f", {self.magnitude / DEG_PER_HOUR:.6g} deg/h{per}"
        else:
            per = "/s" if self.type == "ramp" else ""
            mag = f", {self.magnitude / (1e-6 * G0):.6g} ug{per}"
        freq = "" if self.freq_hz is None else f", {self.freq_hz:g} Hz"
        return f"IMU{self.imu} {self.quantity} {self.type} {span}{mag}{freq}"


def parse_imu_fault(text: str) -> ImuFault:
    """``IMU:QUANTITY:TYPE:key=value,...`` (module docstring); magnitudes with the units of
    ``--fault`` (deg/h, deg/s, mg, ug, ppm, % ...)."""
    what = f"--imu-fault {text!r}"
    parts = text.strip().split(":", 3)
    if len(parts) < 3:
        raise SimError(f"{what}: expected IMU:QUANTITY:TYPE:key=value,... "
                       "(e.g. imu3:gyro_z:square:t=20,mag=20deg/h,freq=1)")
    imu_s, quantity, ftype = (p.strip().lower() for p in parts[:3])
    rest = parts[3] if len(parts) == 4 else ""
    m = re.fullmatch(r"imu([123])", imu_s)
    if not m:
        raise SimError(f"{what}: the IMU must be imu1, imu2 or imu3, got {imu_s!r}")
    if quantity not in QUANTITIES:
        raise SimError(f"{what}: unknown quantity {quantity!r}; quantities are "
                       f"{', '.join(QUANTITIES)}")
    if ftype not in FAULT_TYPES:
        raise SimError(f"{what}: unknown fault type {ftype!r}; types are {', '.join(FAULT_TYPES)}")
    target = quantity.split("_")[0]
    if ftype in OUTPUT_TYPES:
        shape = "stuck"
    elif ftype == "square_onoff":
        shape = "square"
    else:
        shape = ftype
    if re.search(r"(^|,)\s*axis\s*=", rest):
        raise SimError(f"{what}: the axis is part of the quantity ({quantity}); no axis= key")
    try:
        spec = parse_fault(f"{target}:{shape}:{rest}")
    except SimError as exc:
        msg = re.sub(r"^--fault '[^']*': ", "", str(exc))
        raise SimError(f"{what}: {msg}") from None
    mag = spec.magnitude
    if ftype == "full_scale":
        mag = -1.0 if mag < 0 else 1.0
    try:
        return ImuFault(int(m.group(1)), quantity, ftype, spec.start_s, spec.end_s, mag,
                        spec.freq_hz)
    except SimError as exc:
        raise SimError(f"{what}: {re.sub(r'^fault [^:]+:[^:]+:[^:]+: ', '', str(exc))}") \
            from None
