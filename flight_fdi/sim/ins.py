"""Flight simulator: the INS error model of seed 000 (SPEC section 1) with injected faults.

For each horizontal channel (x and y, independent) the truth error state
x = [velocity_error, tilt, accel_bias, gyro_drift] is propagated with THE SAME model the filter
uses (``flight_fdi.core.models.ins_channel``), discretized exactly for the INS interval::

    s[k+1] = Phi s[k] + Bd e[k] + w[k],   w[k] ~ N(0, Qd),   s[0] ~ N(0, P0)
    x[k]   = s[k] + [0, 0, e_a[k], e_w[k]]

where s carries the Gauss-Markov instrument errors and e = [e_a, e_w] are the fault errors
(``faults``), held over each interval and entering the velocity and tilt equations as the
accelerometer and gyro errors do (Bd = int_0^dt expm(A t) dt [I2; 0]). The truth accel_bias
and gyro_drift therefore jump with a step fault, exactly as the instrument error does.

The measured quantities, with the true motion from ``profile``::

    V_INS = V_true + velocity_error             (at the INS rate)
    V_ref = V_true + N(0, sigma_ref^2) (+ reference faults)   (at the reference rate)

Random numbers: one ``numpy.random.SeedSequence(seed)`` spawns independent streams for the x
channel, the y channel, the reference noise and the outliers, so adding a fault never changes
the noise of a run: a faulty and a nominal run with one seed differ by the fault's effect only.
"""
from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np

from flight_fdi.core.errors import CoreError
from flight_fdi.core.models import LinearModel, ins_channel

from .errors import SimError
from .faults import FaultSpec
from .profile import FlightProfile, ProfileSample

EPOCH_S = 1_700_000_000          # stamps start here so that times look real
AXES = ("x", "y")
FORMAT = "flight_fdi.sim/1"
_NS = 1_000_000_000


def _rate_ratio(fast: float, slow: float, what: str) -> int:
    ratio = fast / slow
    k = int(round(ratio))
    if k < 1 or abs(ratio - k) > 1e-9 * ratio:
        raise SimError(f"{what} ({slow:g} Hz) must divide the INS rate ({fast:g} Hz) "
                       f"a whole number of times")
    return k


