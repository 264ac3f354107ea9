"""Attitude-axis scenario (seed 003): three axes under on/off thruster control, with an
actuator fault, written as a bag with the measurement and control-input topics.

Truth, per axis j (x, y, z independent), with the model of
:func:`flight_fdi.core.actuator.attitude_model` discretized exactly for the sample interval::

    s[k+1] = Phi s[k] + Bd u[k+1] + w[k],   s = (angle, rate, disturbance),  w ~ N(0, Qd)

* the disturbance starts at the axis' constant environmental torque per unit inertia
  (N(0, env_torque^2), e.g. gravity gradient and solar pressure) and wanders with the model's
  random walk;
* the control u in {-1, 0, +1} (thruster pair off / on) comes from a phase-plane controller with a
  dead band: u = -sign(s) when |s| > deadband, s = angle + tau * rate (on the true state: the
  controller is idealised, it only has to produce a realistic control signal with long coasts
  of zero control). A command is held over one sample interval: u[k+1] acts from t[k] to
  t[k+1];
* the measurements are z = angle (+ rate) with white noise of the model's R.

The actuator fault (:class:`ActuatorFault`) is a **thruster leak**: from ``start_s`` on, a valve
of the axis' thruster pair does not close completely and produces a constant torque per unit
inertia ``magnitude`` (rad/s^2) *also while the thruster is commanded off*. The controller fights
it (it fires more often on one side), so the attitude stays in its dead band and the fault is not
visible in the angle; but in every coast (u = 0) the filter, which knows u = 0, explains the leak
as disturbance torque: the mean of the estimated disturbance departs from the environment's
~1e-6 rad/s^2 to the leak's value, which is what the monitor of seed 003 tests. (A loss of
thruster efficiency would change the torque only while the thruster fires, and is by design
invisible to the zero-control rule.)

Bag topics (stamps = receive times, ``EPOCH_S`` + t)::

    /attitude/angle    geometry_msgs/Vector3Stamped  measured angle per axis (x, y, z), rad
    /attitude/rate     geometry_msgs/Vector3Stamped  measured rate (only with measure angle+rate)
    /attitude/control  geometry_msgs/Vector3Stamped  commanded u per axis (-1, 0, +1), stamped
                       when commanded (t[k]) and held until the next message
    /sim/truth         flight_fdi_msgs/FilterState   true (angle, rate, disturbance) per axis
                       (channel x / y / z) at every sample
    /sim/fault         std_msgs/String               JSON description (transient local)

:func:`read_attitude_bag` reads one axis back: the measurement z[k] at t[k] and the control
u[k] applied over (t[k-1], t[k]] -- the last control message stamped before t[k].
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np

from flight_fdi.core.actuator import MEASUREMENTS, attitude_model, require_observable
from flight_fdi.core.errors import CoreError
from flight_fdi.core.models import LinearModel

from .errors import SimError
from .ins import EPOCH_S, psd_sqrt

AXES = ("x", "y", "z")
FORMAT = "flight_fdi.sim.attitude/1"
ANGLE_TOPIC = "/attitude/angle"
RATE_TOPIC = "/attitude/rate"
CONTROL_TOPIC = "/attitude/control"
TRUTH_TOPIC = "/sim/truth"
FAULT_TOPIC = "/sim/fault"
VECTOR3 = "geometry_msgs/msg/Vector3Stamped"
FILTER_STATE = "flight_fdi_msgs/msg/FilterState"
STRING = "std_msgs/msg/String"
_NS = 1_000_000_000


@dataclass(frozen=True)
class ActuatorFault:
    """A thruster leak on one axis: a constant torque per unit inertia ``magnitude`` (rad/s^2)
    from ``start_s`` on, also while the thruster is commanded off."""

    start_s: float
    magnitude: float
    axis: str = "x"
    type: str = "leak"

    def __post_init__(self) -> None:
        if self.type != "leak":
            raise SimError(f"actuator fault type must be 'leak', got {self.type!r}")
        if self.axis not in AXES:
            raise SimError(f"actuator fault axis must be one of {', '.join(AXES)}, "
                           f"got {self.axis!r}")
        if not math.isfinite(self.start_s) or self.start_s < 0:
            raise SimError(f"actuator fault: start must be a time >= 0 s, got {self.start_s!r}")
        if not math.isfinite(self.magnitude) or self.magnitude == 0:
            raise SimError(f"actuator fault: magnitude must be a non-zero torque per unit "
                           f"inertia (rad/s^2), got {self.magnitude!r}")


def parse_actuator_fault(text: str) -> ActuatorFault:
    """``leak:t=600,mag=5e-5[,axis=x]`` -> ActuatorFault."""
    what = f"--fault {text!r}"
    kind, _, rest = text.strip().partition(":")
    if kind.strip().lower() != "leak":
        raise SimError(f"{what}: expected leak:t=...,mag=...[,axis=x|y|z]")
    values: dict[str, str] = {}
    for item in filter(None, (s.strip() for s in rest.split(","))):
        key, eq, val = item.partition("=")
        if not eq or key.strip() not in ("t", "mag", "axis"):
            raise SimError(f"{what}: {item!r} is not one of t=..., mag=..., axis=...")
        values[key.strip()] = val.strip()
    if "t" not in values or "mag" not in values:
        raise SimError(f"{what}: t=... and mag=... are required")
    try:
        start, mag = float(values["t"]), float(values["mag"])
    except ValueError:
        raise SimError(f"{what}: t and mag must be numbers") from None
    return ActuatorFault(start_s=start, magnitude=mag, axis=values.get("axis", "x"))


@dataclass(frozen=True)
class AttitudeSimConfig:
    """What to simulate (times in s, torques per unit inertia in rad/s^2)."""

    duration_s: float = 1200.0
    rate_hz: float = 10.0
    seed: int = 0
    measure: str = "angle"           # angle | angle+rate (rate only is refused: unobservable)
    fault: ActuatorFault | None = None
    m_c: float = 1e-3                # control torque per unit inertia of one thruster pair
    env_torque: float = 1e-6         # std of the constant environmental torque per axis
    sigma_md_walk: float = 3e-8      # random walk of the disturbance, rad/s^2/sqrt(s)
    sigma_angle: float = 1e-4        # rad
    sigma_rate: float = 1e-5         # rad/s (used with measure angle+rate)
    deadband: float = 5e-3           # rad, controller dead band on s = angle + tau rate
    tau: float = 10.0                # s, slope of the controller's switching line
    min_on_s: float = 0.5            # s, minimum on-time of a thruster firing
    epoch_s: int = EPOCH_S
    model_params: dict = field(default_factory=dict)  # further attitude_axis overrides

    def __post_init__(self) -> None:
        for name in ("duration_s", "rate_hz", "m_c", "sigma_md_walk", "sigma_angle",
                     "sigma_rate", "deadband", "tau", "min_on_s"):
            val = getattr(self, name)
            if isinstance(val, bool) or not isinstance(val, (int, float)) \
                    or not math.isfinite(val) or val <= 0:
                raise SimError(f"{name.replace('_', ' ')} must be a positive number, got {val!r}")
        if not isinstance(self.env_torque, (int, float)) or not math.isfinite(self.env_torque) \
                or self.env_torque < 0:
            raise SimError(f"env torque must be a number >= 0, got {self.env_torque!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) \
                or self.seed < 0:
            raise SimError(f"seed must be an integer >= 0, got {self.seed!r}")
        if self.measure not in MEASUREMENTS:
            raise SimError(f"measure must be one of {', '.join(MEASUREMENTS)}, "
                           f"got {self.measure!r}")
        if self.n < 2:
            raise SimError("the flight must hold at least two samples")
        if self.fault is not None:
            if not isinstance(self.fault, ActuatorFault):
                raise SimError("fault must be an ActuatorFault")
            if self.fault.start_s >= self.duration_s:
                raise SimError(f"actuator fault starts at {self.fault.start_s:g} s, after the end "
                               f"of the {self.duration_s:g}-s flight")

    @property
    def n(self) -> int:
        return int(round(self.duration_s * self.rate_hz))

    def model(self) -> LinearModel:
        """The filter's (and the truth's) model; CoreError when the configuration is refused."""
        params = {"m_c": self.m_c, "sigma_md_walk": self.sigma_md_walk,
                  "sigma_angle": self.sigma_angle, **self.model_params}
        if self.measure != "angle":
            params["sigma_rate"] = self.sigma_rate
        try:
            return attitude_model(self.measure, **params)
        except TypeError as exc:
            raise SimError(f"model parameters: {exc}") from None


@dataclass
class AttitudeFlight:
    """A simulated attitude flight (axis order x, y, z; times in s from the start)."""

    config: AttitudeSimConfig
    model: LinearModel
    t: np.ndarray           # (N,)
    x_true: np.ndarray      # (3, N, 3) true (angle, rate, disturbance) per axis
    u: np.ndarray           # (N, 3) control applied over (t[k-1], t[k]] (u[0] = 0)
    z: np.ndarray           # (N, 3, m) measurements per axis
    leak: np.ndarray        # (N, 3) leak torque per axis (the fault), rad/s^2

    @property
    def stamp_ns(self) -> np.ndarray:
        return self.config.epoch_s * _NS + np.round(self.t * _NS).astype(np.int64)

    def axis_data(self, axis: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(t, z (N, m), u (N, 1)) of one axis, as the filter takes them."""
        a = _axis_index(axis)
        return self.t, self.z[:, a, :], self.u[:, a:a + 1]

    def description(self) -> dict:
        c = self.config
        d = {k: v for k, v in asdict(c).items() if k != "fault"}
        d["format"] = FORMAT
        d["fault"] = None if c.fault is None else asdict(c.fault)
        d["model"] = {"name": self.model.name, "params": dict(self.model.params)}
        d["topics"] = {"angle": ANGLE_TOPIC, "control": CONTROL_TOPIC,
                       "rate": RATE_TOPIC if c.measure == "angle+rate" else None}
        return d


