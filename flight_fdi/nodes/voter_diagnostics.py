"""The /diagnostics statuses of voter_node: inputs, the vote, the threshold table."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..core.voting import HEALTHY, MULTIPLE_FAULT, PAIRS, SINGLE_FAULT, STATUS_NAMES
from . import diagnostics as diag


def statuses(node: Any) -> list:
    """[inputs, vote, thresholds] DiagnosticStatus of ``node`` (a VoterNode)."""
    name = node.get_name()
    return [_inputs(node, name), _vote(node, name), _table(node, name)]


def _inputs(node: Any, name: str):
    problems = node.inputs.problems()
    values = node.inputs.key_values() + node.counters.key_values()
    values += [(f"waiting_imu{k + 1}", str(len(q))) for k, q in enumerate(node._queues)]
    inputs = diag.make_status(
        f"{name}: inputs", diag.WARN if problems else diag.OK,
        "; ".join(problems) if problems else "inputs OK", values, hardware_id=name)
    return inputs


def _vote(node: Any, name: str):
    v = node.last_vote
    vals: list[tuple[str, Any]] = [("selected_imu", node.selected),
                                   ("isolated", node._isolated_text())]
    if v is None:
        level, text = diag.WARN, ("no vote yet (waiting for matched triples)"
                                  if node.model.learn_s <= 0 or node._t0 is None else
                                  f"learning offsets ({node.model.learn_s:g} s)")
    else:
        vals.append(("flight_time_s", v["t_flight"]))
        for i, q in enumerate(node.quantities):
            vals.append((f"{q} status", STATUS_NAMES[int(v["status"][i])]))
            vals.append((f"{q} isolated_imu", int(node.latched[i])))
            for j, pair in enumerate(PAIRS):
                vals.append((f"{q} {pair} mean", float(v["mean"][i, j])))
                vals.append((f"{q} {pair} bounds", [float(node._lower[i, j]),
                                                     float(node._upper[i, j])]))
        worst = int(v["status"].max())
        isolated = bool(np.any(node.latched))
        if worst == MULTIPLE_FAULT:
            level = diag.ERROR
            bad = [q for q, s in zip(node.quantities, v["status"]) if s == MULTIPLE_FAULT]
            text = f"multiple fault on {', '.join(bad)}: cannot isolate; output IMU" \
                   f"{node.selected}"
        elif isolated:
            level = diag.WARN
            text = f"isolated {node._isolated_text()}; output IMU{node.selected}"
        elif worst == SINGLE_FAULT:
            level = diag.WARN
            text = f"single fault being confirmed; output IMU{node.selected}"
        elif worst > HEALTHY:
            level = diag.WARN
            bad = [q for q, s in zip(node.quantities, v["status"]) if s != HEALTHY]
            text = f"marginal on {', '.join(bad)}; output IMU{node.selected}"
        else:
            level, text = diag.OK, f"healthy; output IMU{node.selected}"
    return diag.make_status(f"{name}: vote", level, text, vals, hardware_id=name)


def _table(node: Any, name: str):
    v = node.last_vote

    now_t = max((t for t in node._last_t if t is not None), default=None)
    rate = node._triple_rate.rate(now_t) if now_t is not None else 0.0
    tvals = [("file", node.p["thresholds_file"]), ("window", node.window),
             ("rate_hz", node.table.rate_hz), ("alpha", node.table.alpha),
             ("duration_s", node.table.duration_s),
             ("segment_start_s", float(node.table.grid[node.table.segment_index(
                 v["t_flight"])]) if v is not None else 0.0),
             ("confirm_decisions", node.confirm), ("learn_s", node.model.learn_s),
             ("time_offsets_s", [] if node.core.tau is None
              else [float(x) for x in node.core.tau]),
             ("triple_rate_hz", rate)]
    level, text = diag.OK, "threshold table loaded"
    if v is not None and v["t_flight"] > node.table.duration_s:
        level, text = diag.WARN, (f"flight time {v['t_flight']:.1f} s beyond the calibrated "
                                  f"{node.table.duration_s:g} s: last segment's bounds used")
    if rate > 0 and node.counters["matched_triples"] > node.window and \
            abs(rate / node.table.rate_hz - 1.0) > 0.1:
        level, text = diag.WARN, (f"triples arrive at {rate:.1f} Hz, the table is calibrated "
                                  f"for {node.table.rate_hz:g} Hz")
    return diag.make_status(f"{name}: thresholds", level, text, tvals, hardware_id=name)
