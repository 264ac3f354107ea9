"""``/diagnostics`` of filter_node in the attitude mode: the inputs, per axis the channel
(beta2, alarm, accuracy, state) and the actuator monitor (the "switch to reserve" event)."""
from __future__ import annotations

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
