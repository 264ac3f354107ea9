"""filter_node in the attitude mode (seed 003), in-process on sim time.

Seeded attitude flights from ``flight_fdi.sim.attitude`` (one with a thruster leak on x) are
published from a driver node as the simulator's bag holds them (/attitude/angle, /attitude/rate,
/attitude/control), each chunk with its angles before its commands, so that the node has to wait
for the command of each interval. Expected values come from the offline path on the same data:
the batch ``run_attitude`` (``run_forward`` with u + ``monitor_record``), run over the stamps
as the node reads them and the commands as ``read_attitude_bag`` assigns them (the last one
stamped before each sample).
"""
from __future__ import annotations

import json
import math

import numpy as np
import pytest

from flight_fdi.core.actuator import ActuatorConfig, run_attitude
from flight_fdi.nodes import convert
from flight_fdi.nodes import diagnostics as diag
from flight_fdi.nodes.errors import ParameterError
from flight_fdi.sim.attitude import ActuatorFault, AttitudeSimConfig, simulate_attitude

# samples per chunk: published between two spins. A chunk spans less than attitude_wait_s
# (0.5 s) of stamps, so that however DDS delivers the topics of one chunk, no sample stops
# waiting for its command before it arrives
CHUNK = 4
NODE = "filter_node"
LEAK = ActuatorFault(start_s=30.0, magnitude=5e-5, axis="x")


# ------------------------------------------------------------------------------ the rig

def _stamp(ns: int):
    from builtin_interfaces.msg import Time

    return Time(sec=int(ns) // 1_000_000_000, nanosec=int(ns) % 1_000_000_000)


def _vec(ns: int, v) -> object:
    from geometry_msgs.msg import Vector3Stamped

    msg = Vector3Stamped()
    msg.header.stamp = _stamp(ns)
    msg.vector.x, msg.vector.y, msg.vector.z = (float(c) for c in v)
    return msg


def _t(ns) -> np.ndarray:
    """Stamps as the node reads them (sec + nanosec * 1e-9)."""
    return np.array([convert.stamp_to_s(_stamp(n)) for n in np.atleast_1d(ns)])


class Rig:
    """The node in attitude mode, and a driver owning sim time, the inputs and collectors."""

    def __init__(self, ros, **params):
        from diagnostic_msgs.msg import DiagnosticArray
        from flight_fdi_msgs.msg import FilterState, Innovation, ModelInfo
        from geometry_msgs.msg import Vector3Stamped
        from harness import collect
        from rcl_interfaces.msg import Log
        from rosgraph_msgs.msg import Clock

        from flight_fdi.nodes.filter_node import FilterNode

        self.ros = ros
        self.clock_s = 1.0
        self.drv = ros.node("attitude_test_driver")
        self.pub_clock = self.drv.create_publisher(Clock, "/clock", 10)
        self.pub_clock.publish(Clock(clock=convert.s_to_stamp(self.clock_s)))
        params = {"model": "attitude_axis", "use_sim_time": True, "diagnostics_period_s": 0.25,
                  **params}
        self.node = ros.node(FilterNode, parameters=params)
        load_kernels(self.node.model)
        self.pub = {k: self.drv.create_publisher(Vector3Stamped, f"/attitude/{k}", 100)
                    for k in ("angle", "rate", "control")}
        self.innov = collect(ros, self.drv, Innovation, "fdi/innovation", 1000)
        self.states = collect(ros, self.drv, FilterState, "fdi/state", 1000)
        self.models = collect(ros, self.drv, ModelInfo, "fdi/model", _latched())
        self.events = collect(ros, self.drv, _string(), "fdi/actuator_event", _latched())
        self.diags = collect(ros, self.drv, DiagnosticArray, "/diagnostics", 100)
        self.logs = collect(ros, self.drv, Log, "/rosout", 1000)
        used = ["angle", "control"] + (["rate"] if self.node.model.m == 2 else [])
        ros.wait_for_subscribers([self.pub_clock] + [self.pub[k] for k in used])
        ros.wait_for_subscribers([self.node.pub_innovation, self.node.pub_state,
                                  self.node.diagnostics.publisher])
        self.sent = {"angle": 0, "rate": 0, "control": 0}
        self.advance(0.0)

    def advance(self, seconds: float):
        from rosgraph_msgs.msg import Clock

        self.clock_s += seconds
        self.pub_clock.publish(Clock(clock=convert.s_to_stamp(self.clock_s)))
        target = int(round(self.clock_s * 1e9))
        self.ros.spin_until(lambda: self.node.get_clock().now().nanoseconds >= target,
                            what="node clock")

    def send(self, topic: str, ns: int, v):
        self.pub[topic].publish(_vec(ns, v))
        self.sent[topic] += 1

    def settle(self):
        c = self.node.counters
        self.ros.spin_until(lambda: all(c[f"received_{k}"] == n for k, n in self.sent.items()
                                        if n), what="inputs received")

    def feed(self, flight, chunk: int = CHUNK):
        """Publish a simulated flight as its bag holds it (the command held over (t[k], t[k+1]]
        is u[k+1], stamped t[k]); per chunk the angles (and rates) first, then the commands."""
        ns = flight.stamp_ns
        N = ns.size
        for k0 in range(0, N, chunk):
            ks = range(k0, min(N, k0 + chunk))
            for k in ks:
                self.send("angle", ns[k], flight.z[k, :, 0])
            if flight.model.m == 2:
                for k in ks:
                    self.send("rate", ns[k], flight.z[k, :, 1])
            for k in ks:
                if k < N - 1:
                    self.send("control", ns[k], flight.u[k + 1])
            self.settle()
            self.advance(chunk / flight.config.rate_hz)

    def channel(self, msgs, name):
        return [m for m in msgs if m.channel == name]

    def next_diagnostics(self, advance_s: float = 0.3) -> dict:
        n = len(self.diags)
        self.advance(advance_s)
        self.ros.spin_until(lambda: len(self.diags) > n, what="diagnostics")
        return {s.name: s for s in self.diags[-1].status}


def load_kernels(model) -> None:
    """Load (or, with a stale numba cache, compile) the filter kernels the node's first step
    runs, here rather than inside that step: the waits of the rig bound DDS delivery and the
    node's work, and a compile there (10-30 s on a loaded machine) outlasted them."""
    from flight_fdi.core.kalman import KalmanFilter

    kf = KalmanFilter(model)
    u = None if model.B is None else [0.0]
    kf.step(0.0, np.zeros(model.m), model.R, u)     # the first step: an update only
    kf.step(0.1, np.zeros(model.m), model.R, u)
    kf.predict(0.1, u)                               # a step with some rows only
    kf.update(np.zeros(1), model.R[:1, :1], model.H[:1])


def _latched():
    from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

    return QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                      reliability=ReliabilityPolicy.RELIABLE,
                      durability=DurabilityPolicy.TRANSIENT_LOCAL)


