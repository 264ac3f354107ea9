"""The filter node's attitude mode (seed 003, SPEC section 7): per axis the Kalman filter of the
spacecraft attitude axis with its control input, and the actuator monitor whose decision is
"switch to reserve".

The mode is selected by the node's ``model`` parameter: ``attitude_axis`` (the built-in model,
shaped by the ``attitude_*`` parameters) or a model YAML file with a control input B (one input,
a state named ``disturbance``, rows angle or angle and rate). ``filter_node`` declares every
parameter (``FILTER_PARAMS``) and builds :class:`AttitudeMode`; the attitude logic is here.

Start-up check
    The Kalman rank test rank [H^T A^T H^T (A^T)^2 H^T] = n (``core.actuator.require_observable``)
    runs before anything is created: an unobservable configuration -- ``attitude_measure: rate``,
    where the angle never enters a measurement -- stops the node with a ParameterError naming
    ``attitude_measure`` (``model`` for a model file) and the rank message.

Inputs (geometry_msgs/Vector3Stamped, one value per axis x, y, z; QoS ``input_qos``)
    ``angle_topic``   (/attitude/angle)    measured angle [rad]
    ``rate_topic``    (/attitude/rate)     measured rate [rad/s]; only with
                                           ``attitude_measure: angle+rate``
    ``control_topic`` (/attitude/control)  command u per axis (-1 / 0 / +1 for an on/off thruster
                                           pair; torque = m_c u), stamped when commanded and in
                                           force until the next message

The step (per channel, ``channels``: any of x, y, z; one filter and one monitor each)
    Each angle message is one step at its stamp t_k. The command in force over (t_{k-1}, t_k] is
    the last control message stamped *before* t_k (as ``sim.attitude.read_attitude_bag`` reads a
    bag): the filter predicts with it over dt = t_k - t_{k-1} (exact discretisation) and updates
    with the angle, and with the rate sample whose stamp is within ``rate_sync_tolerance_s`` of
    t_k when the rate is measured (angle alone when it is missing: counted ``rate_missing``).
    The first step after a (re)start is an update only (dt = 0, u = 0: no command acts over an
    empty interval). A command stamped inside the interval is applied over all of it (counted
    ``control_changed_within_interval`` when it changes the value): publish commands at
    measurement stamps, as the simulator does, and the discretisation is exact.

    A sample waits until the control topic has reached its stamp (a control message stamped
    at or after t_k: no command for the interval can still come) and, with the rate, until its
    rate sample came or the rate topic moved past it -- at most ``attitude_wait_s``, of angle
    stamps (a newer angle more than that ahead) or of node time (a timer), after which it is
    processed with what is known. A controller that publishes only on change therefore costs up
    to ``attitude_wait_s`` of latency, never a wrong command. Samples are never reordered.

    No command is ever assumed: before the first control message (stamped at or before t_k)
    samples are dropped (``dropped_no_control``; the filter starts with the first command).

Actuator monitor (``core.actuator.ActuatorMonitor``; ``actuator_*`` -> ActuatorConfig)
    After each step the monitor takes (t_k, u, x, P). The mean of the estimated disturbance over
    a window of ``actuator_window_s`` of zero control (|u| <= ``actuator_zero_tolerance``, from
    ``actuator_settle_s`` after the last firing), when the estimate is precise enough (rms std
    <= threshold / ``actuator_k_sigma``), above the threshold (``actuator_threshold_urad_s2``, in
    micro-rad/s^2; the monitor and its events work in rad/s^2) is an actuator fault. On
    that event the node

    * logs an ERROR with the event,
    * publishes it as JSON on ``fdi/actuator_event`` (std_msgs/String, reliable + transient
      local, so a late subscriber gets it): node, axis, t, window_start_t, window_end_t, mean,
      threshold, std, samples, ``"action": "switch_to_reserve"``, message;
    * turns the status ``"<node>: actuator <axis>"`` of ``/diagnostics`` to ERROR ("switch to
      reserve: ..."; values ``action``, ``event_t_s``, ``event_window_start_s``,
      ``event_window_end_s``, ``event_mean``, ``event_std``, ``event_samples``, ``threshold``)
      and publishes ``/diagnostics`` at once.

    The event is latched: the status stays ERROR (the reserve set is in use) until the node is
    restarted or the service ``~/reset_actuator`` (std_srvs/Trigger) re-arms the monitors; a
    reset publishes ``{"action": "reset", "axes": [...]}`` on ``fdi/actuator_event``. Without
    an event the status is OK with the last window's mean, std and whether it was evaluated.

Outputs as in the INS velocity mode: ``fdi/innovation`` (row names = the angle and rate topics of
the rows used), ``fdi/state`` (FilterState with ``u`` = [the command applied], z, r, h of the rows
used), ``fdi/model`` (ModelInfo with B, latched). ``/diagnostics``: "<node>: inputs" (rates,
staleness, counts), per channel "<node>: channel <c>" (beta2, gate, innovation alarm -- WARN:
the measurements disagree with the model --, last command, counts, x) and
"<node>: actuator <c>".

Bad input is counted, never fatal (message level in "inputs", sample level per channel; the
counts are listed in ``nodes/attitude_diag.py``).

A jump back of the control stamps (a bag loop) clears the command state and restarts the
filters; samples between the jumps of the two topics may use a command of the other time line
for a moment -- the angle's own jump then restarts the filters again.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Any

import numpy as np

from ..core.errors import CoreError
from ..core.kalman import ALARM_CLEARED, ALARM_RAISED, GateConfig
from ..core.models import LinearModel
from . import attitude_diag, convert
from . import diagnostics as diag
from .attitude_parts import (  # noqa: F401 (parameters re-exported for filter_node)
    ATTITUDE_ONLY, MODEL_KEYS, MONITOR_KEYS, AxisChannel, FilterHost, Sample, actuator_config,
    build_attitude_model, is_attitude_model)
from .filter_parts import count_step
from .params import fail

EVENT_TOPIC = "fdi/actuator_event"
RESET_SERVICE = "~/reset_actuator"
#: commands buffered for samples still to come; beyond this the oldest are folded into the one
#: in force (a sample older than a folded command is then dropped: ``control_expired``)
MAX_CONTROLS = 10000


# --------------------------------------------------------------------------- the mode

class AttitudeMode:
    """The attitude mode of a FilterNode (module docstring). Built by the node after its
    parameters are declared; creates the subscriptions, publishers, the reset service and the
    diagnostics timer on the node, and sets the node's ``counters``, ``channels``, ``inputs``
    and ``diagnostics``."""

    def __init__(self, node: FilterHost, model: LinearModel, gate: GateConfig, qos: Any) -> None:
        self.node = node
        p = self.p = node.p
        self.model = model
        self.gate = gate
        self.config = actuator_config(p)
        self.with_rate = model.m == 2
        self.wait_s = p["attitude_wait_s"]
        self.tol = p["rate_sync_tolerance_s"]
        self.jump_s = p["time_jump_reset_s"]
        self._H = np.asarray(model.H, dtype=float)
        self._R = np.asarray(model.R, dtype=float)

        self._resolve_topics()
        self._row_names = [self.angle_name] + ([self.rate_name] if self.with_rate else [])

        axes = sorted(p["channels"], key=convert.AXIS_INDEX.__getitem__)
        self._axes = np.array([convert.AXIS_INDEX[a] for a in axes])
        self.channels = [AxisChannel(a, model, gate, self.config) for a in axes]
        names = ["received_angle"] + (["received_rate"] if self.with_rate else []) + [
            "received_control", "time_jump_resets", "control_late",
            "control_changed_within_interval"] + (["rate_missing"] if self.with_rate else [])
        self.counters = diag.Counters(names)
        node.counters = self.counters
        node.channels = self.channels

        self._pending: deque[Sample] = deque()
        self._rates: deque[tuple[float, np.ndarray]] = deque()     # rate samples awaiting angles
        self._controls: deque[tuple[float, np.ndarray]] = deque()  # commands for samples to come
        self._current: tuple[float, np.ndarray] | None = None      # the last command stamped
        #                                                   before the last sample processed
        self._horizon: float | None = None  # stamp of the newest command folded out of the buffer
        self._last_angle_t: float | None = None
        self._last_rate_t: float | None = None
        self._last_control_t: float | None = None
        self._last_sample_t: float | None = None  # stamp of the last sample processed

        self._create_interfaces(qos)
        stamp = node.get_clock().now().to_msg()
        for ch in self.channels:
            node.pub_model.publish(convert.model_info_msg(stamp, ch.name, model, gate,
                                                          frame_id=self.p["frame_id"]))
        c = self.config
        node.get_logger().info(
            f"attitude mode: channels {', '.join(axes)}, model {model.name} measuring "
            f"{' and '.join(model.measurement_names)} (observable), control input "
            f"{self.control_name}, measurements {', '.join(self._row_names)} "
            f"({p['input_qos']}); actuator monitor: |mean disturbance| over {c.window_s:g} s of "
            f"zero control > {c.threshold:g} -> switch to reserve")

    def _resolve_topics(self) -> None:
        """The resolved input topics (distinct; ParameterError naming the parameter)."""
        node, p = self.node, self.p
        self.angle_name = node._resolve("angle_topic", p["angle_topic"])
        self.control_name = node._resolve("control_topic", p["control_topic"])
        if self.control_name == self.angle_name:
            fail("control_topic", p["control_topic"], f"a topic other than angle_topic (both "
                 f"resolve to {self.angle_name})")
        self.rate_name = None
        if self.with_rate:
            self.rate_name = node._resolve("rate_topic", p["rate_topic"])
            if self.rate_name in (self.angle_name, self.control_name):
                fail("rate_topic", p["rate_topic"], f"a topic other than angle_topic and "
                     f"control_topic (it resolves to {self.rate_name})")

    def _create_interfaces(self, qos: Any) -> None:
        """Subscriptions, outputs, the event topic, the reset service, the input monitor, the
        diagnostics and the wait timer, on the node."""
        from geometry_msgs.msg import Vector3Stamped
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
        from std_msgs.msg import String
        from std_srvs.srv import Trigger

        node, p = self.node, self.p
        node.create_subscription(Vector3Stamped, self.angle_name, self._on_angle, qos)
        if self.with_rate:
            node.create_subscription(Vector3Stamped, self.rate_name, self._on_rate, qos)
        node.create_subscription(Vector3Stamped, self.control_name, self._on_control, qos)
        node._create_outputs(len(self.channels))
        latched = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=10,
                             reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self._String = String
        self.pub_event = node.create_publisher(String, EVENT_TOPIC, latched)
        self.reset_service = node.create_service(
            Trigger, RESET_SERVICE, lambda request, response: attitude_diag.on_reset(
                self, request, response))
        inputs = [self.angle_name] + ([self.rate_name] if self.with_rate else []) + [
            self.control_name]
        self.inputs = node.inputs = diag.InputMonitor(node._now, inputs,
                                                      window_s=p["rate_window_s"],
                                                      stale_after_s=p["stale_after_s"])
        node.diagnostics = diag.DiagnosticsTimer(node, p["diagnostics_period_s"],
                                                 self.diagnostic_statuses)
        # samples whose command never comes (a controller publishing only on change) are
        # processed after attitude_wait_s of node time
        self.timer = node.create_timer(self.wait_s / 2.0, self._on_timer)

    # ------------------------------------------------------------------ inputs
    def _order(self, topic: str, t: float, last: float | None) -> str:
        """"ok", "jump" (stamps went back by more than time_jump_reset_s) or "drop" (duplicate
        or out of order; counted)."""
        if last is None or t > last:
            return "ok"
        if t == last:
            self.node._drop(f"{topic}_duplicate", f"{topic} sample at t={t:.3f} s: duplicate "
                            "stamp")
            return "drop"
        if last - t <= self.jump_s:
            self.node._drop(f"{topic}_out_of_order", f"{topic} sample at t={t:.3f} s: older "
                            f"than the last one ({last:.3f} s)")
            return "drop"
        return "jump"

    def _on_angle(self, msg: Any) -> None:
        self.inputs.seen(self.angle_name)
        self.counters.inc("received_angle")
        t, v = convert.vector3_values(msg)
        if self.node._bad_stamp("angle", t, *convert.header_parts(msg)):
            return
        order = self._order("angle", t, self._last_angle_t)
        if order == "drop":
            return
        if order == "jump":
            self._angle_time_jump(t, self._last_angle_t)
        self._last_angle_t = t
        e = Sample(t, v, self.node._now())
        if self.with_rate:
            # rates older than this angle (less the tolerance) can match no angle to come
            while self._rates and self._rates[0][0] < t - self.tol:
                old = self._rates.popleft()
                self.node._drop("rate_unmatched", f"rate sample at t={old[0]:.3f} s: no angle "
                                f"sample within {self.tol} s")
            best = None
            for k, (tr, _) in enumerate(self._rates):
                if abs(tr - t) <= self.tol and (best is None or
                                                abs(tr - t) < abs(self._rates[best][0] - t)):
                    best = k
            if best is not None:
                e.rate = self._rates[best][1]
                del self._rates[best]
        self._pending.append(e)
        self._drain()

    def _on_rate(self, msg: Any) -> None:
        self.inputs.seen(self.rate_name)
        self.counters.inc("received_rate")
        t, v = convert.vector3_values(msg)
        if self.node._bad_stamp("rate", t, *convert.header_parts(msg)):
            return
        order = self._order("rate", t, self._last_rate_t)
        if order == "drop":
            return
        if order == "jump":
            self.node.get_logger().warning(
                f"rate time jumped back from {self._last_rate_t:.3f} s to {t:.3f} s")
            self._rates.clear()
        self._last_rate_t = t
        best = None
        for e in self._pending:
            if e.rate is None and abs(e.t - t) <= self.tol and \
                    (best is None or abs(e.t - t) < abs(best.t - t)):
                best = e
        if best is not None:
            best.rate = v
        elif self._last_sample_t is not None and t <= self._last_sample_t + self.tol:
            self.node._drop("rate_unmatched", f"rate sample at t={t:.3f} s: its angle sample "
                            "was processed already or never came (last processed "
                            f"{self._last_sample_t:.3f} s)")
        else:
            self._rates.append((t, v))
            if len(self._rates) > MAX_CONTROLS:
                old = self._rates.popleft()
                self.node._drop("rate_unmatched", f"rate sample at t={old[0]:.3f} s: no angle "
                                "sample came")
        self._drain()

    def _on_control(self, msg: Any) -> None:
        self.inputs.seen(self.control_name)
        self.counters.inc("received_control")
        t, v = convert.vector3_values(msg)
        if self.node._bad_stamp("control", t, *convert.header_parts(msg)):
            return
        if not np.all(np.isfinite(v[self._axes])):
            self.node._drop("control_nonfinite", f"control at t={t:.3f} s: non-finite command "
                            f"{v[self._axes]} (the previous command stays in force)")
            return
        order = self._order("control", t, self._last_control_t)
        if order == "drop":
            return
        if order == "jump":
            self.node.get_logger().warning(
                f"control time jumped back from {self._last_control_t:.3f} s to {t:.3f} s: "
                "commands cleared, filters restarted")
            self._reset_controls()
            self._restart_channels()
        self._last_control_t = t
        if self._last_sample_t is not None and t < self._last_sample_t:
            # stamped before a sample that was processed without it (it waited attitude_wait_s);
            # every command before it is older, so it is the one in force from now on
            self.counters.inc("control_late")
            self.node.get_logger().warning(
                f"control at t={t:.3f} s arrived after the sample at {self._last_sample_t:.3f} s "
                f"was processed (attitude_wait_s {self.wait_s} s)", throttle_duration_sec=5.0)
            self._current = (t, v)
        else:
            self._controls.append((t, v))
            if len(self._controls) > MAX_CONTROLS:
                self._current = self._controls.popleft()
                self._horizon = self._current[0]
        self._drain()

    def _on_timer(self) -> None:
        if self._pending:
            self._drain(self.node._now())

    # ------------------------------------------------------------------ time jumps
    def _reset_controls(self) -> None:
        self._controls.clear()
        self._current = None
        self._horizon = None
        self._last_control_t = None

    def _restart_channels(self) -> None:
        for ch in self.channels:
            ch.reset()
            ch.counters.inc("resets")
        self._last_sample_t = None

    def _angle_time_jump(self, t: float, last: float) -> None:
        self.counters.inc("time_jump_resets")
        self.node.get_logger().warning(
            f"angle time jumped back from {last:.3f} s to {t:.3f} s: filters reset")
        self._restart_channels()
        if self._pending:
            self.node._drop("time_jump", f"{len(self._pending)} angle samples waiting across a "
                            "time jump", n=len(self._pending))
            self._pending.clear()
        limit = t + self.jump_s
        self._rates = deque(r for r in self._rates if r[0] <= limit)
        if self._last_rate_t is not None and self._last_rate_t > limit:
            self._last_rate_t = None
        if self._last_control_t is not None and self._last_control_t > limit:
            self._reset_controls()  # still on the old time line

    # ------------------------------------------------------------------ processing
    def _ready(self, e: Sample, now: float | None) -> bool:
        """The sample at the head waits for no more input (module docstring)."""
        if self._last_angle_t > e.t + self.wait_s or (now is not None and
                                                      now - e.arrived >= self.wait_s):
            return True
        if self._last_control_t is None or self._last_control_t < e.t:
            return False
        if self.with_rate and e.rate is None and \
                (self._last_rate_t is None or self._last_rate_t <= e.t + self.tol):
            return False
        return True

    def _drain(self, now: float | None = None) -> None:
        while self._pending and self._ready(self._pending[0], now):
            self._process(self._pending.popleft())

    def _process(self, e: Sample) -> None:
        t = e.t
        prev = self._last_sample_t
        self._last_sample_t = t
        if self.with_rate and e.rate is None:
            self.counters.inc("rate_missing")
        if self._horizon is not None and t <= self._horizon:
            self.node._drop("control_expired", f"angle sample at t={t:.3f} s: older than the "
                            f"command buffer ({MAX_CONTROLS} commands)")
            return
        # the command in force over (prev, t]: the last one stamped before t
        at_start = self._current
        while self._controls and self._controls[0][0] < t:
            c = self._controls.popleft()
            if prev is not None and c[0] <= prev:
                at_start = c
            self._current = c
        cur = self._current
        if cur is None and not (self._controls and self._controls[0][0] <= t):
            self.node._drop("no_control", f"angle sample at t={t:.3f} s: no command on "
                            f"{self.control_name} at or before it (filtering starts with the "
                            "first command)")
            return
        if cur is not None and prev is not None and at_start is not cur and (
                at_start is None or not np.array_equal(at_start[1][self._axes],
                                                       cur[1][self._axes])):
            self.counters.inc("control_changed_within_interval")
        self._step(e, None if cur is None else cur[1])

    def _step(self, e: Sample, u_vec: np.ndarray | None) -> None:
        """One step per channel at the angle stamp; ``u_vec`` the command in force over the
        interval (None: only first steps, dt = 0, may be taken)."""
        node = self.node
        t = e.t
        stamp = convert.s_to_stamp(t)
        now = node._now()
        states = []
        for ch in self.channels:
            a = float(e.angle[ch.axis])
            if not math.isfinite(a):
                node._drop("angle_nonfinite", f"angle sample at t={t:.3f} s on channel "
                           f"{ch.name}: non-finite angle {a}", channel=ch)
                continue
            rows, z = [0], [a]
            if e.rate is not None:
                r = float(e.rate[ch.axis])
                if math.isfinite(r):
                    rows.append(1)
                    z.append(r)
                else:
                    node._drop("rate_nonfinite", f"rate sample at t={t:.3f} s on channel "
                               f"{ch.name}: non-finite rate {r} (the angle alone is used)",
                               channel=ch)
            dt, reset = node._dt(ch, t)
            if reset:
                u = 0.0  # an update only: no command acts over an empty interval
            elif u_vec is None:
                node._drop("no_control", f"angle sample at t={t:.3f} s on channel {ch.name}: "
                           "no command for the interval", channel=ch)
                continue
            else:
                u = float(u_vec[ch.axis])
            H, R = self._H, self._R
            try:
                # one transaction: an update refused after the prediction undoes the prediction
                with ch.kf.transaction():
                    if len(rows) == self.model.m:
                        res = ch.kf.step(dt, z, R, [u])
                    else:
                        H, R = H[rows], R[np.ix_(rows, rows)]
                        ch.kf.predict(dt, [u])
                        res = ch.kf.update(z, R, H)
            except CoreError as exc:
                node._drop("core_error", f"sample at t={t:.3f} s on channel {ch.name}: {exc}",
                           channel=ch)
                continue
            x, P = ch.kf.x, ch.kf.P
            self._count(ch, t, res, now, u)
            try:
                event = ch.monitor.update(t, [u], x, P)
            except CoreError as exc:
                node._drop("core_error", f"actuator monitor at t={t:.3f} s on channel "
                           f"{ch.name}: {exc}", channel=ch)
                event = None
            ch.window_closed()
            node.pub_innovation.publish(convert.innovation_msg(
                stamp, ch.name, [self._row_names[k] for k in rows], res,
                frame_id=self.p["frame_id"]))
            states.append(convert.filter_state_msg(
                stamp, ch.name, self.model.state_names, x, P, z=z, R=R, H=H, u=(u,), dt=dt,
                fused=res.fused, gated=res.exceeded, reset=reset, frame_id=self.p["frame_id"]))
            if event is not None:
                attitude_diag.on_event(self, ch, event)
        for msg in states:
            node.pub_state.publish(msg)

    def _count(self, ch: AxisChannel, t: float, res: Any, now: float, u: float) -> None:
        count_step(ch, t, res, now)
        ch.last_u = u
        if res.alarm_state == ALARM_RAISED:
            ch.alarm_since = t
            ch.counters.inc("alarms_raised")
            self.node.get_logger().warning(
                f"channel {ch.name}: innovation alarm raised at t={t:.3f} s (beta2 "
                f"{res.beta2:.3g} > {res.threshold:.3g} in {self.gate.alarm_m} of the last "
                f"{self.gate.alarm_n} samples): the attitude measurements disagree with the model")
        elif res.alarm_state == ALARM_CLEARED:
            ch.alarm_since = None
            self.node.get_logger().info(f"channel {ch.name}: innovation alarm cleared at "
                                        f"t={t:.3f} s")

    # ------------------------------------------------------------------ diagnostics
    def diagnostic_statuses(self) -> list:
        return attitude_diag.statuses(self)
