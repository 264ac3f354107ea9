"""``/diagnostics`` of filter_node in the INS velocity mode (the statuses, built from the node's
state; the attitude mode has its own in ``attitude_mode``).

Statuses
    "<node>: inputs" -- message counts, rates, staleness and every drop count; hardware_id = the
    INS topic (the monitored unit). WARN when an input is stale or never came, or when the node's
    clock stalled (use_sim_time without /clock: staleness is then judged on the wall clock).
    "<node>: channel <c>" -- beta2, threshold, alarm, accuracy J, the channel's counts and its
    state estimate as ``<c>.<state name>`` (channel y: ``y.velocity_error`` ...); hardware_id =
    "<INS topic> <c>". ERROR while the alarm is raised; WARN for ``reset_warn_s`` after a filter
    reset, with the reason; WARN when there was no update for ``stale_after_s``.
    "<node>: reference <topic>" (redundant references) -- per channel failed / excluded, failures,
    readmissions, the last row beta2; hardware_id = the reference topic.
"""
from __future__ import annotations

import math
import time
from typing import Any

from . import diagnostics as diag

_ALARM_NAMES = {0: "clear", 1: "raised", 2: "active", 3: "cleared"}


def statuses(node: Any) -> list:
    """Every status of ``node`` (a FilterNode in the INS velocity mode)."""
    name = node.get_name()
    stalled = node.diagnostics.clock_stalled_s()
    problems = node.inputs.problems(stalled)
    values = node.inputs.key_values() + node.counters.key_values()
    values.append(("waiting_reference_samples", str(len(node.sync.pending))))
    # samples held while a jump of their stamps waits for confirmation (time_jump_confirm)
    values.append(("held_ins_samples", str(node._ins_line.pending)))
    values.append(("held_reference_samples", str(sum(r.line.pending for r in node.refs))))
    inputs = diag.make_status(
        f"{name}: inputs", diag.WARN if problems else diag.OK,
        "; ".join(problems) if problems else "inputs OK", values, hardware_id=node.ins_name)
    out = [inputs] + [_channel_status(node, name, ch) for ch in node.channels]
    if node.redundant:
        out += [_reference_status(node, name, ref) for ref in node.refs]
    return out


def _channel_status(node: Any, name: str, ch: Any):
    res = ch.result
    vals: list[tuple[str, Any]] = [
        ("beta2", math.nan if res is None else res.beta2),
        ("gate_threshold", node.gate.threshold(node.model.m)),
        ("alarm_state", "never updated" if res is None
         else _ALARM_NAMES.get(res.alarm_state, str(res.alarm_state))),
        ("alarm_since_s", ch.alarm_since),
        ("last_stamp_s", ch.last_t),
        ("last_reset", "never" if ch.last_reset is None else ch.last_reset[1]),
    ]
    vals.append(("accuracy_J", ch.kf.accuracy()))
    if ch.rf is not None:
        vals.append(("rows_used", ch.rows_used))
        vals.append(("failed_references", ",".join(
            node.refs[i].name for i in ch.rf.monitor.failed_references())))
    vals += ch.counters.key_values()
    vals += [(f"{ch.name}.{nm}", float(v)) for nm, v in zip(node.model.state_names, ch.kf.x)]
    alarm = ch.kf.alarm_active and ch.last_t is not None
    since = math.nan if ch.last_step_clock is None else node._now() - ch.last_step_clock
    reset_ago = math.inf if ch.last_reset is None else time.monotonic() - ch.last_reset[0]
    if alarm:
        level, text = diag.ERROR, f"INS fault alarm since t={ch.alarm_since:.3f} s"
    elif reset_ago <= node.p["reset_warn_s"]:
        level, text = diag.WARN, f"filter reset {reset_ago:.1f} s ago: {ch.last_reset[1]}"
    else:
        level, text = diag.update_freshness(None if ch.last_step_clock is None else since,
                                            node.p["stale_after_s"])
    return diag.make_status(f"{name}: channel {ch.name}", level, text, vals,
                            hardware_id=f"{node.ins_name} {ch.name}")


def _reference_status(node: Any, name: str, ref: Any):
    """Per reference: failed / excluded on each channel, time since the failure (stamp
    time, at the channel's last update), failures, readmissions, last row beta2."""
    vals: list[tuple[str, Any]] = []
    failed_on = []
    handled = node.ref_config.mode != "nominal"
    for ch in node.channels:
        h = ch.rf.monitor.refs[ref.index]
        since = None
        if h.failed and ch.last_t is not None:
            since = ch.last_t - h.failed_since
            failed_on.append(f"{ch.name} since t={h.failed_since:.3f} s")
        vals += [(f"{ch.name}.failed", h.failed), (f"{ch.name}.excluded", h.failed and handled),
                 (f"{ch.name}.time_since_failure_s", since),
                 (f"{ch.name}.failures", h.failures),
                 (f"{ch.name}.readmissions", h.readmissions),
                 (f"{ch.name}.row_beta2", h.last_beta2)]
    vals += ref.counters.key_values()
    if failed_on:
        what = {"exclude": "excluded", "known_anomaly": "inflated",
                "nominal": "still fused"}[node.ref_config.mode]
        level, text = diag.WARN, f"failed on channel {', '.join(failed_on)} ({what})"
    else:
        level, text = diag.OK, "healthy"
    return diag.make_status(f"{name}: reference {ref.name}", level, text, vals,
                            hardware_id=ref.name)