def _string():
    from std_msgs.msg import String

    return String


def _values(status) -> dict[str, str]:
    return {kv.key: kv.value for kv in status.values}


def _stamps(msgs) -> np.ndarray:
    return np.array([convert.stamp_to_s(m.header.stamp) for m in msgs])


def _batch(flight, axis: str):
    """The offline path on the data the node received: run_attitude over the node's stamps."""
    t = _t(flight.stamp_ns)
    _, z, u = flight.axis_data(axis)
    return t, run_attitude(flight.model, t, z, u, config=ActuatorConfig(), axis=axis)


# ------------------------------------------------------------------------------ the leak

@pytest.fixture(scope="module")
def leak_flight():
    return simulate_attitude(AttitudeSimConfig(duration_s=90.0, seed=1, fault=LEAK))


def test_thruster_leak_switches_to_reserve(ros, leak_flight):
    flight = leak_flight
    rig = Rig(ros, channels=["y", "x"])
    node = rig.node
    assert node.attitude is not None
    # the node's default attitude parameters are the simulator's spacecraft
    for name in ("A", "B", "Qc", "H", "R", "P0"):
        np.testing.assert_array_equal(getattr(node.model, name), getattr(flight.model, name))
    rig.ros.spin_until(lambda: len(rig.models) == 2, what="ModelInfo")
    for m in rig.models:
        assert m.p == 1 and list(m.b) == [0.0, flight.config.m_c, 0.0]
        assert list(m.state_names) == ["angle", "rate", "disturbance"]
    rig.feed(flight)
    N = flight.t.size
    # the last sample's command never comes (the bag has none stamped at or after it): it is
    # processed after attitude_wait_s of node time
    last = _t(flight.stamp_ns[-2:])
    assert all(ch.last_t == last[0] for ch in node.channels)
    assert len(node.attitude._pending) == 1 and node.attitude._pending[0].t == last[1]
    rig.advance(1.0)
    rig.ros.spin_until(lambda: len(rig.states) == 2 * N, what="every sample processed")
    assert len(rig.innov) == 2 * N

    for axis in ("x", "y"):
        t, (fwd, mon) = _batch(flight, axis)
        st = rig.channel(rig.states, axis)
        np.testing.assert_array_equal(_stamps(st), t)
        # FilterState carries the command of each interval (u = 0 at the first step, dt = 0)
        u = np.array([list(m.u) for m in st])
        assert u.shape == (N, 1)
        np.testing.assert_array_equal(u, fwd.u)
        assert st[0].dt == 0.0 and st[0].reset and not st[1].reset
        assert st[1].dt == pytest.approx(0.1, abs=1e-6)
        assert np.count_nonzero(u) > 10 and set(np.unique(u)) <= {-1.0, 0.0, 1.0}  # firings
        x = np.array([list(m.x) for m in st])
        P = np.array([list(m.p) for m in st]).reshape(N, 3, 3)
        sc = flight.model.scale  # compare in units of each state's typical std
        np.testing.assert_allclose(x / sc, fwd.x / sc, rtol=1e-7, atol=1e-9)
        np.testing.assert_allclose(P, fwd.P, rtol=1e-7, atol=0.0)
        assert [list(m.h) for m in st[:1]] == [[1.0, 0.0, 0.0]]
        inn = rig.channel(rig.innov, axis)
        assert list(inn[0].row_names) == ["/attitude/angle"]
        np.testing.assert_allclose([m.innovation[0] for m in inn], fwd.nu[:, 0],
                                   rtol=1e-6, atol=1e-12)

    # the event: on x only, after the leak began, as the offline monitor decides it
    t, (fwd, mon) = _batch(flight, "x")
    (expected,) = mon.events
    assert not _batch(flight, "y")[1][1].fault
    t0 = t[0]
    assert len(rig.events) == 1, [m.data for m in rig.events]
    ev = json.loads(rig.events[0].data)
    assert ev["axis"] == "x" and ev["action"] == "switch_to_reserve"
    assert ev["node"] == f"/{NODE}" and "switch to reserve" in ev["message"]
    assert ev["t"] - t0 > LEAK.start_s and ev["window_start_t"] - t0 >= LEAK.start_s
    # the same samples, hence the same deciding window to the sample
    assert ev["t"] == expected.t and ev["window_start_t"] == expected.window_start_t
    assert ev["mean"] == pytest.approx(expected.mean, rel=1e-6)
    assert abs(ev["mean"]) > ev["threshold"] == ActuatorConfig().threshold
    assert ev["samples"] == expected.samples
    # a zero-control window of the actuator_window_s
    k = (t >= ev["window_start_t"]) & (t <= ev["t"])
    assert np.all(flight.u[k, 0] == 0.0) and ev["t"] - ev["window_start_t"] >= 5.0 - 1e-6
    assert any(m.level == 40 and "switch to reserve" in m.msg for m in rig.logs)

    # /diagnostics: ERROR for the actuator of x (latched), OK for y
    st = rig.next_diagnostics()
    act = st[f"{NODE}: actuator x"]
    assert act.level == diag.ERROR and "switch to reserve" in act.message
    vals = _values(act)
    assert vals["action"] == "switch_to_reserve"
    assert float(vals["event_t_s"]) == pytest.approx(ev["t"], abs=1e-3)
    assert float(vals["event_mean"]) == pytest.approx(ev["mean"], rel=1e-5)
    assert float(vals["threshold"]) == ev["threshold"]
    assert st[f"{NODE}: actuator y"].level == diag.OK
    vy = _values(st[f"{NODE}: actuator y"])
    assert vy["action"] == "none" and int(vy["windows_evaluated"]) > 5
    assert abs(float(vy["last_window_mean"])) < ActuatorConfig().threshold
    assert st[f"{NODE}: channel x"].level == diag.OK
    assert _values(st[f"{NODE}: channel x"])["u"] in ("-1", "0", "1")
    inputs = st[f"{NODE}: inputs"]
    iv = _values(inputs)
    assert iv["received_angle"] == str(N) and iv["received_control"] == str(N - 1)
    assert iv["control_changed_within_interval"] == "0"

    # a late subscriber still gets the event (transient local)
    late = ros.node("late_listener")
    got = []
    late.create_subscription(_string(), "fdi/actuator_event", got.append, _latched())
    ros.spin_until(lambda: len(got) >= 1, what="latched actuator event")
    assert json.loads(got[0].data) == ev

    # ~/reset_actuator re-arms the monitor: the status returns to OK
    from std_srvs.srv import Trigger

    cli = rig.drv.create_client(Trigger, f"/{NODE}/reset_actuator")
    ros.spin_until(lambda: cli.service_is_ready(), what="reset service")
    fut = cli.call_async(Trigger.Request())
    ros.spin_until(fut, what="reset_actuator")
    assert fut.result().success and "x" in fut.result().message
    ros.spin_until(lambda: len(rig.events) == 2, what="reset record")
    assert json.loads(rig.events[1].data)["action"] == "reset"
    st = rig.next_diagnostics()
    assert st[f"{NODE}: actuator x"].level == diag.OK


