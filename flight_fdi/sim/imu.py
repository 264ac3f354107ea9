"""Three co-mounted strapdown IMUs with pulse outputs and the seed-002 fault catalogue.

True motion
    A :class:`~flight_fdi.sim.profile.FlightProfile` (default :func:`maneuver_profile`: take-off
    roll, climb and alternating coordinated turns within a minute) gives the true inputs of the
    six quantities ``gyro_x, gyro_y, gyro_z, accel_x, accel_y, accel_z`` (:func:`true_inputs`).
    The IMU axes are the profile's level axes (x, y horizontal channels, z up): gyro x/y = the
    rates the profile's x/y channel gyros sense; gyro z = heading rate + vertical earth rate;
    accel x/y = the horizontal specific force; accel z = g. The three IMUs share one mount, so
    they see the same input; only their errors differ.

Error model (per IMU and quantity; biases and scale factors drawn once per flight)::

    y = clip((1 + k) u + b + n + e_param(t), -full_scale, +full_scale)
    k ~ N(0, scale_sigma^2),  b ~ N(0, bias_sigma^2),  n white: std N / sqrt(dt)

with N the angle / velocity random walk (deg/sqrt(h) for gyros, ug/sqrt(Hz) for accelerometers)
and e_param the parameter faults. **Pulse output**: the integral of y is quantized to whole
pulses of the pulse equivalent q (rad or m/s) with the remainder carried over (the count of
sample k is floor(Theta_k / q) - floor(Theta_(k-1) / q), Theta = theta0 + sum y dt, theta0
uniform in [0, q)); the reported rate is pulses * q / dt. The sum of the pulses over any window
is within one pulse of the true integral.

Fault catalogue (seed 002; :class:`ImuFault`, one IMU, one quantity, over [start, end))

============== =========================================================== ================
type           effect                                                      magnitude
============== =========================================================== ================
zero           output stuck at zero (no pulses)                            (none)
full_scale     output stuck at the full-scale value (sign of magnitude)    (+1 or -1)
doubled        every pulse counted twice (doubled output)                  (none)
step           bias step                                   (faults.py)     rad/s or m/s^2
scale          scale-factor step: + m * true input         (faults.py)     dimensionless
ramp           linear drift m (t - start)                  (faults.py)     per second
sine           sine drift m sin(2 pi f (t - start))        (faults.py)     amplitude
square         square-wave drift +-m (bipolar)             (faults.py)     amplitude
square_onoff   square-wave drift between 0 and m: step(m/2) + square(m/2)  amplitude
============== =========================================================== ================

Parameter faults use the shapes of :mod:`flight_fdi.sim.faults` (``FaultSpec.instrument_error``);
output faults act on the pulse counts. Command-line form (:func:`parse_imu_fault`)::

    IMU:QUANTITY:TYPE:key=value[,key=value...]     keys t, end, mag, freq (as --fault)
    imu3:gyro_z:square:t=20,mag=20deg/h,freq=1
    imu2:gyro_x:zero:t=5

Random numbers: run r, quantity j of a flight seeded s draws from
``SeedSequence(s, spawn_key=(r, j))``, so a run's noise does not depend on how many runs are
simulated together, and a faulty and a nominal run with one seed differ only by the fault.

Bag output (:func:`write_imu_bag`): ``sensor_msgs/msg/Imu`` on ``/imu1/data``, ``/imu2/data``,
``/imu3/data`` (frame ``imu1`` ...; orientation not provided: orientation_covariance[0] = -1;
the rate / acceleration covariance diagonals = the white-noise variance), and the flight's JSON
description on ``/sim/fault`` (std_msgs/String, transient local). Receive time = header stamp.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any, Sequence

import numpy as np

from flight_fdi.core.voting import QUANTITIES

from .errors import SimError
from .faults import DEG_PER_HOUR, G0
from .imu_faults import (FAULT_TYPES, OUTPUT_TYPES, PARAMETER_TYPES, ImuFault,  # noqa: F401
                         parse_imu_fault)
from .ins import EPOCH_S
from .profile import EARTH_RATE, FlightProfile

FORMAT = "flight_fdi.sim.imu/1"
IMU_TOPICS = ("/imu1/data", "/imu2/data", "/imu3/data")
FAULT_TOPIC = "/sim/fault"
IMU_MSG = "sensor_msgs/msg/Imu"
ARCSEC = math.pi / 180.0 / 3600.0
_NS = 1_000_000_000


def maneuver_profile(duration_s: float) -> FlightProfile:
    """A short flight with maneuvers: 2 s standing, a 16-s take-off roll to 60 m/s, a 5-s
    climb to 80 m/s, then 30-degree coordinated turns (peak 6 deg/s, alternating) every 8 s."""
    return FlightProfile(duration_s=duration_s, taxi_s=2.0, takeoff_accel=6.0, rotate_speed=60.0,
                         climb_s=5.0, climb_pitch_deg=8.0, cruise_speed=80.0, turn_every_s=8.0,
                         turn_angle_deg=30.0, turn_rate_deg_s=6.0,
                         landing_s=max(duration_s, 1.0) * 2.0)


def true_inputs(profile: FlightProfile, t: np.ndarray) -> np.ndarray:
    """(T, 6) true gyro x/y/z [rad/s] and accel x/y/z [m/s^2] in the IMU axes (module doc)."""
    motion = profile.evaluate(t)
    v, f = motion.velocity, motion.specific_force
    speed2 = np.sum(v * v, axis=1)
    moving = speed2 > 1e-6
    yaw_rate = np.where(moving, (v[:, 0] * f[:, 1] - v[:, 1] * f[:, 0])
                        / np.where(moving, speed2, 1.0), 0.0)
    wz = yaw_rate + EARTH_RATE * math.sin(math.radians(profile.latitude_deg))
    return np.column_stack([motion.angular_rate[:, 0], motion.angular_rate[:, 1], wz,
                            f[:, 0], f[:, 1], np.full(t.size, profile.g)])


@dataclass(frozen=True)
class ImuErrorModel:
    """Error parameters shared by the three IMUs (each draws its own bias and scale factor)."""

    gyro_bias_dph: float = 0.05           # turn-on bias std [deg/h]
    gyro_scale_ppm: float = 10.0          # scale-factor error std [ppm]
    gyro_arw_dph_rthz: float = 0.005      # angle random walk [deg/sqrt(h)]
    gyro_pulse_arcsec: float = 1.0        # pulse equivalent [arcsec]
    gyro_full_scale_dps: float = 400.0    # measuring range [deg/s]
    accel_bias_ug: float = 50.0           # turn-on bias std [ug]
    accel_scale_ppm: float = 50.0         # scale-factor error std [ppm]
    accel_vrw_ug_rthz: float = 20.0       # velocity random walk [ug/sqrt(Hz)]
    accel_pulse_mps: float = 1e-4         # pulse equivalent [m/s]
    accel_full_scale_g: float = 20.0      # measuring range [g]

    def __post_init__(self) -> None:
        for name, val in asdict(self).items():
            if not isinstance(val, (int, float)) or not math.isfinite(val) or val < 0:
                raise SimError(f"IMU error model: {name} must be a number >= 0, got {val!r}")
        for name in ("gyro_pulse_arcsec", "gyro_full_scale_dps", "accel_pulse_mps",
                     "accel_full_scale_g"):
            if getattr(self, name) <= 0:
                raise SimError(f"IMU error model: {name} must be > 0")

    # per quantity, SI units ------------------------------------------------------------------
    def bias_sigma(self) -> np.ndarray:
        return np.array([self.gyro_bias_dph * DEG_PER_HOUR] * 3
                        + [self.accel_bias_ug * 1e-6 * G0] * 3)

    def scale_sigma(self) -> np.ndarray:
        return np.array([self.gyro_scale_ppm * 1e-6] * 3 + [self.accel_scale_ppm * 1e-6] * 3)

    def noise_density(self) -> np.ndarray:
        """White-noise density N (rad/sqrt(s), m/s^2 * sqrt(s)): sample std = N / sqrt(dt)."""
        arw = self.gyro_arw_dph_rthz * math.pi / 180.0 / 60.0
        return np.array([arw] * 3 + [self.accel_vrw_ug_rthz * 1e-6 * G0] * 3)

    def pulse(self) -> np.ndarray:
        """Pulse equivalent (rad, m/s) per quantity."""
        return np.array([self.gyro_pulse_arcsec * ARCSEC] * 3 + [self.accel_pulse_mps] * 3)

    def full_scale(self) -> np.ndarray:
        return np.array([math.radians(self.gyro_full_scale_dps)] * 3
                        + [self.accel_full_scale_g * G0] * 3)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> "ImuErrorModel":
        known = set(cls.__dataclass_fields__)
        unknown = set(data) - known
        if unknown:
            raise SimError(f"IMU error model: unknown parameters {sorted(unknown)}; parameters "
                           f"are {', '.join(sorted(known))}")
        try:
            return cls(**{k: float(v) for k, v in data.items()})
        except (TypeError, ValueError) as exc:
            raise SimError(f"IMU error model: {exc}") from None


@dataclass(frozen=True)
class ImuSimConfig:
    """What to simulate. ``profile`` None: :func:`maneuver_profile` of the duration."""

    duration_s: float = 60.0
    rate_hz: float = 200.0
    seed: int = 0
    faults: tuple[ImuFault, ...] = ()
    errors: ImuErrorModel = field(default_factory=ImuErrorModel)
    profile: FlightProfile | None = None
    epoch_s: int = EPOCH_S

    def __post_init__(self) -> None:
        object.__setattr__(self, "faults", tuple(self.faults))
        for name in ("duration_s", "rate_hz"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) \
                    or not math.isfinite(val) or val <= 0:
                raise SimError(f"{name.replace('_', ' ')} must be a positive number, got {val!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise SimError(f"seed must be an integer >= 0, got {self.seed!r}")
        n = self.duration_s * self.rate_hz
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 2:
            raise SimError(f"duration ({self.duration_s:g} s) must be a whole number (>= 2) of "
                           f"IMU intervals (1/{self.rate_hz:g} s)")
        if not isinstance(self.epoch_s, (int, np.integer)) or \
                not 0 <= self.epoch_s < 2**31 - 10**6 - self.duration_s:
            raise SimError(f"epoch must be whole seconds in [0, 2^31), got {self.epoch_s!r}")
        if not isinstance(self.errors, ImuErrorModel):
            raise SimError("errors must be an ImuErrorModel")
        if self.profile is not None and not isinstance(self.profile, FlightProfile):
            raise SimError("profile must be a FlightProfile")
        for f in self.faults:
            if not isinstance(f, ImuFault):
                raise SimError(f"faults must be ImuFault objects, got {f!r}")
            f.check_against(self.duration_s, self.rate_hz)

    @property
    def n(self) -> int:
        return int(round(self.duration_s * self.rate_hz))

    @property
    def dt(self) -> float:
        return 1.0 / self.rate_hz

    def flight_profile(self) -> FlightProfile:
        return self.profile or maneuver_profile(self.duration_s)

    def times(self) -> np.ndarray:
        return np.arange(self.n) / self.rate_hz

    def stamps_ns(self) -> np.ndarray:
        return self.epoch_s * _NS + np.round(np.arange(self.n) * (_NS / self.rate_hz)).astype(
            np.int64)


@dataclass
class ImuFlight:
    """A simulated flight of the three IMUs (IMU axis 0..2 = IMU1..IMU3)."""

    config: ImuSimConfig
    t: np.ndarray              # (T,) s from the start
    stamp_ns: np.ndarray       # (T,)
    truth: np.ndarray          # (T, 6) true inputs
    pulses: np.ndarray         # (3, T, 6) int64 pulse counts per sample
    output: np.ndarray         # (3, T, 6) reported rate / acceleration (pulses * q / dt)
    bias: np.ndarray           # (3, 6) per-flight turn-on bias [SI]
    scale: np.ndarray          # (3, 6) per-flight scale-factor error

    def description(self) -> dict[str, Any]:
        c = self.config
        return {"format": FORMAT, "seed": int(c.seed), "duration_s": float(c.duration_s),
                "rate_hz": float(c.rate_hz), "epoch_s": int(c.epoch_s),
                "quantities": list(QUANTITIES), "topics": list(IMU_TOPICS),
                "errors": asdict(c.errors),
                "profile": asdict(c.flight_profile()),
                "faults": [f.to_dict() for f in c.faults]}


class ImuBatch:
    """Vectorised simulation of many runs of the three IMUs on one profile (no faults yet).

    ``continuous(quantities)`` gives the error-laden, un-quantized outputs (R, 3, T, Q) of the
    runs; ``quantize`` turns them (after adding faults) into pulses. Run r and quantity j draw
    from their own stream ``SeedSequence(seed, spawn_key=(r, j))`` in a fixed order (phase,
    bias, scale, noise), so a run's numbers do not depend on which runs and quantities are
    simulated together.
    """

    def __init__(self, config: ImuSimConfig, n_runs: int, first_run: int = 0) -> None:
        if isinstance(n_runs, bool) or not isinstance(n_runs, (int, np.integer)) or n_runs < 1:
            raise SimError(f"number of runs must be an integer >= 1, got {n_runs!r}")
        self.config = config
        self.n_runs = int(n_runs)
        self.t = config.times()
        self.truth = true_inputs(config.flight_profile(), self.t)
        self.first_run = int(first_run)
        e = config.errors
        self._bias_sigma = e.bias_sigma()
        self._scale_sigma = e.scale_sigma()
        self._noise_std = e.noise_density() / math.sqrt(config.dt)
        self.pulse = e.pulse()
        self.full_scale = e.full_scale()

    def draws(self, quantity_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(phase (R, 3) in pulses, bias (R, 3), scale (R, 3), noise (R, 3, T)) of one quantity."""
        R, T = self.n_runs, self.t.size
        phase = np.empty((R, 3))
        bias = np.empty((R, 3))
        scale = np.empty((R, 3))
        noise = np.empty((R, 3, T))
        j = quantity_index
        for r in range(R):
            rng = np.random.default_rng(np.random.SeedSequence(
                self.config.seed, spawn_key=(self.first_run + r, j)))
            phase[r] = rng.random(3)
            bias[r] = rng.standard_normal(3) * self._bias_sigma[j]
            scale[r] = rng.standard_normal(3) * self._scale_sigma[j]
            noise[r] = rng.standard_normal((3, T)) * self._noise_std[j]
        return phase, bias, scale, noise

    def continuous(self, quantity_index: int) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                      np.ndarray]:
        """(y (R, 3, T) without faults and before quantization, phase, bias, scale)."""
        phase, bias, scale, noise = self.draws(quantity_index)
        u = self.truth[:, quantity_index]
        y = (1.0 + scale)[:, :, None] * u[None, None, :] + bias[:, :, None] + noise
        return y, phase, bias, scale

    def quantize(self, y: np.ndarray, phase: np.ndarray, quantity_index: int) -> np.ndarray:
        """Pulse counts (R, 3, T) int64 of the rates ``y`` (clipped at full scale)."""
        j = quantity_index
        fs, q, dt = self.full_scale[j], self.pulse[j], self.config.dt
        y = np.clip(y, -fs, fs)
        theta = phase[..., None] + np.cumsum(y * (dt / q), axis=-1)  # in pulses
        level = np.floor(theta)
        counts = np.diff(level, axis=-1, prepend=np.floor(phase)[..., None])
        return counts.astype(np.int64)

    def to_output(self, counts: np.ndarray, quantity_index: int) -> np.ndarray:
        return counts * (self.pulse[quantity_index] / self.config.dt)


