"""Flight trajectories for the 3-D simulator: straight legs, coordinated turns, climbs and
descents, speed changes.

A flight is a sequence of legs (``Leg``); each leg changes one control smoothly (quintic
smoothstep, so the jerk stays finite and the IMU signals are continuous):

- speed V (m/s, over the Earth; no wind), flight-path angle gamma (climb positive), bank phi
  (right wing down positive);
- heading (course, from North clockwise) from the coordinated-turn rate
  chi' = g0 tan(phi) / (V cos gamma), integrated with the trapezoidal rule on the sample grid;
- attitude (REP 103 Euler angles, ``rotation``): yaw = pi/2 - chi, pitch = -(gamma + alpha)
  (nose up is a negative REP 103 pitch), roll = phi; alpha is a constant angle of attack;
- velocity ENU = V (cos gamma sin chi, cos gamma cos chi, sin gamma); position from the velocity
  with the mechanization's own trapezoidal rule (``strapdown.integrate_position``), so the
  sampled trajectory is exactly one the mechanization can fly.

Profiles (``PROFILES``): ``cruise_turns`` (default: cruise with turns of 90-180 deg, 600-m
climbs and descents and speed changes every few minutes), ``survey_grid`` (parallel lines joined
by 180-deg turns, constant height and speed), ``straight`` (one straight, level leg), ``random``
(seeded random legs). Designed for speeds 50-250 m/s, 0.5-3 h, latitudes 0-70 deg (shorter
flights work: the leg sequence is cut at the end of the flight).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from .errors import SimError
from .rotation import quat_from_euler_array
from .strapdown import NavSolution, integrate_position

G0 = 9.80665
PROFILES = ("cruise_turns", "survey_grid", "straight", "random")
DEFAULT_SPEED = {"cruise_turns": 200.0, "survey_grid": 80.0, "straight": 200.0, "random": 150.0}
CONTROLS = ("speed", "gamma", "bank")


def smoothstep(s: np.ndarray) -> np.ndarray:
    """Quintic 0 -> 1 on [0, 1] with zero first and second derivatives at both ends."""
    s = np.clip(s, 0.0, 1.0)
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def _mean_tan(bank: float) -> float:
    """mean of tan(bank * smoothstep(s)) over s in [0, 1] (Simpson, 201 points)."""
    s = np.linspace(0.0, 1.0, 201)
    y = np.tan(bank * smoothstep(s))
    return float((y[0] + y[-1] + 4 * y[1:-1:2].sum() + 2 * y[2:-1:2].sum()) / 600.0)


@dataclass
class Leg:
    """One leg: a transition of ``control`` to ``value`` over [start, start + ramp_s], held,
    then (``back``) a return to the previous value over the last ramp_s of the leg."""

    kind: str          # straight | turn | climb | speed
    duration_s: float
    control: str = "bank"
    value: float = 0.0
    ramp_s: float = 0.0
    back: bool = False


@dataclass
class Schedule:
    """Smooth transitions per control: (t0, t1, delta) lists; values start at ``initial``."""

    initial: dict[str, float]
    steps: dict[str, list[tuple[float, float, float]]] = field(
        default_factory=lambda: {c: [] for c in CONTROLS})
    legs: list[tuple[float, Leg]] = field(default_factory=list)

    def evaluate(self, t: np.ndarray) -> dict[str, np.ndarray]:
        """The controls at the (sorted) times t."""
        out = {}
        for c in CONTROLS:
            y = np.full(t.shape, float(self.initial[c]))
            for t0, t1, d in self.steps[c]:
                i0, i1 = np.searchsorted(t, [t0, t1])
                y[i0:i1] += d * smoothstep((t[i0:i1] - t0) / (t1 - t0))
                y[i1:] += d
            out[c] = y
        return out


def _turn(delta_deg: float, speed: float, bank_deg: float, roll_s: float = 6.0) -> Leg:
    """A coordinated turn by delta_deg (right positive): roll in, hold, roll out."""
    chi = math.radians(abs(delta_deg))
    bank = math.radians(bank_deg)
    hold = (chi * speed / G0 - 2 * roll_s * _mean_tan(bank)) / math.tan(bank)
    if hold < 0:  # a small turn: lower the bank until the roll in and out alone make it
        lo, hi = 0.0, bank
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if 2 * roll_s * _mean_tan(mid) * G0 / speed < chi else (lo, mid)
        bank, hold = 0.5 * (lo + hi), 0.0
    return Leg("turn", 2 * roll_s + hold, "bank", math.copysign(bank, delta_deg), roll_s, True)


def _climb(delta_h: float, speed: float, gamma_deg: float = 3.0, ramp_s: float = 10.0) -> Leg:
    """Climb (or descend, delta_h < 0) by delta_h metres at flight-path angle gamma_deg."""
    g = math.radians(abs(gamma_deg))
    s = np.linspace(0.0, 1.0, 201)
    mean_sin = float(np.mean(np.sin(g * smoothstep(s))))
    hold = max(0.0, (abs(delta_h) / speed - 2 * ramp_s * mean_sin) / math.sin(g))
    return Leg("climb", 2 * ramp_s + hold, "gamma", math.copysign(g, delta_h), ramp_s, True)


def _speed(delta_v: float, accel: float = 0.5) -> Leg:
    ramp = 1.875 * abs(delta_v) / accel   # peak acceleration of the smoothstep = accel
    return Leg("speed", ramp, "speed", delta_v, ramp, False)


def _cruise_turns(speed: float, duration: float, rng: np.random.Generator) -> list[Leg]:
    dv = min(30.0, speed - 50.0)  # the slow-down keeps the speed >= 50 m/s
    slow = [_speed(-dv), Leg("straight", 180.0)] if dv >= 1.0 else [Leg("straight", 180.0)]
    back = [_speed(dv)] if dv >= 1.0 else []
    v2 = speed - max(dv, 0.0) if dv >= 1.0 else speed
    cycle = [
        Leg("straight", 300.0), _turn(90, speed, 25), Leg("straight", 240.0),
        _climb(600, speed), Leg("straight", 300.0), _turn(-135, speed, 20),
        Leg("straight", 240.0), *slow, _turn(180, v2, 30), Leg("straight", 300.0),
        _climb(-600, v2), Leg("straight", 180.0), *back, _turn(-135, speed, 25)]
    legs: list[Leg] = []
    while sum(leg.duration_s for leg in legs) < duration:
        legs += cycle
    return legs


def _survey_grid(speed: float, duration: float, rng: np.random.Generator) -> list[Leg]:
    legs: list[Leg] = [Leg("straight", 300.0)]
    sign = 1
    while sum(leg.duration_s for leg in legs) < duration:
        legs += [_turn(180 * sign, speed, 20), Leg("straight", 480.0)]
        sign = -sign
    return legs


def _random(speed: float, duration: float, rng: np.random.Generator,
            alt: float = 3000.0) -> list[Leg]:
    legs: list[Leg] = [Leg("straight", float(rng.uniform(120, 300)))]
    v, h = speed, alt
    while sum(leg.duration_s for leg in legs) < duration:
        kind = rng.choice(["turn", "turn", "climb", "speed"])
        if kind == "turn":
            legs.append(_turn(float(rng.choice([-1, 1]) * rng.uniform(30, 180)), v,
                              float(rng.uniform(15, 30))))
        elif kind == "climb":
            dh = float(rng.uniform(200, 1500)) * (1 if h < 6000 else -1) * rng.choice([1, 1, -1])
            dh = float(np.clip(h + dh, 500, 12000) - h)
            if abs(dh) > 50:
                legs.append(_climb(dh, v, float(rng.uniform(2, 5))))
                h += dh
        else:
            dv = float(np.clip(v + rng.choice([-1, 1]) * rng.uniform(10, 50), 50, 250) - v)
            if abs(dv) > 1:
                legs.append(_speed(dv, float(rng.uniform(0.3, 1.0))))
                v += dv
        legs.append(Leg("straight", float(rng.uniform(120, 900))))
    return legs


@dataclass(frozen=True)
class TrajectoryConfig:
    """What to fly. Angles in degrees, heading from North clockwise."""

    profile: str = "cruise_turns"
    duration_s: float = 3600.0
    rate_hz: float = 100.0
    lat_deg: float = 45.0
    lon_deg: float = 7.0
    alt_m: float = 3000.0
    speed_mps: float | None = None      # None: the profile's default (DEFAULT_SPEED)
    heading_deg: float = 0.0
    aoa_deg: float = 2.0
    seed: int = 0

    def __post_init__(self) -> None:
        if self.profile not in PROFILES:
            raise SimError(f"unknown profile {self.profile!r}; choose one of {', '.join(PROFILES)}")
        for name in ("duration_s", "rate_hz"):
            val = getattr(self, name)
            if not isinstance(val, (int, float)) or not math.isfinite(val) or val <= 0:
                raise SimError(f"{name.replace('_', ' ')} must be a positive number, got {val!r}")
        if not -70.0 <= self.lat_deg <= 70.0:
            raise SimError(f"latitude must be within +-70 deg, got {self.lat_deg!r}")
        if not -1000.0 <= self.alt_m <= 15000.0:
            raise SimError(f"altitude must be within -1000..15000 m, got {self.alt_m!r}")
        if self.speed_mps is not None and not 0.0 <= self.speed_mps <= 300.0:
            raise SimError(f"speed must be within 0..300 m/s, got {self.speed_mps!r}")
        n = self.duration_s * self.rate_hz
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 2:
            raise SimError(f"duration ({self.duration_s:g} s) must be a whole number (>= 2) of "
                           f"sample intervals (1/{self.rate_hz:g} s)")

    @property
    def speed(self) -> float:
        return DEFAULT_SPEED[self.profile] if self.speed_mps is None else float(self.speed_mps)

    @property
    def n(self) -> int:
        return int(round(self.duration_s * self.rate_hz)) + 1


def schedule(config: TrajectoryConfig) -> Schedule:
    """The profile's legs laid out in time."""
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, 14]))
    v0 = config.speed
    builder = {"cruise_turns": _cruise_turns, "survey_grid": _survey_grid,
               "straight": lambda v, d, r: [Leg("straight", d)], "random": _random}
    if config.profile == "random":
        legs = _random(v0, config.duration_s, rng, config.alt_m)
    else:
        legs = builder[config.profile](v0, config.duration_s, rng)
    sched = Schedule(initial={"speed": v0, "gamma": 0.0, "bank": 0.0})
    t = 0.0
    for leg in legs:
        if t >= config.duration_s:
            break
        sched.legs.append((t, leg))
        if leg.kind != "straight":
            sched.steps[leg.control].append((t, t + leg.ramp_s, leg.value))
            if leg.back:
                t1 = t + leg.duration_s
                sched.steps[leg.control].append((t1 - leg.ramp_s, t1, -leg.value))
        t += leg.duration_s
    return sched