# ------------------------------------------------------------------------------ nominal

def test_nominal_flight_with_rate_gives_no_event(ros):
    flight = simulate_attitude(AttitudeSimConfig(duration_s=50.0, seed=7, measure="angle+rate"))
    rig = Rig(ros, channels=["x", "y", "z"], attitude_measure="angle+rate")
    assert rig.node.model.m == 2
    rig.feed(flight)
    N = flight.t.size
    rig.advance(1.0)
    rig.ros.spin_until(lambda: len(rig.states) == 3 * N, what="every sample processed")
    for axis in ("x", "y", "z"):
        t, (fwd, mon) = _batch(flight, axis)
        assert not mon.fault
        st = rig.channel(rig.states, axis)
        x = np.array([list(m.x) for m in st])
        sc = flight.model.scale
        np.testing.assert_allclose(x / sc, fwd.x / sc, rtol=1e-6, atol=1e-9)
        assert all(list(m.h) == [1.0, 0.0, 0.0, 0.0, 1.0, 0.0] for m in st)
        inn = rig.channel(rig.innov, axis)
        assert all(list(m.row_names) == ["/attitude/angle", "/attitude/rate"] for m in inn)
        np.testing.assert_array_equal(np.array([list(m.u) for m in st]), fwd.u)
    st = rig.next_diagnostics()
    assert rig.events == []
    for axis in ("x", "y", "z"):
        assert st[f"{NODE}: actuator {axis}"].level == diag.OK
        assert int(_values(st[f"{NODE}: actuator {axis}"])["windows_evaluated"]) > 0
    assert _values(st[f"{NODE}: inputs"])["rate_missing"] == "0"


