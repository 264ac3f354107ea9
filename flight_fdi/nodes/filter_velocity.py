"""The INS velocity mode of filter_node: its inputs (INS and reference messages, their time
lines), the grouping of references into updates (``core.refsync.ReferenceSync``) and the filter
step per channel. A mixin of :class:`flight_fdi.nodes.filter_node.FilterNode` (the node's
parameters, publishers, counters and channels are set up there).

Bad input never stops the node; every dropped sample is counted by reason and reported in
``/diagnostics`` (status "<node>: inputs" for message-level counts, "<node>: channel <c>" for
per-channel counts). Messages are never reordered.

    =============================== ===========================================================
    count                           what happened
    =============================== ===========================================================
    dropped_ins_invalid_stamp       INS stamp after the last time a stamp can hold (sec
                                    2^31 - 1 with nanosec >= 1e9: outputs could not carry it)
    dropped_ins_nonfinite           INS velocity NaN/Inf on a configured axis
    dropped_ins_duplicate           INS stamp equal to the previous one
    dropped_ins_out_of_order        INS stamp older than the previous one (by <= time_jump_reset_s)
    dropped_ins_stamp_outlier       INS stamp that jumped (filter_node) and was not continued
    dropped_reference_invalid_stamp reference stamp after the last time a stamp can hold
    dropped_reference_duplicate     reference stamp equal to the previous one
    dropped_reference_out_of_order  reference stamp older than the previous one (idem)
    dropped_reference_stamp_outlier reference stamp that jumped and was not continued
    dropped_ins_gap                 the INS samples around the reference stamp are more than
                                    ``max_gap_s`` apart (INS dropout): the reference is dropped
    dropped_ins_too_old             the reference stamp is older than the INS buffer
    dropped_ins_core_error          the INS buffer refused the sample (CoreError)
    dropped_ins_timeout             a reference waited more than ``buffer_s`` (of reference
                                    stamps) for the INS sample after it
    dropped_time_jump               references waiting when the time line jumped back
    time_jump_resets                stamps went back by more than ``time_jump_reset_s``
    (channel) dropped_reference_nonfinite   reference velocity NaN/Inf on the channel's axis
    (channel) dropped_core_error    the core raised CoreError for this sample
    (channel) covariance_invalid    zero / negative / NaN reference covariance: the sample is
                                    used with R = ``reference_variance``
    (channel) resets                filter restarts (time jump, or a gap > reset_after_gap_s)
    =============================== ===========================================================

Redundant references (SPEC section 2, seed 001; core ``flight_fdi.core.references``)
    With ``reference_topics`` naming i topics, every reference is one measurement row (row name =
    its resolved topic name). Reference samples whose stamps lie within
    ``reference_sync_tolerance_s`` of the first one of a group are stacked into one i-row update
    at that first stamp (each row uses the INS velocity interpolated at its own stamp). A
    reference that has no sample for a stamp is absent from that update (fewer rows; counted as
    ``missing`` of that reference): an update waits for a missing reference until that reference
    has moved past the stamp, or until some reference is ``reference_sync_wait_s`` (of stamps)
    ahead, and not at all for a reference more than ``reference_sync_wait_s`` behind (dead or
    lagging); a sample arriving after its stamp was processed is dropped and counted
    (``dropped_reference_late``). Updates are never reordered.

    Per channel each row has its own gate (beta2_k = nu_k^2 / S_kk against the one-row
    threshold); a reference whose exceedance is isolated (the other rows agree with the
    prediction) ``alarm_m`` of ``alarm_n`` times is declared failed, and is readmitted after its
    own gate has passed for ``readmit_after_s``. ``reference_mode`` says what a failed reference
    does to the filter: ``exclude`` (AF, its row is struck out), ``known_anomaly`` (KF2, its
    variance grows by ``anomaly_variance``), ``nominal`` (nothing: reported only). In the two
    active modes a row isolated at the current sample is handled so already (a suspect). The last
    healthy reference is never declared failed; an update that carries only failed rows fuses
    nothing in exclude mode (a prediction only: FilterState without rows, fused false).

    Innovation (one per channel and update) carries every row present: ``innovation``,
    ``innovation_covariance`` and ``row_beta2`` are the nominal ones (S = H P- H^T + R, also
    for excluded rows); ``beta2`` and ``gate_threshold`` are over the rows used (known_anomaly:
    with S + C Gamma C^T); ``row_failed`` = the reference is declared failed; ``row_excluded`` =
    the row is handled by the mode in this update -- struck out (exclude) or inflated by Gamma
    (known_anomaly), for a failed or a suspect row; always false in nominal mode. FilterState
    carries z, r, h of the rows actually fused (exclude: the rows kept; known_anomaly: every row
    with the inflated r), so a recording re-runs exactly what was fused. ``/diagnostics`` has one
    status per reference ("<node>: reference <topic>": per channel failed / excluded, time since
    the failure, failures and readmissions, its last row beta2; missing and late counts) and,
    per channel, the estimation accuracy J = tr(D P) with D the identity on the scaled states
    (J = sum_i P_ii / scale_i^2: the prior std of each state counts 1; 4 for a fresh INS
    channel) and the rows used at the last update.
"""
from __future__ import annotations