def _apply_output_fault(counts: np.ndarray, fault: ImuFault, mask: np.ndarray,
                        full_scale_counts: float) -> None:
    """Output faults on the pulse counts (in place) of the faulty IMU (last axis: time)."""
    if fault.type == "zero":
        counts[..., mask] = 0
    elif fault.type == "doubled":
        counts[..., mask] *= 2
    else:  # full_scale
        counts[..., mask] = int(round(full_scale_counts)) * (-1 if fault.magnitude < 0 else 1)


def simulate_quantity(batch: ImuBatch, quantity: str, faults: Sequence[ImuFault] = (),
                      draws: tuple | None = None) -> np.ndarray:
    """Pulse counts (R, 3, T) of one quantity for every run of ``batch``, with ``faults``
    (those on other quantities are ignored). ``draws``: a ``batch.continuous(j)`` result to
    reuse (it is not modified)."""
    j = QUANTITIES.index(quantity)
    y, phase, _, _ = draws if draws is not None else batch.continuous(j)
    y = y.copy()
    c = batch.config
    mine = [f for f in faults if f.quantity == quantity]
    for f in mine:
        if f.type not in OUTPUT_TYPES:
            y[:, f.imu - 1] += f.parameter_error(batch.t, batch.truth[:, j], c.duration_s)
    counts = batch.quantize(y, phase, j)
    fs_counts = batch.full_scale[j] * c.dt / batch.pulse[j]
    for f in mine:
        if f.type in OUTPUT_TYPES:
            _apply_output_fault(counts[:, f.imu - 1], f, f.active(batch.t, c.duration_s),
                                fs_counts)
    return counts