# ------------------------------------------------------------------------------ bad input

def test_bad_input_is_counted_and_commands_are_waited_for(ros):
    """Hand-made 10-Hz data (zero angles; zero commands except where noted), published in
    steps so that the outcome does not depend on the delivery order of the topics."""
    rig = Rig(ros, channels=["x", "y"], attitude_wait_s=0.45)
    ns0 = 1_700_000_000 * 10**9
    ns = [ns0 + k * 100_000_000 for k in range(26)]
    zero = (0.0, 0.0, 0.0)
    # angles 0, 1 come before any command: they wait, then are dropped (no command is assumed)
    rig.send("angle", ns[0], zero)
    rig.send("angle", ns[1], zero)
    rig.settle()
    assert rig.states == []
    for k in range(2, 11):
        rig.send("control", ns[k], zero)
        if k == 3:
            rig.send("control", ns[3] + 1, (math.nan, 0.0, 0.0))  # NaN command: ignored
    rig.send("control", ns[10] + 50_000_000, (1.0, -1.0, 0.0))  # fires inside (t10, t11]
    rig.send("control", ns[11], zero)
    rig.settle()
    for k in range(2, 12):
        rig.send("angle", ns[k], (math.nan, 1e-4, 0.0) if k == 5 else zero)  # NaN on x only
        if k == 7:
            rig.send("angle", ns[7], zero)                     # duplicate stamp
    rig.send("angle", ns[6] + 1, zero)                         # out of order
    rig.settle()
    rig.send("control", ns[11], zero)                          # duplicate command stamp
    rig.send("control", ns[12], (0.0, 1.0, 0.0))               # the last command
    rig.settle()
    for k in range(12, 26):
        rig.send("angle", ns[k], zero)
    rig.settle()
    c = rig.node.counters
    assert c["dropped_no_control"] == 2
    assert c["dropped_control_nonfinite"] == 1
    assert c["dropped_angle_duplicate"] == 1 and c["dropped_angle_out_of_order"] == 1
    assert c["dropped_control_duplicate"] == 1
    assert c["control_changed_within_interval"] == 1
    chx, chy = rig.node.channels
    assert chx.counters["dropped_angle_nonfinite"] == 1 and chy.counters.total() == 0
    # samples up to t[12] went when the commands reached them; 13 .. 20 when an angle more than
    # attitude_wait_s newer came; 21 .. 25 wait for node time
    assert chy.last_t == convert.stamp_to_s(_stamp(ns[20]))
    assert [e.t for e in rig.node.attitude._pending] == list(_t(ns[21:]))
    rig.ros.spin_until(lambda: len(rig.channel(rig.states, "y")) == 19, what="states")
    rig.advance(1.0)
    rig.ros.spin_until(lambda: len(rig.channel(rig.states, "y")) == 24, what="timed-out samples")
    x, y = rig.channel(rig.states, "x"), rig.channel(rig.states, "y")
    assert len(x) == 23  # sample 5 dropped on x only
    np.testing.assert_array_equal(_stamps(y), _t(ns[2:]))
    uy = {round(convert.stamp_to_s(m.header.stamp) - ns0 * 1e-9, 1): m.u[0] for m in y}
    ux = {round(convert.stamp_to_s(m.header.stamp) - ns0 * 1e-9, 1): m.u[0] for m in x}
    assert uy[0.2] == 0.0 and y[0].reset and y[0].dt == 0.0  # the first step: dt = 0, u = 0
    assert all(uy[round(0.1 * k, 1)] == 0.0 for k in range(3, 11))
    assert ux[1.1] == 1.0 and uy[1.1] == -1.0       # the command that fired inside (1.0, 1.1]
    assert uy[1.2] == 0.0 and uy[1.3] == 1.0 and uy[2.5] == 1.0  # held after the last command
    st = rig.next_diagnostics()
    vx = _values(st[f"{NODE}: channel x"])
    assert vx["dropped_angle_nonfinite"] == "1" and vx["fused"] == "23"
    vi = _values(st[f"{NODE}: inputs"])
    assert vi["dropped_no_control"] == "2" and vi["waiting_samples"] == "0"


