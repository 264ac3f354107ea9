"""What filter_node's attitude mode reports: ``/diagnostics`` (the inputs, per axis the channel
-- beta2, alarm, accuracy, state -- and the actuator monitor) and the "switch to reserve" event
on ``fdi/actuator_event`` with its reset service.

Bad input is counted, never fatal (message level in "inputs", sample level per channel):

    =================================== =======================================================
    count                               what happened
    =================================== =======================================================
    dropped_{angle,rate,control}_invalid_stamp stamp after the last time a ROS stamp can hold
                                        (sec 2^31 - 1 with nanosec >= 1e9)
    dropped_{angle,rate,control}_duplicate     stamp equal to the previous one on that topic
    dropped_{angle,rate,control}_out_of_order  stamp older than the previous one (by at most
                                        ``time_jump_reset_s``)
    dropped_control_nonfinite           NaN/Inf command on a configured axis: the message is
                                        ignored, the previous command stays in force
    dropped_no_control                  no command known yet for the sample
    dropped_rate_unmatched              a rate sample with no angle sample within
                                        ``rate_sync_tolerance_s`` (or after its angle was used)
    dropped_time_jump                   samples waiting when the angle time line jumped back
    dropped_control_expired             a sample older than the bounded command buffer
    rate_missing                        a step without its rate sample (angle alone)
    control_late                        a command stamped before a sample already processed
                                        (in force from then on)
    control_changed_within_interval     see above
    time_jump_resets                    angle stamps went back by more than
                                        ``time_jump_reset_s``: filters restarted
    (channel) dropped_angle_nonfinite   NaN/Inf angle on the channel's axis
    (channel) dropped_rate_nonfinite    NaN/Inf rate on the channel's axis (angle alone)
    (channel) dropped_core_error        the core raised CoreError for this sample
    (channel) resets                    filter restarts (time jump, gap > reset_after_gap_s,
                                        control time jump)
    =================================== =======================================================
"""
from __future__ import annotations

import json
import math
from typing import Any

from . import diagnostics as diag

_ALARM_NAMES = {0: "clear", 1: "raised", 2: "active", 3: "cleared"}


def _time(t: float | None) -> str:
    """A stamp for /diagnostics: full resolution (format_value's 6 digits would turn
    1700000054.0 into 1.7e+09)."""
    return "never" if t is None else f"{t:.6f}"


def statuses(mode: Any) -> list:
    """Every status of an AttitudeMode."""
    name = mode.node.get_name()
    problems = mode.inputs.problems(mode.node.diagnostics.clock_stalled_s())
    values = mode.inputs.key_values() + mode.counters.key_values()
    values += [("waiting_samples", str(len(mode._pending))),
               ("buffered_commands", str(len(mode._controls)))]
    out = [diag.make_status(f"{name}: inputs", diag.WARN if problems else diag.OK,
                            "; ".join(problems) if problems else "inputs OK", values,
                            hardware_id=mode.angle_name)]
    now = mode.node._now()
    for ch in mode.channels:
        out.append(_channel_status(mode, name, ch, now))
        out.append(_actuator_status(mode, name, ch))
    return out

def _channel_status(mode: Any, name: str, ch: Any, now: float):
    res = ch.result
    vals: list[tuple[str, Any]] = [
        ("beta2", math.nan if res is None else res.beta2),
        ("gate_threshold", mode.gate.threshold(mode.model.m) if res is None
         else res.threshold),
        ("alarm_state", "never updated" if res is None
         else _ALARM_NAMES.get(res.alarm_state, str(res.alarm_state))),
        ("alarm_since_s", _time(ch.alarm_since)),
        ("last_stamp_s", _time(ch.last_t)),
        ("u", ch.last_u),
        ("accuracy_J", ch.kf.accuracy()),
    ]
    vals += ch.counters.key_values()
    vals += [(f"{ch.name}.{nm}", float(v))
             for nm, v in zip(mode.model.state_names, ch.kf.x)]
    since = math.nan if ch.last_step_clock is None else now - ch.last_step_clock
    if ch.kf.alarm_active and ch.last_t is not None:
        level, text = diag.WARN, (f"innovation alarm since t={ch.alarm_since:.3f} s (the "
                                  "measurements disagree with the model)")
    else:
        level, text = diag.update_freshness(None if ch.last_step_clock is None else since,
                                            mode.p["stale_after_s"])
    return diag.make_status(f"{name}: channel {ch.name}", level, text, vals,
                            hardware_id=f"{mode.angle_name} {ch.name}")

def _actuator_status(mode: Any, name: str, ch: Any):
    c = mode.config
    ev = ch.event
    w = ch.monitor.last_window
    vals: list[tuple[str, Any]] = [
        ("action", "switch_to_reserve" if ev is not None else "none"),
        ("threshold", c.threshold), ("window_s", c.window_s),
        ("windows_closed", ch.windows_closed), ("windows_evaluated", ch.windows_evaluated),
        ("last_window_mean", None if w is None else w.mean),
        ("last_window_std", None if w is None else w.std),
        ("last_window_end_s", _time(None if w is None else w.end_t)),
        ("last_window_evaluated", None if w is None else w.evaluated),
    ]
    if ev is not None:
        vals += [("event_t_s", _time(ev.t)), ("event_window_start_s", _time(ev.window_start_t)),
                 ("event_window_end_s", _time(ev.window_end_t)), ("event_mean", ev.mean),
                 ("event_std", ev.std), ("event_samples", ev.samples)]
        level, text = diag.ERROR, f"switch to reserve: {ev.message()}"
    elif w is None:
        level, text = diag.OK, "no actuator fault (no zero-control window closed yet)"
    else:
        note = "" if w.evaluated else ", not evaluated: estimate too uncertain"
        level, text = diag.OK, (f"no actuator fault (last window mean {w.mean:.3g} "
                                f"rad/s^2{note})")
    return diag.make_status(f"{name}: actuator {ch.name}", level, text, vals,
                            hardware_id=f"actuator {ch.name}")


# --------------------------------------------------------------------------- the event

def publish_record(mode: Any, record: dict) -> None:
    """A JSON record on fdi/actuator_event (latched)."""
    record = {"node": mode.node.get_fully_qualified_name(), **record}
    mode.pub_event.publish(mode._String(data=json.dumps(record, sort_keys=True,
                                                        allow_nan=False)))


def on_event(mode: Any, ch: Any, event: Any) -> None:
    """An actuator event of channel ``ch``: latched, logged, published, diagnosed at once."""
    ch.event = event
    mode.node.get_logger().error(f"{event.message()} (t={event.t:.3f} s, window "
                                 f"{event.window_start_t:.3f} .. {event.window_end_t:.3f} s)")
    publish_record(mode, {**event.as_dict(), "message": event.message()})
    mode.node.diagnostics.publish_now()


def on_reset(mode: Any, request: Any, response: Any) -> Any:
    """The ~/reset_actuator service: re-arm the monitors that latched an event."""
    axes = [ch.name for ch in mode.channels if ch.event is not None]
    for ch in mode.channels:
        if ch.event is not None:
            ch.event = None
            ch.monitor.reset()
    if axes:
        publish_record(mode, {"action": "reset", "axes": axes})
        mode.node.get_logger().warning(
            f"actuator monitor re-armed on axis {', '.join(axes)} (reset_actuator)")
        response.message = f"actuator monitor re-armed on axis {', '.join(axes)}"
        mode.node.diagnostics.publish_now()
    else:
        response.message = "no actuator event latched"
    response.success = True
    return response