def simulate_imus(config: ImuSimConfig, run: int = 0) -> ImuFlight:
    """One flight of the three IMUs (run ``run`` of the seed's streams)."""
    batch = ImuBatch(config, 1, first_run=run)
    T = batch.t.size
    pulses = np.empty((3, T, len(QUANTITIES)), dtype=np.int64)
    bias = np.empty((3, len(QUANTITIES)))
    scale = np.empty((3, len(QUANTITIES)))
    for j, q in enumerate(QUANTITIES):
        draws = batch.continuous(j)
        pulses[:, :, j] = simulate_quantity(batch, q, config.faults, draws)[0]
        bias[:, j], scale[:, j] = draws[2][0], draws[3][0]
    output = pulses * (batch.pulse / config.dt)[None, None, :]
    return ImuFlight(config, batch.t, config.stamps_ns(), batch.truth, pulses, output, bias,
                     scale)


def output_variance(config: ImuSimConfig) -> np.ndarray:
    """Per-sample variance (6,) of the reported rate / acceleration about the true input:
    white noise N^2 / dt plus the pulse quantization (the carried remainders of two samples
    differ by a uniform variable each: (q / dt)^2 / 6)."""
    e = config.errors
    return e.noise_density() ** 2 / config.dt + (e.pulse() / config.dt) ** 2 / 6.0