def _axis_index(axis: str) -> int:
    if axis not in AXES:
        raise SimError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
    return AXES.index(axis)


def simulate_attitude(config: AttitudeSimConfig) -> AttitudeFlight:
    """Run one seeded attitude flight (no I/O)."""
    c = config
    try:
        model = c.model()
        require_observable(model, c.duration_s)
    except CoreError as exc:
        raise SimError(str(exc)) from None
    N = c.n
    dt = 1.0 / c.rate_hz
    t = np.arange(N) * dt
    Phi, Qd, Bd = model.discretize(dt)
    Bd = np.asarray(Bd)[:, 0]
    Lq = psd_sqrt(Qd, model.scale)
    L0 = psd_sqrt(model.P0[:2, :2], model.scale[:2])
    rngs = [np.random.default_rng(s) for s in np.random.SeedSequence(c.seed).spawn(len(AXES) + 1)]
    rng_meas = rngs[-1]
    x_true = np.empty((len(AXES), N, 3))
    u = np.zeros((N, len(AXES)))
    leak = np.zeros((N, len(AXES)))
    if c.fault is not None:
        k0 = int(math.ceil(c.fault.start_s * c.rate_hz - 1e-9))
        leak[k0:, _axis_index(c.fault.axis)] = c.fault.magnitude
    Phi_l = Phi.tolist()
    on_steps = max(1, int(round(c.min_on_s * c.rate_hz)))
    for a in range(len(AXES)):
        rng = rngs[a]
        s = np.empty(3)
        s[:2] = L0 @ rng.standard_normal(2)
        s[2] = c.env_torque * rng.standard_normal()
        w = rng.standard_normal((N, 3)) @ Lq.T
        x = s.tolist()
        cmd = 0.0
        hold = 0
        for k in range(N):
            if k:
                x = [Phi_l[i][0] * x[0] + Phi_l[i][1] * x[1] + Phi_l[i][2] * x[2]
                     + Bd[i] * cmd + w[k - 1, i] for i in range(3)]
                u[k, a] = cmd
            # the leak enters as disturbance torque (the truth's disturbance state is the total
            # torque the filter should estimate) from its onset sample on
            x[2] += leak[k, a] - (leak[k - 1, a] if k else 0.0)
            x_true[a, k] = x
            if hold:
                hold -= 1  # a firing lasts at least the minimum on-time
            else:
                sw = x[0] + c.tau * x[1]
                cmd = -1.0 if sw > c.deadband else (1.0 if sw < -c.deadband else 0.0)
                hold = on_steps - 1 if cmd else 0
    m = model.m
    noise = rng_meas.standard_normal((N, len(AXES), m)) * np.sqrt(np.diag(model.R))
    z = np.einsum("mi,ani->nam", model.H, x_true) + noise
    return AttitudeFlight(config=c, model=model, t=t, x_true=x_true, u=u, z=z, leak=leak)