def test_rate_rows_unmatched_rates_and_a_time_jump(ros):
    """angle+rate: a rate before its angle, a missing rate, an unmatched one, a NaN one; then
    the stamps jump back (a bag loop). Each input is settled before the next (deterministic)."""
    rig = Rig(ros, channels=["x"], attitude_measure="angle+rate")
    ns0 = 1_700_000_000 * 10**9
    ns = [ns0 + k * 100_000_000 for k in range(10)]
    zero = (0.0, 0.0, 0.0)

    def send(topic, n, v=zero):
        rig.send(topic, n, v)
        rig.settle()

    for k in range(10):
        rig.send("control", ns[k], zero)
    rig.settle()
    send("rate", ns[0])                       # before its angle: buffered
    send("angle", ns[0])                      # joined: two rows
    send("angle", ns[1])                      # waits for its rate ...
    assert rig.node.channels[0].last_t == _t(ns[0])[0]
    send("rate", ns[2])                       # ... until the rate topic moves past it
    send("angle", ns[2])                      # joins the buffered rate
    send("rate", ns[2] + 50_000_000)          # no angle at t2 + 50 ms
    send("angle", ns[3])                      # -> that rate is unmatched
    send("rate", ns[3], (math.nan, 0.0, 0.0))  # NaN on x: the angle alone
    c = rig.node.counters
    assert c["rate_missing"] == 1 and c["dropped_rate_unmatched"] == 1
    ch = rig.node.channels[0]
    assert ch.counters["dropped_rate_nonfinite"] == 1 and ch.last_t == _t(ns[3])[0]
    # a bag loop: every topic starts again 10 s earlier
    back = ns0 - 10 * 10**9
    send("angle", back)
    assert c["time_jump_resets"] == 1 and ch.counters["resets"] == 1
    send("rate", back)
    send("control", back)                     # the commands' time line is reset too
    rig.ros.spin_until(lambda: len(rig.states) == 5, what="states")
    rows = [len(m.z) for m in rig.states]
    assert rows == [2, 1, 2, 1, 2]
    assert [list(m.row_names) for m in rig.innov[:2]] == [
        ["/attitude/angle", "/attitude/rate"], ["/attitude/angle"]]
    last = rig.states[-1]
    assert last.reset and last.dt == 0.0 and convert.stamp_to_s(last.header.stamp) == _t(back)[0]
    assert c["dropped_time_jump"] == 0 and c["dropped_no_control"] == 0


