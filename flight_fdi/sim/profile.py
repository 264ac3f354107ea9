"""A smooth flight profile: the true motion the INS measures.

Horizontal ground speed s(t) and heading psi(t) are sums of smooth (cosine) ramps, so velocity,
specific force and their rates are continuous:

* standing still for ``taxi_s`` seconds (alignment), a take-off roll to ``rotate_speed`` with
  peak acceleration ``takeoff_accel``, an accelerating climb to ``cruise_speed`` over ``climb_s``
  with pitch ``climb_pitch_deg``;
* cruise with coordinated turns of ``turn_angle_deg`` (alternating left/right, peak rate
  ``turn_rate_deg_s``) every ``turn_every_s`` seconds;
* a final deceleration to ``final_speed`` over the last ``landing_s`` seconds (descent pitch
  ``descent_pitch_deg``), when the flight is long enough to hold it.

Per channel (x, y) the profile gives the true velocity v, the true specific force along the
channel f = dv/dt (the horizontal accelerometer input) and the true angular rate sensed by the
gyro that drives the channel's tilt: the horizontal earth rate (on x, pointing north at
``latitude_deg``), the transport rate v/R, and the vehicle's pitch rate (x) or roll rate (y,
the bank of the coordinated turns). Only the stuck and scale-factor faults depend on f and the
angular rate; the error model of SPEC section 1 itself does not.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .errors import SimError

EARTH_RATE = 7.2921150e-5  # rad/s


def _ramp(t: np.ndarray, start: float, length: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Cosine ramp from 0 (t <= start) to 1 (t >= start + length): value, rate, second rate."""
    u = np.clip((t - start) / length, 0.0, 1.0)
    inside = (t > start) & (t < start + length)
    w = np.pi / length
    value = 0.5 * (1.0 - np.cos(np.pi * u))
    rate = np.where(inside, 0.5 * w * np.sin(np.pi * u), 0.0)
    accel = np.where(inside, 0.5 * w * w * np.cos(np.pi * u), 0.0)
    return value, rate, accel


@dataclass(frozen=True)
class ProfileSample:
    """True motion at the requested times; arrays of shape (N, 2) for the x and y channels."""

    velocity: np.ndarray        # m/s
    specific_force: np.ndarray  # m/s^2
    angular_rate: np.ndarray    # rad/s sensed by each channel's gyro