# --------------------------------------------------------------------------- bag output / input

def write_attitude_bag(flight: AttitudeFlight, path: str | Path, storage: str = "mcap",
                       compression: str = "zstd", overwrite: bool = False) -> dict[str, int]:
    """Write an attitude flight as a rosbag2 bag (topics in the module docstring)."""
    from flight_fdi.bagio.typestore import get_typestore
    from flight_fdi.bagio.writer import open_writer

    store = get_typestore()
    V3S = store.types[VECTOR3]
    V3 = store.types["geometry_msgs/msg/Vector3"]
    Header = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    FilterState = store.types[FILTER_STATE]
    String = store.types[STRING]
    stamps = flight.stamp_ns
    N = stamps.size

    def header(k: int, frame: str):
        sec, nsec = divmod(int(stamps[k]), _NS)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id=frame)

    def vec_series(values: np.ndarray, frame: str, index: range) -> list[bytes]:
        return [bytes(store.serialize_cdr(
            V3S(header=header(k, frame), vector=V3(x=float(v[0]), y=float(v[1]), z=float(v[2]))),
            VECTOR3)) for k, v in zip(index, values)]

    angle = flight.z[:, :, 0]
    series = []
    doc = json.dumps(flight.description(), sort_keys=True)
    fault_payload = bytes(store.serialize_cdr(String(data=doc), STRING))
    series.append((FAULT_TOPIC, STRING, stamps[:1], [fault_payload]))
    names = list(flight.model.state_names)
    empty = np.zeros(0)
    dt = 1.0 / flight.config.rate_hz
    truth = []
    truth_t = []
    for k in range(N):
        for a, axis in enumerate(AXES):
            msg = FilterState(header=header(k, "sim"), channel=axis, state_names=names,
                              x=np.ascontiguousarray(flight.x_true[a, k]), p=empty, z=empty,
                              r=empty, h=empty, u=empty, dt=0.0 if k == 0 else dt, fused=False,
                              gated=False, reset=False)
            truth.append(bytes(store.serialize_cdr(msg, FILTER_STATE)))
            truth_t.append(int(stamps[k]))
    series.append((TRUTH_TOPIC, FILTER_STATE, np.array(truth_t, dtype=np.int64), truth))
    # the command held over (t[k], t[k+1]] is u[k+1]; it is published at t[k]
    series.append((CONTROL_TOPIC, VECTOR3, stamps[:-1],
                   vec_series(flight.u[1:], "control", range(N - 1))))
    series.append((ANGLE_TOPIC, VECTOR3, stamps, vec_series(angle, "attitude", range(N))))
    if flight.model.m == 2:
        series.append((RATE_TOPIC, VECTOR3, stamps,
                       vec_series(flight.z[:, :, 1], "attitude", range(N))))
    with open_writer(path, storage=storage, compression=compression, overwrite=overwrite) as bag:
        bag.add_topic(FAULT_TOPIC, STRING, qos="transient_local")
        bag.set_metadata("flight_fdi.sim.attitude", doc)
        bag.write_series(series)
        counts = dict(bag.counts)
    return counts