import math
import time
from typing import Any

import numpy as np

from ..bagio.cdr import WireError
from ..core.errors import CoreError
from ..core.kalman import ALARM_CLEARED, ALARM_RAISED
from ..core.references import ReferenceConfig
from ..core.refsync import ReferenceSync
from ..core.timeline import ACCEPT, DUPLICATE, HELD, NEW_LINE, OUT_OF_ORDER, OUTLIER
from . import convert
from . import diagnostics as diag
from .errors import ParameterError
from .filter_parts import (Channel as _Channel, Reference as _Reference, count_step,
                           reference_topics)
from .params import fail
from .qos import InputSubscriptions


class VelocityMode:
    """The INS velocity mode's methods of FilterNode (module docstring)."""

    def _setup_velocity_mode(self) -> None:
        """Channels, references, their synchronisation, subscriptions and outputs of the INS
        velocity mode (after the node's parameters, model and gate are set)."""
        p = self.p
        axes = sorted(p["channels"], key=convert.AXIS_INDEX.__getitem__)
        self._axes = np.array([convert.AXIS_INDEX[a] for a in axes])
        self._axes_list = self._axes.tolist()
        self._h = np.asarray(self.model.H, dtype=float)
        self._h_list = self._h.reshape(-1).tolist()
        # published: filter steps published (one Innovation and one FilterState each)
        self.counters = diag.Counters(("received_ins", "received_reference", "published",
                                       "time_jump_resets"))

        ref_key = "reference_topics" if any(p["reference_topics"]) else "reference_topic"
        self.ins_name = self._resolve("ins_topic", p["ins_topic"])
        ref_names = [self._resolve(ref_key, topic) for topic in reference_topics(p)]
        if self.ins_name in ref_names:
            fail(ref_key, p[ref_key], f"a topic other than ins_topic (both resolve to "
                 f"{self.ins_name})")
        if len(set(ref_names)) != len(ref_names):
            fail(ref_key, p[ref_key], f"distinct topics (they resolve to {ref_names})")
        self.refs = [_Reference(k, nm) for k, nm in enumerate(ref_names)]
        # grouping of the reference samples into updates, INS interpolation (core.refsync)
        self.sync = ReferenceSync(len(self.refs), p["reference_sync_tolerance_s"],
                                  p["reference_sync_wait_s"], p["max_gap_s"], p["buffer_s"],
                                  on_drop=lambda reason, detail, n: self._drop(reason, detail,
                                                                               n=n))
        self._ins_line = self._stamp_line()
        self._frame = p["frame_id"]
        for ref in self.refs:
            ref.line = self._stamp_line()
        self.ref_name = ref_names[0]
        self.redundant = len(self.refs) > 1
        if self.redundant:
            try:
                self.ref_config = ReferenceConfig(mode=p["reference_mode"],
                                                  anomaly_variance=p["anomaly_variance"],
                                                  readmit_after_s=p["readmit_after_s"])
            except CoreError as exc:  # the table's checks should make this unreachable
                raise ParameterError(f"invalid reference parameters: {exc}") from None
            self.channels = [_Channel(a, k, self.model, self.gate, ref_names, self.ref_config)
                             for k, a in enumerate(axes)]
        else:
            self.ref_config = None
            self.channels = [_Channel(a, k, self.model, self.gate) for k, a in enumerate(axes)]
        self._subscribe_inputs()
        self._row_names = [self.ref_name]

        self._create_outputs(len(self.channels))

        self.inputs = diag.InputMonitor(self._now, [self.ins_name] + ref_names,
                                        window_s=p["rate_window_s"],
                                        stale_after_s=p["stale_after_s"])
        self.diagnostics = diag.DiagnosticsTimer(self, p["diagnostics_period_s"],
                                                 self.diagnostic_statuses)
        stamp = self.get_clock().now().to_msg()
        for ch in self.channels:
            self.pub_model.publish(convert.model_info_msg(stamp, ch.name, self.model, self.gate,
                                                         frame_id=p["frame_id"]))
        refs_text = ", ".join(ref_names)
        if self.redundant:
            refs_text += (f" (redundant: mode {p['reference_mode']}, readmit after "
                          f"{p['readmit_after_s']} s)")
        self.get_logger().info(
            f"filtering channels {', '.join(axes)} with model {self.model.name} "
            f"(gate {self.gate.rule}, alarm {self.gate.alarm_m} of {self.gate.alarm_n}, "
            f"action {self.gate.action}); inputs {self.ins_name}, {refs_text} "
            f"(input_qos {p['input_qos']}: {self.subs.reliability(self.ins_name)})")

    def _subscribe_inputs(self) -> None:
        """Raw subscriptions of the INS and reference topics in their configured types: the few
        fields used are read from the CDR bytes (convert / wire), ~15 times cheaper than rclpy
        building the message objects (TwistStamped INS: the original fast decoder)."""
        p = self.p
        self._decode_ref = convert.velocity_decoder(p["reference_type"], p["odometry_twist_frame"])
        if p["ins_type"] == convert.VELOCITY_TYPES[0]:
            self._decode_ins = convert.twist_velocity_raw
        else:
            full = convert.velocity_decoder(p["ins_type"], p["odometry_twist_frame"])
            self._decode_ins = lambda data: full(data)[:3]
        self.subs = InputSubscriptions(self, p["input_qos"], p["input_queue_depth"])
        self.subs.subscribe(convert.message_class(p["ins_type"]), self.ins_name, self._on_ins)
        ref_cls = convert.message_class(p["reference_type"])
        for ref in self.refs:
            self.subs.subscribe(ref_cls, ref.name,
                                lambda data, k=ref.index: self._on_reference(k, data))

    def _malformed(self, what: str, exc: Exception) -> None:
        """A message whose bytes are not its type (only a broken publisher sends that)."""
        self._drop(f"{what}_malformed", f"{what} message: {exc}")

    def _received(self, what: str, decode: Any, data: bytes) -> tuple[float, tuple] | None:
        """(t, the decoded message) of an input message, counted ``received_<what>``; None (a
        counted drop) when its bytes are malformed or its stamp cannot be carried."""
        self.counters.inc(f"received_{what}")
        try:
            msg = decode(data)
        except WireError as exc:
            self._malformed(what, exc)
            return None
        t = convert.parts_to_s(msg[0], msg[1])
        if self._bad_stamp(what, t, msg[0], msg[1]):
            return None
        return t, msg

    # ------------------------------------------------------------------ INS input
    def _on_ins(self, data: bytes) -> None:
        self.inputs.seen(self.ins_name)
        got = self._received("ins", self._decode_ins, data)
        if got is None:
            return
        t, (_, _, lin) = got
        values = [lin[a] for a in self._axes_list]
        if not all(map(math.isfinite, values)):
            self._drop("ins_nonfinite", f"INS sample at t={t:.3f} s: non-finite velocity "
                       f"{values}")
            return
        # one channel: a plain float (the aligner's cheap path); several: a vector
        v = values[0] if len(values) == 1 else np.array(values)
        verdict = self._ins_line.check(t, (t, v))
        if verdict.dismissed:
            self._outliers("ins", verdict.dismissed)
        kind = verdict.kind
        if kind == ACCEPT:
            self._add_ins(t, v)
        elif kind == NEW_LINE:
            self._ins_time_jump(*verdict.jump)
            for t_k, v_k in verdict.released:
                self._add_ins(t_k, v_k)
        elif kind != HELD:
            self._stamp_drop("ins", kind, t)

    def _add_ins(self, t: float, v: Any) -> None:
        try:
            updates = self.sync.add_ins(t, v)
        except CoreError as exc:
            self._drop("ins_core_error", f"INS sample at t={t:.3f} s: {exc}")
            return
        self._process(updates)

    def _stamp_drop(self, what: str, kind: str, t: float, ref: Any = None) -> None:
        """A sample dropped by its time line (duplicate, out of order, outlier)."""
        line = self._ins_line if ref is None else ref.line
        where = "INS" if ref is None else f"reference sample on {ref.name}"
        why = {DUPLICATE: "duplicate stamp", OUT_OF_ORDER: f"older than the last one "
               f"({line.last:.3f} s)", OUTLIER: "repeats a wild stamp"}[kind]
        self._drop(f"{what}_{'stamp_outlier' if kind == OUTLIER else kind}",
                   f"{where} at t={t:.3f} s: {why}")

    def _outliers(self, what: str, dismissed: list) -> None:
        """Held samples whose jump the next samples did not continue: wild stamps."""
        stamps = ", ".join(f"{p[0]:.3f}" for p in dismissed)
        self._drop(f"{what}_stamp_outlier", f"{len(dismissed)} {what} sample(s) with a wild stamp "
                   f"({stamps} s; the time line continued)", n=len(dismissed))

    def _ins_time_jump(self, last: float, t: float) -> None:
        self.get_logger().warning(
            f"INS time jumped from {last:.3f} s to {t:.3f} s (confirmed by "
            f"{self.p['time_jump_confirm']} samples): INS buffer reset")
        self.sync.ins_time_jump(t, self.p["time_jump_reset_s"])

    # ------------------------------------------------------------------ reference input
    def _on_reference(self, k: int, data: bytes) -> None:
        ref = self.refs[k]
        self.inputs.seen(ref.name)
        got = self._received("reference", self._decode_ref, data)
        if got is None:
            return
        t, (_, _, lin, var) = got
        verdict = ref.line.check(t, (t, lin, var))
        if verdict.dismissed:
            self._outliers("reference", verdict.dismissed)
        kind = verdict.kind
        if kind == ACCEPT:
            self._accept_reference(k, t, lin, var)
        elif kind == NEW_LINE:
            self._reference_time_jump(*verdict.jump)
            # the other references start on the new line too; what they held is on it
            todo = [(s_[0], k, s_, True) for s_ in verdict.released]
            todo += [(s_[0], j, s_, False) for j, other in enumerate(self.refs) if j != k
                     for s_ in other.line.reset()]
            for _, j, (t_j, lin_j, var_j), accepted in sorted(todo, key=lambda e: e[0]):
                if accepted:
                    self._accept_reference(j, t_j, lin_j, var_j)
                else:
                    self._on_reference_sample(j, t_j, lin_j, var_j)
        elif kind != HELD:
            self._stamp_drop("reference", kind, t, ref)

    def _on_reference_sample(self, k: int, t: float, lin: Any, var: Any) -> None:
        ref = self.refs[k]
        verdict = ref.line.check(t, (t, lin, var))
        if verdict.kind == ACCEPT:
            self._accept_reference(k, t, lin, var)
        else:  # only after a reset of the line: cannot jump again
            self._stamp_drop("reference", verdict.kind, t, ref)

    def _accept_reference(self, k: int, t: float, lin: Any, var: Any) -> None:
        ref = self.refs[k]
        ref.counters.inc("samples")
        updates = self.sync.add_reference(k, t, lin, var)
        if updates is None:
            # its stamp has been processed (without it): an update is never redone
            ref.counters.inc("dropped_late")
            self._drop("reference_late", f"reference sample on {ref.name} at t={t:.3f} s: "
                       f"arrived after the update at {self.sync.last_epoch_t:.3f} s")
            return
        self._process(updates)

    def _reference_time_jump(self, last: float, t: float) -> None:
        self.counters.inc("time_jump_resets")
        reason = (f"reference time jumped from {last:.3f} s to {t:.3f} s (confirmed by "
                  f"{self.p['time_jump_confirm']} samples)")
        self.get_logger().warning(f"{reason}: filter reset")
        for ch in self.channels:
            self._reset_channel(ch, reason)
        self.sync.reference_time_jump(t, self.p["time_jump_reset_s"])

    def _process(self, updates: list) -> None:
        """Step the filter for the updates released by the synchronisation, in stamp order."""
        for u in updates:
            if self.redundant:
                for k in u.missing:
                    self.refs[k].counters.inc("missing")
                self._step_redundant(u.t, u.rows)
            else:
                _, v_ins, v_ref, var = u.rows[0]
                self._step(u.t, v_ins, v_ref, var)

    # ------------------------------------------------------------------ the filter step
    def _row(self, ch: _Channel, t: float, v_ins: np.ndarray, v_ref: np.ndarray,
             var: np.ndarray) -> tuple[float, float] | None:
        """(z, r) of one reference sample on channel ``ch``; None (counted) when the reference
        velocity is not finite on that axis."""
        vr = float(v_ref[ch.axis])
        if not math.isfinite(vr):
            self._drop("reference_nonfinite", f"reference sample at t={t:.3f} s on "
                       f"channel {ch.name}: non-finite velocity {vr}", channel=ch)
            return None
        r = float(var[ch.axis])
        if not (self.p["use_reference_covariance"] and math.isfinite(r) and r > 0.0):
            if self.p["use_reference_covariance"]:
                ch.counters.inc("covariance_invalid")
            r = self.p["reference_variance"]
        return float(v_ins[ch.column]) - vr, r

    def _dt(self, ch: _Channel, t: float) -> tuple[float, bool]:
        """(dt, reset) of the next step of ``ch`` at ``t``; restarts it after a long gap."""
        reset = ch.last_t is None
        dt = 0.0 if reset else t - ch.last_t
        if dt > self.p["reset_after_gap_s"]:
            reason = (f"no update for {dt:.1f} s (> reset_after_gap_s "
                      f"{self.p['reset_after_gap_s']} s)")
            self.get_logger().warning(f"channel {ch.name}: {reason}: filter restarted from the "
                                      "prior")
            self._reset_channel(ch, reason)
            reset, dt = True, 0.0
        return dt, reset

    @staticmethod
    def _reset_channel(ch: _Channel, reason: str) -> None:
        ch.reset()
        ch.counters.inc("resets")
        ch.last_reset = (time.monotonic(), reason)

    def _count(self, ch: _Channel, t: float, res: Any, now: float) -> None:
        count_step(ch, t, res, now)
        self._alarm_transition(ch, t, res)

    def _step(self, t: float, v_ins: np.ndarray, v_ref: np.ndarray, var: np.ndarray) -> None:
        """One filter step per channel at reference stamp ``t`` (one reference). The
        innovations (what the in-flight monitor waits for) are published as soon as each is
        known, the states after."""
        stamp = convert.stamp_parts(t)
        now = self._now()
        states = []
        for ch in self.channels:
            row = self._row(ch, t, v_ins, v_ref, var)
            if row is None:
                continue
            z, r = row
            dt, reset = self._dt(ch, t)
            try:
                res = ch.kf.step1(dt, z, r)
            except CoreError as exc:
                self._drop("core_error", f"sample at t={t:.3f} s on channel {ch.name}: {exc}",
                           channel=ch)
                continue
            ch.rows_used = 1
            self._count(ch, t, res, now)
            self.pub_innovation.publish(
                convert.innovation_bytes(stamp, ch.name, self._row_names, res,
                                         frame_id=self._frame))
            x, P = ch.kf.state_lists()
            states.append(convert.filter_state_bytes(
                stamp, ch.name, self.model.state_names, x, P, z=[z], R=[r], H=self._h_list,
                dt=dt, fused=res.fused, gated=res.exceeded, reset=reset, frame_id=self._frame))
        for msg in states:
            self.pub_state.publish(msg)
        self.counters.inc("published", len(states))

    def _step_redundant(self, t: float, rows: list) -> None:
        """One update per channel at stamp ``t`` with the rows of the references present
        (``rows``: (reference index, INS velocity at its stamp, reference velocity, variance))."""
        stamp = convert.stamp_parts(t)
        now = self._now()
        states = []
        for ch in self.channels:
            present, zs, rs = [], [], []
            for k, v_ins, v_ref, var in rows:
                row = self._row(ch, t, v_ins, v_ref, var)
                if row is not None:
                    present.append(k)
                    zs.append(row[0])
                    rs.append(row[1])
            if not present:
                continue
            dt, reset = self._dt(ch, t)
            try:
                out = ch.rf.step(t, dt, zs, rs, present)
            except CoreError as exc:
                self._drop("core_error", f"sample at t={t:.3f} s on channel {ch.name}: {exc}",
                           channel=ch)
                continue
            res = out.update
            ch.rows_used = len(out.z_used)
            self._count(ch, t, res, now)
            for ev in out.events:
                self._reference_event(ch, ev)
            self.pub_innovation.publish(convert.innovation_bytes(
                stamp, ch.name, out.names, res, row_failed=out.row_failed,
                row_excluded=out.row_excluded, frame_id=self._frame))
            states.append(convert.filter_state_bytes(
                stamp, ch.name, self.model.state_names, ch.kf.x, ch.kf.P, z=out.z_used,
                R=out.R_used, H=out.H_used, dt=dt, fused=res.fused, gated=res.exceeded,
                reset=reset, frame_id=self._frame))
        for msg in states:
            self.pub_state.publish(msg)
        self.counters.inc("published", len(states))

    def _reference_event(self, ch: _Channel, ev: Any) -> None:
        mode = self.ref_config.mode
        if ev.kind == "failed":
            what = {"exclude": "excluded", "known_anomaly": "inflated by anomaly_variance",
                    "nominal": "still fused (nominal mode)"}[mode]
            self.get_logger().warning(
                f"channel {ch.name}: reference {ev.name} failed at t={ev.t:.3f} s (row beta2 "
                f"{ev.beta2:.3g} > {self.gate.threshold(1):.3g} in {self.gate.alarm_m} of its "
                f"last {self.gate.alarm_n} samples): {what}")
        else:
            self.get_logger().info(
                f"channel {ch.name}: reference {ev.name} readmitted at t={ev.t:.3f} s "
                f"(healthy for {self.p['readmit_after_s']} s)")

    def _alarm_transition(self, ch: _Channel, t: float, res: Any) -> None:
        if res.alarm_state == ALARM_RAISED:
            ch.alarm_since = t
            ch.counters.inc("alarms_raised")
            self.get_logger().warning(
                f"channel {ch.name}: INS fault alarm raised at t={t:.3f} s "
                f"(beta2 {res.beta2:.3g} > {res.threshold:.3g} in {self.gate.alarm_m} of the "
                f"last {self.gate.alarm_n} samples)")
        elif res.alarm_state == ALARM_CLEARED:
            ch.alarm_since = None
            self.get_logger().info(f"channel {ch.name}: alarm cleared at t={t:.3f} s")