@dataclass
class Trajectory:
    """A sampled true trajectory and the controls that made it."""

    config: TrajectoryConfig
    t: np.ndarray                  # (N,) s from the start
    nav: NavSolution               # true lat, lon, h, v (ENU), q_b^n
    controls: dict[str, np.ndarray]  # speed, gamma, bank, heading (rad)
    schedule: Schedule

    @property
    def dt(self) -> float:
        return 1.0 / self.config.rate_hz


def generate(config: TrajectoryConfig) -> Trajectory:
    """Sample the profile at ``config.rate_hz`` from t = 0 to the duration (inclusive)."""
    sched = schedule(config)
    t = np.arange(config.n) / config.rate_hz
    c = sched.evaluate(t)
    if np.any(c["speed"] < 0):
        raise SimError("the profile's speed changes make the speed negative; raise --speed")
    vh = c["speed"] * np.cos(c["gamma"])
    chi_rate = G0 * np.tan(c["bank"]) / np.where(vh > 1e-3, vh, np.inf)
    chi = math.radians(config.heading_deg) + np.concatenate(
        [[0.0], np.cumsum(0.5 * (chi_rate[1:] + chi_rate[:-1]) / config.rate_hz)])
    v = np.stack([vh * np.sin(chi), vh * np.cos(chi), c["speed"] * np.sin(c["gamma"])], axis=1)
    q = quat_from_euler_array(0.5 * np.pi - chi, -(c["gamma"] + math.radians(config.aoa_deg)),
                              c["bank"])
    lat, lon, h = integrate_position(math.radians(config.lat_deg), math.radians(config.lon_deg),
                                     float(config.alt_m), np.ascontiguousarray(v),
                                     1.0 / config.rate_hz)
    c["heading"] = chi
    return Trajectory(config, t, NavSolution(lat, lon, h, v, q), c, sched)