# --------------------------------------------------------------------------- Monte Carlo

def pair_window_means(counts: np.ndarray, batch: ImuBatch, quantity_index: int,
                      window: int) -> np.ndarray:
    """Window means (R, T, 3) of x1, x2, x3 for pulse counts (R, 3, T) of one quantity, in the
    output units (rad/s, m/s^2)."""
    from flight_fdi.core.voting import pair_differences, window_means

    out = batch.to_output(counts, quantity_index)          # (R, 3, T)
    return window_means(pair_differences(np.moveaxis(out, 1, -1)), window, axis=1)


def nominal_window_means(config: ImuSimConfig, n_flights: int, window: int,
                         quantities: Sequence[str] = QUANTITIES, eval_every: int = 10,
                         batch_size: int = 100, first_run: int = 0,
                         progress: Any = None) -> tuple[np.ndarray, np.ndarray]:
    """Monte Carlo over ``n_flights`` nominal flights: the window means of the pair differences
    every ``eval_every`` samples. Returns (t (K,), means (n_flights, K, Q, 3)).

    Flights are simulated ``batch_size`` at a time (vectorised over the runs of a batch);
    ``progress(k)`` is called after each batch with the number of flights done in it.
    """
    if config.faults:
        raise SimError("the calibration Monte Carlo simulates nominal flights; remove the faults")
    for name, val in (("n_flights", n_flights), ("window", window), ("eval_every", eval_every),
                      ("batch_size", batch_size)):
        if isinstance(val, bool) or not isinstance(val, (int, np.integer)) or val < 1:
            raise SimError(f"{name} must be an integer >= 1, got {val!r}")
    bad = [q for q in quantities if q not in QUANTITIES]
    if bad or not quantities:
        raise SimError(f"unknown quantities {bad}; quantities are {', '.join(QUANTITIES)}")
    idx = np.arange(0, config.n, eval_every)
    t = idx / config.rate_hz
    means = np.empty((n_flights, idx.size, len(quantities), 3))
    done = 0
    while done < n_flights:
        b = min(batch_size, n_flights - done)
        batch = ImuBatch(config, b, first_run=first_run + done)
        for iq, q in enumerate(quantities):
            j = QUANTITIES.index(q)
            counts = simulate_quantity(batch, q)
            means[done:done + b, :, iq, :] = pair_window_means(counts, batch, j, window)[:, idx]
        done += b
        if progress is not None:
            progress(b)
    return t, means