@dataclass(frozen=True)
class SimConfig:
    """What to simulate. Rates in Hz, times in seconds."""

    duration_s: float = 1000.0
    ins_rate_hz: float = 50.0
    ref_rate_hz: float = 10.0
    truth_rate_hz: float = 1.0
    seed: int = 0
    channel: str = "x"                        # default axis of the faults
    faults: tuple[FaultSpec, ...] = ()
    model_params: Mapping[str, float] = field(default_factory=dict)  # ins_channel overrides
    epoch_s: int = EPOCH_S
    profile: FlightProfile | None = None      # default: FlightProfile(duration_s)

    def __post_init__(self) -> None:
        object.__setattr__(self, "faults", tuple(self.faults))
        object.__setattr__(self, "model_params", dict(self.model_params))
        for name in ("duration_s", "ins_rate_hz", "ref_rate_hz", "truth_rate_hz"):
            val = getattr(self, name)
            if not isinstance(val, (int, float)) or not math.isfinite(val) or val <= 0:
                raise SimError(f"{name.replace('_', ' ')} must be a positive number, got {val!r}")
        if self.channel not in AXES:
            raise SimError(f"channel must be x or y, got {self.channel!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise SimError(f"seed must be an integer >= 0, got {self.seed!r}")
        if not isinstance(self.epoch_s, (int, np.integer)) or not 0 <= self.epoch_s < 2**31 - 10**6:
            raise SimError(f"epoch must be whole seconds in [0, 2^31), got {self.epoch_s!r}")
        n = self.duration_s * self.ins_rate_hz
        if abs(n - round(n)) > 1e-6 * max(1.0, n) or round(n) < 2:
            raise SimError(f"duration ({self.duration_s:g} s) must be a whole number (>= 2) of "
                           f"INS intervals (1/{self.ins_rate_hz:g} s)")
        if self.epoch_s + self.duration_s >= 2**31:
            raise SimError("the flight would end after the year 2038 (int32 stamp seconds)")
        _rate_ratio(self.ins_rate_hz, self.ref_rate_hz, "the reference rate")
        _rate_ratio(self.ins_rate_hz, self.truth_rate_hz, "the truth rate")
        for f in self.faults:
            if not isinstance(f, FaultSpec):
                raise SimError(f"faults must be FaultSpec objects, got {f!r}")
            f.check_against(self.duration_s, self.ins_rate_hz, self.ref_rate_hz)
        if self.profile is not None and not isinstance(self.profile, FlightProfile):
            raise SimError("profile must be a FlightProfile")

    @property
    def n_ins(self) -> int:
        return int(round(self.duration_s * self.ins_rate_hz))

    def model(self) -> LinearModel:
        """The INS channel model with the parameter overrides."""
        try:
            return ins_channel(**self.model_params)
        except TypeError as exc:
            raise SimError(f"model parameters: {exc}") from None
        except CoreError as exc:
            raise SimError(f"model parameters: {exc}") from None


@dataclass
class SimulatedFlight:
    """Everything a simulation produced (times in s from the start; axis order x, y)."""

    config: SimConfig
    model: LinearModel
    t: np.ndarray                 # (N,) INS sample times, s
    stamp_ns: np.ndarray          # (N,) INS header stamps, ns since the Unix epoch
    motion: ProfileSample         # true velocity, specific force, angular rate (N, 2)
    x_true: np.ndarray            # (2, N, n) true error state per axis at the INS times
    fault_error: np.ndarray       # (2, N, 2) injected instrument errors [accel, gyro] per axis
    v_ins: np.ndarray             # (N, 2)
    ref_index: np.ndarray         # (M,) INS sample index of each reference message sent
    v_ref: np.ndarray             # (M, 2)
    ref_outlier: np.ndarray       # (M, 2) bool: an outlier was added
    sigma_ref: float
    truth_index: np.ndarray       # (K,) INS sample index of each truth message

    @property
    def t_ref(self) -> np.ndarray:
        return self.t[self.ref_index]

    @property
    def stamp_ref_ns(self) -> np.ndarray:
        return self.stamp_ns[self.ref_index]

    def description(self) -> dict[str, Any]:
        """The JSON document stored on /sim/fault: the flight's settings and injected faults."""
        c = self.config
        return {
            "format": FORMAT,
            "seed": int(c.seed),
            "duration_s": float(c.duration_s),
            "ins_rate_hz": float(c.ins_rate_hz),
            "ref_rate_hz": float(c.ref_rate_hz),
            "truth_rate_hz": float(c.truth_rate_hz),
            "channel": c.channel,
            "epoch_s": int(c.epoch_s),
            "model": {"name": self.model.name, "params": dict(self.model.params)},
            "faults": [f.to_dict(c.channel) for f in c.faults],
        }


def psd_sqrt(M: np.ndarray, scale: np.ndarray | None = None) -> np.ndarray:
    """L with L L^T = M for a symmetric positive semidefinite M (possibly singular).

    Computed by an eigen-decomposition in the scaled coordinates M / (s s^T), which keeps
    states of very different magnitudes (m/s next to rad/s) accurate.
    """
    M = np.asarray(M, dtype=float)
    s = np.ones(M.shape[0]) if scale is None else np.asarray(scale, dtype=float)
    Ms = M / np.outer(s, s)
    Ms = 0.5 * (Ms + Ms.T)
    lam, V = np.linalg.eigh(Ms)
    top = max(float(np.max(np.abs(lam))), 1e-300)
    if lam.min() < -1e-9 * top:
        raise SimError(f"covariance is not positive semidefinite (eigenvalue {lam.min():.3g})")
    return s[:, None] * (V * np.sqrt(np.clip(lam, 0.0, None)))


def propagate(Phi: np.ndarray, x0: np.ndarray, u: np.ndarray) -> np.ndarray:
    """X with X[0] = x0 and X[k+1] = Phi X[k] + u[k]; u has N-1 rows, X has N.

    Exact block evaluation (no per-sample Python loop): the series is cut into blocks of
    L ~ sqrt(N) samples; the zero-state responses of all blocks are run side by side (L steps),
    the block start states follow with Phi^L (N/L steps), and X = Phi^i S_b + Z_b[i].
    """
    Phi = np.asarray(Phi, dtype=float)
    x0 = np.asarray(x0, dtype=float).reshape(-1)
    u = np.asarray(u, dtype=float)
    n = x0.size
    N = u.shape[0] + 1
    L = max(1, int(math.isqrt(N)))
    nb = -(-N // L)
    U = np.zeros((nb * L, n))
    U[:N - 1] = u
    U = U.reshape(nb, L, n)
    Z = np.zeros((nb, L + 1, n))
    PhiT = Phi.T
    for i in range(L):
        Z[:, i + 1] = Z[:, i] @ PhiT + U[:, i]
    powers = np.empty((L + 1, n, n))
    powers[0] = np.eye(n)
    for i in range(L):
        powers[i + 1] = Phi @ powers[i]
    S = np.empty((nb, n))
    S[0] = x0
    PhiL = powers[L]
    for b in range(nb - 1):
        S[b + 1] = PhiL @ S[b] + Z[b, L]
    X = np.einsum("lij,bj->bli", powers[:L], S) + Z[:, :L]
    return X.reshape(nb * L, n)[:N]


def _fault_input_matrix(model: LinearModel, dt: float) -> np.ndarray:
    """Bd: how a held accelerometer / gyro error over one interval moves the state."""
    iv, it = model.index("velocity_error"), model.index("tilt")
    B = np.zeros((model.n, 2))
    B[iv, 0] = 1.0   # dV' = ... + accelerometer error
    B[it, 1] = 1.0   # tilt' = ... + gyro error
    with_b = LinearModel(model.name, model.state_names, model.state_units, model.A, model.Qc,
                         model.H, model.R, model.P0, B=B, scale=model.scale)
    return np.asarray(with_b.discretize(dt)[2])


def simulate(config: SimConfig) -> SimulatedFlight:
    """Run one seeded flight (no I/O)."""
    c = config
    model = c.model()
    iv, ia, iw = (model.index(nm) for nm in ("velocity_error", "accel_bias", "gyro_drift"))
    N = c.n_ins
    dt = 1.0 / c.ins_rate_hz
    t = np.arange(N) * dt
    stamp_ns = c.epoch_s * _NS + np.round(np.arange(N) * (_NS / c.ins_rate_hz)).astype(np.int64)
    profile = c.profile or FlightProfile(c.duration_s, g=model.params.get("g", 9.80665),
                                         earth_radius=model.params.get("earth_radius", 6.371e6))
    motion = profile.evaluate(t)

    rng_axes = [np.random.default_rng(s) for s in np.random.SeedSequence(c.seed).spawn(4)]
    rng_ref, rng_out = rng_axes[2], rng_axes[3]
    Phi, Qd, _ = model.discretize(dt)
    Bd = _fault_input_matrix(model, dt)
    Lq = psd_sqrt(Qd, model.scale)
    L0 = psd_sqrt(model.P0, model.scale)

    x_true = np.empty((2, N, model.n))
    fault_error = np.zeros((2, N, 2))
    for a, axis in enumerate(AXES):
        rng = rng_axes[a]
        x0 = L0 @ rng.standard_normal(model.n)
        w = rng.standard_normal((N - 1, model.n)) @ Lq.T
        for f in c.faults:
            if f.target == "ref" or (f.axis or c.channel) != axis:
                continue
            col = 0 if f.target == "accel" else 1
            true_input = (motion.specific_force if col == 0 else motion.angular_rate)[:, a]
            fault_error[a, :, col] += f.instrument_error(t, true_input, c.duration_s)
        u = w + fault_error[a, :-1] @ Bd.T
        x = propagate(Phi, x0, u)
        x[:, ia] += fault_error[a, :, 0]
        x[:, iw] += fault_error[a, :, 1]
        x_true[a] = x
    v_ins = motion.velocity + x_true[:, :, iv].T

    k_ref = _rate_ratio(c.ins_rate_hz, c.ref_rate_hz, "the reference rate")
    ref_index = np.arange(0, N, k_ref)
    t_ref = t[ref_index]
    sigma_ref = float(np.sqrt(model.R[0, 0]))
    v_ref = motion.velocity[ref_index] + sigma_ref * rng_ref.standard_normal((ref_index.size, 2))
    outlier = np.zeros((ref_index.size, 2), dtype=bool)
    keep = np.ones(ref_index.size, dtype=bool)
    for f in c.faults:
        if f.target != "ref":
            continue
        a = AXES.index(f.axis or c.channel)
        active = f.active(t_ref, c.duration_s)
        if f.type == "jump":
            v_ref[active, a] += f.magnitude
        elif f.type == "outliers":
            hit = (rng_out.random(ref_index.size) < f.freq_hz / c.ref_rate_hz) & active
            sign = np.where(rng_out.random(ref_index.size) < 0.5, -1.0, 1.0)
            v_ref[hit, a] += sign[hit] * f.magnitude
            outlier[hit, a] = True
        else:  # dropout
            keep &= ~active
    k_truth = _rate_ratio(c.ins_rate_hz, c.truth_rate_hz, "the truth rate")
    return SimulatedFlight(
        config=c, model=model, t=t, stamp_ns=stamp_ns, motion=motion, x_true=x_true,
        fault_error=fault_error, v_ins=v_ins, ref_index=ref_index[keep], v_ref=v_ref[keep],
        ref_outlier=outlier[keep], sigma_ref=sigma_ref, truth_index=np.arange(0, N, k_truth))


# --------------------------------------------------------------------------- bag output

FILTER_STATE = "flight_fdi_msgs/msg/FilterState"
INS_TOPIC = "/ins/velocity"
REF_TOPIC = "/reference/velocity"
TRUTH_TOPIC = "/sim/truth"
FAULT_TOPIC = "/sim/fault"
INS_FRAME = "ins"
REF_FRAME = "reference"
TRUTH_FRAME = "sim"
#: variance written for the quantities the reference does not measure (z, angular rates)
UNMEASURED_VARIANCE = 1e6


def reference_covariance(sigma_ref: float) -> np.ndarray:
    """The 6x6 row-major covariance of the reference twist: R on the x and y diagonal."""
    cov = np.zeros(36)
    cov[0] = cov[7] = sigma_ref**2
    cov[14] = cov[21] = cov[28] = cov[35] = UNMEASURED_VARIANCE
    return cov


def write_bag(flight: SimulatedFlight, path: str, storage: str = "mcap",
              compression: str = "zstd", overwrite: bool = False) -> dict[str, int]:
    """Write a simulated flight as a rosbag2 bag; returns the message count per topic.

    /ins/velocity       geometry_msgs/TwistStamped (linear x, y = V_INS; z and angular 0)
    /reference/velocity geometry_msgs/TwistWithCovarianceStamped (R on the x/y diagonal)
    /sim/truth          flight_fdi_msgs/FilterState, one per axis and truth tick: the true
                        error state x (p, z, r, h empty)
    /sim/fault          std_msgs/String, once, transient local: ``SimulatedFlight.description``
    Receive time = header stamp.
    """
    from flight_fdi.bagio import cdr
    from flight_fdi.bagio.typestore import get_typestore
    from flight_fdi.bagio.writer import open_writer

    N = flight.t.size
    twist = np.zeros((N, 6))
    twist[:, :2] = flight.v_ins
    ins_payloads = cdr.encode(cdr.TWIST_STAMPED, flight.stamp_ns, INS_FRAME, twist)
    M = flight.ref_index.size
    twist_ref = np.zeros((M, 6))
    twist_ref[:, :2] = flight.v_ref
    ref_payloads = cdr.encode(cdr.TWIST_COV_STAMPED, flight.stamp_ref_ns, REF_FRAME, twist_ref,
                              reference_covariance(flight.sigma_ref))

    store = get_typestore()
    FilterState = store.types[FILTER_STATE]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    String = store.types["std_msgs/msg/String"]
    empty = np.zeros(0)
    names = list(flight.model.state_names)
    truth_dt = 1.0 / flight.config.truth_rate_hz
    truth_t, truth_payloads = [], []
    for j, k in enumerate(flight.truth_index.tolist()):
        sec, nsec = divmod(int(flight.stamp_ns[k]), _NS)
        header = Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=TRUTH_FRAME)
        for a, axis in enumerate(AXES):
            msg = FilterState(header=header, channel=axis, state_names=names,
                              x=np.ascontiguousarray(flight.x_true[a, k]), p=empty, z=empty,
                              r=empty, h=empty, u=empty, dt=0.0 if j == 0 else truth_dt,
                              fused=False, gated=False, reset=False)
            truth_payloads.append(bytes(store.serialize_cdr(msg, FILTER_STATE)))
            truth_t.append(int(flight.stamp_ns[k]))
    doc = json.dumps(flight.description(), sort_keys=True)
    fault_payload = bytes(store.serialize_cdr(String(data=doc), "std_msgs/msg/String"))

    with open_writer(path, storage=storage, compression=compression, overwrite=overwrite) as bag:
        bag.add_topic(FAULT_TOPIC, "std_msgs/msg/String", qos="transient_local")
        bag.set_metadata("flight_fdi.sim", doc)
        bag.write_series([
            (FAULT_TOPIC, "std_msgs/msg/String", np.array([flight.stamp_ns[0]]), [fault_payload]),
            (TRUTH_TOPIC, FILTER_STATE, np.array(truth_t, dtype=np.int64),
             truth_payloads),
            (REF_TOPIC, cdr.TWIST_COV_STAMPED, flight.stamp_ref_ns, ref_payloads),
            (INS_TOPIC, cdr.TWIST_STAMPED, flight.stamp_ns, ins_payloads),
        ])
        counts = dict(bag.counts)
    return counts


def simulate_to_bag(config: SimConfig, path: str, storage: str = "mcap",
                    compression: str = "zstd", overwrite: bool = False
                    ) -> tuple[SimulatedFlight, dict[str, int]]:
    """``simulate`` then ``write_bag``."""
    flight = simulate(config)
    return flight, write_bag(flight, path, storage, compression, overwrite)


def faults_on(flight: SimulatedFlight, axis: str) -> Sequence[FaultSpec]:
    """The faults injected on one axis."""
    return [f for f in flight.config.faults if (f.axis or flight.config.channel) == axis]