# ------------------------------------------------------------------------------ parameters

def test_rate_only_is_refused_at_start_up(ros):
    from flight_fdi.nodes.filter_node import FilterNode

    with pytest.raises(ParameterError) as err:
        ros.node(FilterNode, parameters={"model": "attitude_axis", "attitude_measure": "rate"})
    text = str(err.value)
    assert "'attitude_measure'" in text and "'rate'" in text
    assert "not observable" in text and "rank" in text and "= 2 < n = 3" in text
    assert "angle cannot be estimated" in text


@pytest.mark.parametrize("overrides, name", [
    ({"model": "attitude_axis", "tau_a": 100.0}, "tau_a"),
    ({"model": "attitude_axis", "reference_topics": ["/a", "/b"]}, "reference_topics"),
    ({"model": "attitude_axis", "attitude_sigma_rate_urad_s": 5.0}, "attitude_sigma_rate_urad_s"),
    ({"model": "attitude_axis", "control_topic": "/attitude/angle"}, "control_topic"),
    ({"model": "attitude_axis", "channels": ["w"]}, "channels"),
    ({"model": "attitude_axis", "actuator_threshold_urad_s2": 0.0}, "actuator_threshold_urad_s2"),
    ({"actuator_threshold_urad_s2": 20.0}, "actuator_threshold_urad_s2"),
    ({"model": "attitude_axis", "attitude_wait_s": 1}, "attitude_wait_s"),
    ({"angle_topic": "/att"}, "angle_topic"),
])
def test_parameters_of_the_other_mode_and_invalid_ones_are_refused(ros, overrides, name):
    from flight_fdi.nodes.filter_node import FilterNode

    with pytest.raises(ParameterError) as err:
        ros.node(FilterNode, parameters=overrides)
    assert f"'{name}'" in str(err.value), str(err.value)
    assert repr(overrides[name]) in str(err.value)


MODEL_FILE = """\
name: my_axis
states: [{name: angle, unit: rad}, {name: rate, unit: rad/s}, {name: disturbance, unit: rad/s^2}]
A: [[0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0, 0.0, 0.0]]
B: [[0.0], [2.0e-3], [0.0]]
Qc: [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 1.0e-15]]
H: [{h}]
R: [{r}]
P0: [[1.0e-4, 0.0, 0.0], [0.0, 1.0e-6, 0.0], [0.0, 0.0, 1.0e-8]]
"""


def test_a_model_file_with_a_control_input_runs_the_attitude_mode(ros, tmp_path):
    from flight_fdi.nodes.filter_node import FilterNode

    good = tmp_path / "axis.yaml"
    good.write_text(MODEL_FILE.replace("{h}", "[1.0, 0.0, 0.0]").replace("{r}", "[1.0e-8]"))
    node = ros.node(FilterNode, parameters={"model": str(good), "channels": ["z"]})
    assert node.attitude is not None and node.model.name == "my_axis"
    assert node.model.B[1, 0] == 2.0e-3 and node.model.R[0, 0] == 1.0e-8  # its own R
    assert [ch.name for ch in node.channels] == ["z"]
    with pytest.raises(ParameterError, match="'attitude_m_c'.*attitude_axis"):
        ros.node(FilterNode, parameters={"model": str(good), "attitude_m_c": 1.0})
    rate_only = tmp_path / "rate.yaml"
    rate_only.write_text(MODEL_FILE.replace("{h}", "[0.0, 1.0, 0.0]").replace("{r}", "[1.0e-10]"))
    with pytest.raises(ParameterError, match="'model'.*not observable.*angle"):
        ros.node(FilterNode, parameters={"model": str(rate_only)})