# --------------------------------------------------------------------------- bag output

def encode_imu(stamp_ns: np.ndarray, output: np.ndarray, frame_id: str,
               noise_var: np.ndarray) -> list[bytes]:
    """Serialize a series of sensor_msgs/Imu (vectorised,
    :func:`flight_fdi.bagio.cdr.encode_doubles`):
    ``output`` (T, 6) = gyro x/y/z, accel x/y/z; ``noise_var`` (6,) the covariance diagonals.
    Orientation (0, 0, 0, 1) with orientation_covariance[0] = -1 (no orientation estimate, per
    the message definition)."""
    from flight_fdi.bagio import cdr

    out = np.asarray(output, dtype=float)
    n = out.shape[0]
    values = np.zeros((n, 37))  # orientation 4, its covariance 9, gyro 3 + 9, accel 3 + 9
    values[:, 3] = 1.0
    values[:, 4] = -1.0
    values[:, 13:16] = out[:, :3]
    values[:, [16, 20, 24]] = noise_var[0]
    values[:, 25:28] = out[:, 3:]
    values[:, [28, 32, 36]] = noise_var[3]
    return cdr.encode_doubles(cdr.IMU, stamp_ns, frame_id, values)


def write_imu_bag(flight: ImuFlight, path: str, storage: str = "mcap",
                  compression: str = "zstd", overwrite: bool = False) -> dict[str, int]:
    """Write the three IMU streams (and /sim/fault) as a rosbag2 bag; message count per topic."""
    from flight_fdi.bagio.typestore import get_typestore
    from flight_fdi.bagio.writer import open_writer

    c = flight.config
    noise_var = output_variance(c)
    if not np.all(np.isfinite(flight.output)):
        raise SimError("the simulated IMU output contains NaN or Inf")
    series = []
    for k, topic in enumerate(IMU_TOPICS):
        payloads = encode_imu(flight.stamp_ns, flight.output[k], f"imu{k + 1}", noise_var)
        series.append((topic, IMU_MSG, flight.stamp_ns, payloads))
    doc = json.dumps(flight.description(), sort_keys=True)
    store = get_typestore()
    String = store.types["std_msgs/msg/String"]
    fault_payload = bytes(store.serialize_cdr(String(data=doc), "std_msgs/msg/String"))
    with open_writer(path, storage=storage, compression=compression, overwrite=overwrite) as bag:
        bag.add_topic(FAULT_TOPIC, "std_msgs/msg/String", qos="transient_local")
        bag.set_metadata("flight_fdi.sim.imu", doc)
        bag.write_series([(FAULT_TOPIC, "std_msgs/msg/String",
                           np.array([flight.stamp_ns[0]]), [fault_payload])] + series)
        counts = dict(bag.counts)
    return counts
