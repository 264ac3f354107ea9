"""filter_node with ``model: ins3d`` in-process: the four contract topics of a short simulated
flight are published from a driver node; the node's innovations and states must equal the
batch 3-D filter (core.ins3d.filter.run_forward) on the batch reader's input of the same
messages; bad messages are counted, never fatal; parameters are validated."""
from __future__ import annotations

import numpy as np
import pytest

from harness import collect

from flight_fdi.core.gate import GateConfig
from flight_fdi.core.ins3d.filter import run_forward
from flight_fdi.core.ins3d.stream import Ins3dAssembler
from flight_fdi.nodes.errors import ParameterError
from flight_fdi.nodes.filter_node import FilterNode
from flight_fdi.nodes.ins3d_mode import build_model

from .streams import batch_input, flight, topic_messages

TOPICS = {"ins_imu": "/ins/imu", "ins_velocity": "/ins/velocity", "ins_fix": "/ins/fix",
          "ref_velocity": "/reference/velocity"}


def _msg(key, ns, vals):
    from builtin_interfaces.msg import Time
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from sensor_msgs.msg import Imu, NavSatFix

    stamp = Time(sec=ns // 10**9, nanosec=ns % 10**9)
    if key == "ins_imu":
        m = Imu()
        q, f, w = vals
        m.orientation.w, m.orientation.x, m.orientation.y, m.orientation.z = map(float, q)
        m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z = map(float, f)
        m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z = map(float, w)
    elif key == "ins_velocity":
        m = TwistStamped()
        m.twist.linear.x, m.twist.linear.y, m.twist.linear.z = map(float, vals[0])
    elif key == "ins_fix":
        m = NavSatFix()
        m.latitude, m.altitude = float(np.degrees(vals[0])), float(vals[1])
    else:
        m = TwistWithCovarianceStamped()
        m.twist.twist.linear.x, m.twist.twist.linear.y, m.twist.twist.linear.z = \
            map(float, vals[0])
        cov = np.zeros(36)
        cov[[0, 7, 14]] = vals[1]
        m.twist.covariance = cov.tolist()
    m.header.stamp = stamp
    return m


def _as_received(msgs):
    """The messages' values as the node reads them back (latitude through degrees)."""
    out = []
    for ns, key, vals in msgs:
        if key == "ins_fix":
            vals = (np.radians(np.array([float(np.degrees(vals[0]))]))[0], float(vals[1]))
        out.append((ns, key, vals))
    return out


def _replay(h, node, driver, msgs, chunk=200):
    """Publish in stamp order, spinning until the node has taken each chunk (no sleeps)."""
    from geometry_msgs.msg import TwistStamped, TwistWithCovarianceStamped
    from sensor_msgs.msg import Imu, NavSatFix

    cls = {"ins_imu": Imu, "ins_velocity": TwistStamped, "ins_fix": NavSatFix,
           "ref_velocity": TwistWithCovarianceStamped}
    pubs = {k: driver.create_publisher(cls[k], TOPICS[k], 10000) for k in TOPICS}
    h.wait_for_subscribers(pubs.values())
    c = node.counters
    for i in range(0, len(msgs), chunk):
        part = msgs[i:i + chunk]
        for ns, key, vals in part:
            pubs[key].publish(_msg(key, ns, vals))
        done = i + len(part)
        h.spin_until(lambda: c["received_ins"] + c["received_reference"] >= done, timeout=30,
                     what="the node took the messages")


@pytest.mark.slow
@pytest.mark.timeout(300)
def test_node_outputs_equal_the_batch_filter(ros):
    from flight_fdi_msgs.msg import FilterState, Innovation, ModelInfo
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

    msgs = _as_received(topic_messages(flight(180.0)))
    node = ros.node(FilterNode, {"model": "ins3d", "input_qos": "reliable",
                                     "input_queue_depth": 5000, "ins3d_end_idle_s": 0.0})
    driver = ros.node("driver")
    states = collect(ros, driver, FilterState, "fdi/state", 100000)
    innov = collect(ros, driver, Innovation, "fdi/innovation", 100000)
    models = collect(ros, driver, ModelInfo, "fdi/model", QoSProfile(
        depth=1, reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL))
    _replay(ros, node, driver, msgs)
    node.ins3d.finish()
    inp = batch_input(msgs)
    n_steps, n_refs = len(inp.steps), inp.refs.t.size
    ros.spin_until(lambda: len(states) >= n_steps + 1 + n_refs and len(innov) >= n_refs
                       and models, timeout=30, what="all outputs")
    model = node.model
    st = inp.steps
    P0 = model.p0_aligned(st.C[0], st.f_n[0], float(st.lat[0]))
    fwd = run_forward(model, st, inp.refs, gate=GateConfig(), P0=P0)
    np.testing.assert_array_equal(np.array([m.innovation for m in innov]), fwd.nu)
    np.testing.assert_array_equal([m.beta2 for m in innov], fwd.beta2)
    np.testing.assert_array_equal([m.alarm_state for m in innov], fwd.alarm)
    assert list(innov[0].row_names) == ["east", "north", "up"]
    # the state after the last update of each boundary is the batch filter's x[k]
    last = {}
    k = -1
    for m in states:
        if m.reset or m.dt > 0:
            k += 1
        last[k] = np.array(m.x)
    np.testing.assert_array_equal(np.array([last[i] for i in range(n_steps + 1)]), fwd.x)
    assert models[0].model_name == "ins3d/navigation" and list(models[0].state_names) == \
        list(model.names)
    assert node.counters["published"] == n_refs
    statuses = {s.name: s for s in node.diagnostic_statuses()}
    assert statuses["filter_node: ins3d"].message == "filtering" or "alarm" in \
        statuses["filter_node: ins3d"].message


def _last_states(states):
    """The state after the last update of each boundary (a reset starts a new record)."""
    last, k = {}, -1
    for m in states:
        if m.reset or m.dt > 0:
            k += 1
        last[k] = np.array(m.x)
    return np.array([last[i] for i in range(k + 1)])


@pytest.mark.timeout(300)
def test_end_of_input_flushes_the_waiting_steps_and_a_new_record_starts(ros):
    """Without finish(): after ins3d_end_idle_s without input the node publishes the steps and
    rows that waited for later samples (the whole batch filter), and the next message starts a
    new record (a reset state, the filter from its first step again)."""
    from flight_fdi_msgs.msg import FilterState

    msgs = _as_received(topic_messages(flight(60.0)))
    node = ros.node(FilterNode, {"model": "ins3d", "input_qos": "reliable",
                                     "input_queue_depth": 5000, "ins3d_end_idle_s": 1.0})
    driver = ros.node("driver")
    states = collect(ros, driver, FilterState, "fdi/state", 100000)
    _replay(ros, node, driver, msgs)
    inp = batch_input(msgs)
    n_steps, n_refs = len(inp.steps), inp.refs.t.size
    asm = Ins3dAssembler(wait_s=1.0)        # without the flush the last row would wait
    for ns, key, vals in msgs:
        asm.add(key, ns, *vals)
    assert len(asm.refs) == 1               # (it needs a velocity sample after its stamp)
    ros.spin_until(lambda: len(states) >= n_steps + 1 + n_refs, timeout=60,
                   what="the end-of-input flush")
    assert node.counters["records_ended"] == 1
    model = node.model
    st = inp.steps
    fwd = run_forward(model, st, inp.refs, gate=GateConfig(),
                      P0=model.p0_aligned(st.C[0], st.f_n[0], float(st.lat[0])))
    np.testing.assert_array_equal(_last_states(states), fwd.x)
    # a message after the end starts a new record (here: the same flight 100 s later)
    later = [(ns + 100 * 10**9, key, vals) for ns, key, vals in msgs[:400]]
    n_before = len(states)
    _replay(ros, node, driver, later)
    ros.spin_until(lambda: any(m.reset for m in states[n_before:]), timeout=30,
                   what="the new record's first state")
    assert node.ins3d.asm.t0_ns == later[0][0]


def test_a_stall_is_not_the_end_of_input(ros, monkeypatch):
    """After a stall (a long callback, a process starved of CPU) the executor may run the idle
    timer before the messages that queued meanwhile: the first idle tick only notes it, the
    queued messages continue the record, and the end is flushed only when two ticks in a row
    saw no message (steady clock replaced by a controlled one)."""
    from types import SimpleNamespace

    from flight_fdi.nodes import ins3d_mode

    clock = SimpleNamespace(now=1000.0)
    monkeypatch.setattr(ins3d_mode, "time", SimpleNamespace(monotonic=lambda: clock.now))
    msgs = _as_received(topic_messages(flight(30.0)))
    node = ros.node(FilterNode, {"model": "ins3d", "input_qos": "reliable",
                                     "input_queue_depth": 5000, "ins3d_end_idle_s": 1.0})
    # the test is the idle timer: its ticks are the calls below (the executor's own ticks, at
    # any moment of the replay -- e.g. while discovery matches the new publishers, seconds on a
    # loaded machine -- made two ticks without a message between them and ended the record)
    node.ins3d._idle_timer.cancel()
    driver = ros.node("driver")
    half = len(msgs) // 2
    _replay(ros, node, driver, msgs[:half])
    mode, c = node.ins3d, node.counters
    clock.now += 5.0                    # the stall: the timer's tick comes first
    mode._check_idle()
    assert c["records_ended"] == 0
    _replay(ros, node, driver, msgs[half:])
    assert c["records_ended"] == 0 and not mode.asm.finished
    assert mode.asm.t0_ns == msgs[0][0]     # still the first record
    clock.now += 5.0                    # now the input has really ended
    mode._check_idle()
    assert c["records_ended"] == 0
    mode._check_idle()
    assert c["records_ended"] == 1 and mode.asm.finished


def test_bad_messages_are_counted_not_fatal(ros):
    msgs = _as_received(topic_messages(flight(180.0)))[:3000]
    bad = []
    for i, (ns, key, vals) in enumerate(msgs):
        if i == 1000 and key != "ins_fix":
            vals = tuple(np.asarray(v, dtype=float) * np.nan for v in vals)
        bad.append((ns, key, vals))
    refs = [i for i, m in enumerate(bad) if m[1] == "ref_velocity" and i > 1500]
    ns, key, vals = bad[refs[0]]
    bad[refs[0]] = (ns, key, (vals[0], np.zeros(3)))        # zero covariance
    bad.insert(refs[1] + 1, bad[refs[1]])                    # a duplicate stamp
    node = ros.node(FilterNode, {"model": "ins3d", "input_qos": "reliable",
                                     "input_queue_depth": 5000})
    driver = ros.node("driver")
    _replay(ros, node, driver, bad)
    c = node.counters
    key1000 = bad[1000][1]
    assert c[f"dropped_{key1000}_non_finite"] == 1
    assert c["dropped_ref_velocity_invalid_covariance"] == 1
    assert c["dropped_ref_velocity_duplicate_stamp"] == 1
    assert c["published"] > 100                              # it kept filtering
    vals = {v.key: v.value for v in node.diagnostic_statuses()[0].values}
    assert vals["dropped_ref_velocity_invalid_covariance"] == "1"


@pytest.mark.parametrize("params,needle", [
    ({"model": "ins3d", "tau_a": 100.0}, "'tau_a'"),
    ({"model": "ins3d", "ins3d_grade": "consumer"}, "'ins3d_grade'"),
    ({"model": "ins3d", "ins3d_rows": 4}, "'ins3d_rows'"),
    ({"model": "ins3d", "fix_topic": "/ins/imu"}, "four distinct topics"),
    ({"imu_topic": "/my/imu"}, "applies only to model ins3d"),
    ({"model": "ins3d", "channels": ["x"]}, "'channels'"),
])
def test_parameters_are_validated_at_start(ros, params, needle):
    with pytest.raises(ParameterError, match=needle):
        ros.node(FilterNode, params)


def test_model_from_parameters_matches_the_cli_analysis():
    from flight_fdi.nodes.filter_node import _DEFAULTS

    m = build_model({**_DEFAULTS, "model": "ins3d", "ins3d_grade": "tactical",
                     "ins3d_rows": 3}, _DEFAULTS)
    assert m.grade.name == "tactical" and m.rows == 3 and m.latency and m.ref_markov
    assert m.n == 12 + 3 + 3 + 1 and m.vertical == "loop" and not m.position
    assert m.names[12:15] == ("dh", "int_dh", "b_aid")