@dataclass(frozen=True)
class FlightProfile:
    duration_s: float
    taxi_s: float = 30.0
    takeoff_accel: float = 2.5          # m/s^2, peak
    rotate_speed: float = 80.0          # m/s
    climb_s: float = 240.0
    climb_pitch_deg: float = 8.0
    cruise_speed: float = 220.0         # m/s
    turn_every_s: float = 300.0
    turn_angle_deg: float = 90.0
    turn_rate_deg_s: float = 1.5        # peak (about 30 deg of bank at cruise speed)
    landing_s: float = 240.0
    final_speed: float = 70.0           # m/s
    descent_pitch_deg: float = -3.0
    heading0_deg: float = 30.0
    latitude_deg: float = 45.0
    earth_radius: float = 6_371_000.0
    g: float = 9.80665

    def __post_init__(self) -> None:
        for name in ("duration_s", "takeoff_accel", "rotate_speed", "climb_s", "cruise_speed",
                     "turn_every_s", "turn_rate_deg_s", "landing_s", "earth_radius", "g"):
            val = getattr(self, name)
            if not np.isfinite(val) or val <= 0:
                raise SimError(f"flight profile: {name} must be a positive number, got {val!r}")
        for name in ("taxi_s", "final_speed", "turn_angle_deg"):
            val = getattr(self, name)
            if not np.isfinite(val) or val < 0:
                raise SimError(f"flight profile: {name} must be >= 0, got {val!r}")
        if not -90 < self.latitude_deg < 90:
            raise SimError(f"flight profile: latitude_deg must be in (-90, 90), "
                           f"got {self.latitude_deg!r}")

    # phases -----------------------------------------------------------------------------
    @property
    def takeoff_s(self) -> float:
        """Length of the take-off roll (cosine ramp with the given peak acceleration)."""
        return np.pi * self.rotate_speed / (2.0 * self.takeoff_accel)

    @property
    def cruise_start_s(self) -> float:
        return self.taxi_s + self.takeoff_s + self.climb_s

    @property
    def landing_start_s(self) -> float | None:
        """Start of the final deceleration, None when the flight is too short to hold it."""
        start = self.duration_s - self.landing_s
        return start if start >= self.cruise_start_s else None

    def turn_starts(self) -> list[float]:
        turn_len = self._turn_len()
        end = self.landing_start_s if self.landing_start_s is not None else self.duration_s
        starts, t = [], self.cruise_start_s + 0.5 * self.turn_every_s
        while self.turn_angle_deg > 0 and t + turn_len <= end:
            starts.append(t)
            t += self.turn_every_s
        return starts

    def _turn_len(self) -> float:
        return np.pi * self.turn_angle_deg / (2.0 * self.turn_rate_deg_s)

    # evaluation -------------------------------------------------------------------------
    def evaluate(self, t: np.ndarray) -> ProfileSample:
        """True velocity, specific force and sensed angular rate at times ``t`` (s)."""
        t = np.asarray(t, dtype=float).reshape(-1)
        zero = np.zeros_like(t)
        s, ds = zero.copy(), zero.copy()
        t1 = self.taxi_s + self.takeoff_s
        for start, length, delta in ((self.taxi_s, self.takeoff_s, self.rotate_speed),
                                     (t1, self.climb_s, self.cruise_speed - self.rotate_speed)):
            r, dr, _ = _ramp(t, start, length)
            s += delta * r
            ds += delta * dr
        theta, dtheta = zero.copy(), zero.copy()
        pitch = np.radians(self.climb_pitch_deg)
        for start, length, delta in ((t1 - 5.0, 10.0, pitch),
                                     (self.cruise_start_s - 20.0, 20.0, -pitch)):
            r, dr, _ = _ramp(t, start, length)
            theta += delta * r
            dtheta += delta * dr
        landing = self.landing_start_s
        if landing is not None:
            r, dr, _ = _ramp(t, landing, self.landing_s)
            s += (self.final_speed - self.cruise_speed) * r
            ds += (self.final_speed - self.cruise_speed) * dr
            descent = np.radians(self.descent_pitch_deg)
            for start, delta in ((landing, descent), (self.duration_s - 20.0, -descent)):
                r, dr, _ = _ramp(t, start, 20.0)
                theta += delta * r
                dtheta += delta * dr
        psi = np.full_like(t, np.radians(self.heading0_deg))
        dpsi, ddpsi = zero.copy(), zero.copy()
        turn_len = self._turn_len()
        for k, start in enumerate(self.turn_starts()):
            delta = np.radians(self.turn_angle_deg) * (1.0 if k % 2 == 0 else -1.0)
            r, dr, ddr = _ramp(t, start, turn_len)
            psi += delta * r
            dpsi += delta * dr
            ddpsi += delta * ddr
        c, sn = np.cos(psi), np.sin(psi)
        velocity = np.stack([s * c, s * sn], axis=1)
        force = np.stack([ds * c - s * dpsi * sn, ds * sn + s * dpsi * c], axis=1)
        # bank of a coordinated turn, phi = atan(s psi' / g); its rate is the roll rate
        u = s * dpsi / self.g
        du = (ds * dpsi + s * ddpsi) / self.g
        roll_rate = du / (1.0 + u * u)
        transport = velocity / self.earth_radius
        rate = np.stack([EARTH_RATE * np.cos(np.radians(self.latitude_deg)) + transport[:, 0]
                         + dtheta, transport[:, 1] + roll_rate], axis=1)
        return ProfileSample(velocity, force, rate)