@dataclass
class AttitudeData:
    """One axis read from an attitude bag (times in s since the first angle message)."""

    path: str
    axis: str
    t: np.ndarray               # (N,) measurement times
    z: np.ndarray               # (N, m) angle (and rate)
    u: np.ndarray               # (N, 1) control applied over (t[k-1], t[k]]
    measure: str                # angle | angle+rate
    t0_ns: int
    description: dict | None = None
    t_truth: np.ndarray | None = None
    x_truth: np.ndarray | None = None


def read_attitude_bag(path: str | Path, axis: str = "x") -> AttitudeData:
    """Read one axis of an attitude bag (see the module docstring for the topics)."""
    from flight_fdi.bagio.errors import BagError
    from flight_fdi.bagio.reader import bag_topics, read_messages

    a = _axis_index(axis)
    topics = bag_topics(path)
    for topic in (ANGLE_TOPIC, CONTROL_TOPIC):
        if topics.get(topic) != VECTOR3:
            raise BagError(f"bag '{path}': no {VECTOR3} messages on {topic} (topics: "
                           f"{', '.join(sorted(topics)) or 'none'})")
    wanted = [ANGLE_TOPIC, CONTROL_TOPIC]
    has_rate = topics.get(RATE_TOPIC) == VECTOR3
    if has_rate:
        wanted.append(RATE_TOPIC)
    for extra, msgtype in ((TRUTH_TOPIC, FILTER_STATE), (FAULT_TOPIC, STRING)):
        if topics.get(extra) == msgtype:
            wanted.append(extra)
    series: dict[str, tuple[list[int], list[float]]] = {t: ([], []) for t in wanted}
    truth_t: list[int] = []
    truth_x: list[np.ndarray] = []
    description = None
    for topic, _, _, msg in read_messages(path, topics=wanted):
        if topic == FAULT_TOPIC:
            try:
                description = json.loads(msg.data)
            except ValueError:
                raise BagError(f"bag '{path}': {FAULT_TOPIC} is not JSON") from None
            continue
        stamp = msg.header.stamp.sec * _NS + msg.header.stamp.nanosec
        if topic == TRUTH_TOPIC:
            if msg.channel == axis:
                truth_t.append(stamp)
                truth_x.append(np.asarray(msg.x, dtype=float))
            continue
        v = msg.vector
        series[topic][0].append(stamp)
        series[topic][1].append((v.x, v.y, v.z)[a])
    ts, zs = (np.asarray(s) for s in series[ANGLE_TOPIC])
    if ts.size < 2:
        raise BagError(f"bag '{path}': fewer than two messages on {ANGLE_TOPIC}")
    if np.any(np.diff(ts) <= 0):
        raise BagError(f"bag '{path}': {ANGLE_TOPIC} stamps do not increase")
    columns = [zs]
    if has_rate:
        tr, zr = (np.asarray(s) for s in series[RATE_TOPIC])
        if not np.array_equal(tr, ts):
            raise BagError(f"bag '{path}': {RATE_TOPIC} and {ANGLE_TOPIC} have different stamps")
        columns.append(zr)
    tc, uc = (np.asarray(s) for s in series[CONTROL_TOPIC])
    order = np.argsort(tc, kind="stable")
    tc, uc = tc[order], uc[order]
    # u[k]: the last command stamped before t[k] (0 before the first command)
    j = np.searchsorted(tc, ts, side="left") - 1
    u = np.where(j >= 0, uc[np.maximum(j, 0)], 0.0)
    t0 = int(ts[0])
    data = AttitudeData(path=str(path), axis=axis, t=(ts - t0) * 1e-9,
                        z=np.column_stack(columns), u=u.reshape(-1, 1),
                        measure="angle+rate" if has_rate else "angle", t0_ns=t0,
                        description=description)
    if truth_t:
        data.t_truth = (np.asarray(truth_t) - t0) * 1e-9
        data.x_truth = np.vstack(truth_x)
    return data
