"""``flight-fdi vote BAG``: the triple-IMU voter on a recorded bag, without a ROS graph.

Reads sensor_msgs/Imu on /imu1/data, /imu2/data, /imu3/data, matches the samples by header stamp
and runs the voter engine that voter_node runs (flight_fdi.core.voter_core: time and mounting
alignment, the per-unit offsets learnt in the first seconds, window means, the table's bounds,
the seed's truth table, confirmation and latched isolation). Prints per quantity the status
timeline, every isolation with its time and IMU, the selected IMU over time and counts; ``--json``
prints one object with ``decisions``, ``fraction_by_status`` (healthy, marginal, single_fault,
multiple_fault: over all quantities and decisions), ``isolations`` [{t_s, quantity, imu}] and
``selected`` [{t_s, imu}] (the selection from t_s on). Times are seconds from the first message
of the bag. Without ``--thresholds`` the table shipped for the Xsens DOT recordings
(config/voter_thresholds_mimu.json) is used.
"""
from __future__ import annotations

import argparse
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

DEFAULT_TABLE = Path(__file__).resolve().parents[2] / "config" / "voter_thresholds_mimu.json"
STATUS_KEYS = ("healthy", "marginal", "single_fault", "multiple_fault")


def register(sub: argparse._SubParsersAction) -> None:
    from flight_fdi.core.voter_core import DEFAULT_CONFIRM_S, DEFAULT_RELEASE_WINDOWS

    p = sub.add_parser("vote", help="run the triple-IMU voter on a bag (no ROS graph)",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="bag with /imu1/data, /imu2/data, /imu3/data (sensor_msgs/Imu)")
    p.add_argument("--thresholds", metavar="FILE", default=None,
                   help="threshold table from flight-fdi voter-calibrate (default: the shipped "
                        "table for the Xsens DOT recordings)")
    p.add_argument("--confirm-s", type=float, default=DEFAULT_CONFIRM_S, metavar="S",
                   help="a single fault must persist this long to isolate an IMU "
                        f"(default {DEFAULT_CONFIRM_S:g}; 0: one decision)")
    p.add_argument("--release-windows", type=int, default=DEFAULT_RELEASE_WINDOWS, metavar="K",
                   help="healthy windows in a row that release an isolation (0: never; "
                        f"default {DEFAULT_RELEASE_WINDOWS})")
    p.add_argument("--time-offsets", default=None, metavar="T2,T3",
                   help="time offsets of IMU2 and IMU3 against IMU1 in seconds (default: the "
                        "table's, or estimated at start-up when the table says so)")
    p.add_argument("--topics", default="/imu1/data,/imu2/data,/imu3/data", metavar="A,B,C")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    p.set_defaults(func=run)


def confirm_decisions(confirm_s: float, rate_hz: float) -> int:
    """Decisions of a confirmation time (at least one)."""
    return max(1, int(math.ceil(confirm_s * rate_hz - 1e-9)))


def vote_bag(path: str, table, confirm_s: float, release_windows: int, time_offsets=None,
             topics=("/imu1/data", "/imu2/data", "/imu3/data")) -> dict[str, Any]:
    """Run the voter over a bag; plain-data result (see the module docstring)."""
    from flight_fdi.bagio.imu_reader import read_imu_triples
    from flight_fdi.core.voter_core import VoterCore

    data = read_imu_triples(path, topics)
    core = VoterCore(table, confirm_decisions(confirm_s, table.rate_hz), release_windows,
                     time_offsets_s=time_offsets)
    parts = [core.push(data.stamp_ns, data.P), core.finish()]
    shift = (int(data.stamp_ns[0]) - data.first_ns) * 1e-9
    return summarize(core, parts, shift, data)


def summarize(core, parts, shift: float, data=None) -> dict[str, Any]:
    """The result document from the engine's decisions (``shift``: flight time -> bag time)."""
    from flight_fdi.core.voter_align import mounting_summary
    from flight_fdi.core.voter_core import select

    qs = list(core.table.quantities)
    status = np.concatenate([d.status for d in parts])
    t = np.concatenate([d.t_flight for d in parts]) + shift
    events = [e for d in parts for e in d.events]
    n = int(status.shape[0])
    frac = {k: (float(np.mean(status == i)) if n else 0.0) for i, k in enumerate(STATUS_KEYS)}
    isolations, releases, selected = [], [], []
    current = 1
    isolated = [0] * len(qs)
    if n:
        selected.append({"t_s": round(float(t[0]), 6), "imu": 1})
    for te, q, old, new in events:
        isolated[q] = new
        item = {"t_s": round(te + shift, 6), "quantity": qs[q], "imu": int(new or old)}
        (isolations if new else releases).append(item)
        nxt = select(isolated, current)
        if nxt != current:
            current = nxt
            selected.append({"t_s": round(te + shift, 6), "imu": int(nxt)})
    timeline = {}
    for iq, q in enumerate(qs):
        timeline[q] = _runs(t, status[:, iq]) if n else []
    out = {"decisions": n, "fraction_by_status": frac, "isolations": isolations,
           "releases": releases, "selected": selected, "timeline": timeline,
           "first_decision_s": round(float(t[0]), 6) if n else None,
           "time_offsets_s": None if core.tau is None else [round(float(v), 6) for v in core.tau],
           "mounting": mounting_summary(core.model.mounting),
           "table": {"alpha": core.table.alpha, "window": core.table.window,
                     "rate_hz": core.table.rate_hz, "learn_s": core.model.learn_s,
                     "prefilter": core.model.prefilter, "baseline": core.model.baseline,
                     "linear": sorted((core.model.linear or {}).get("coef", {})),
                     "offset_blocks": core.model.offset_blocks,
                     "sequential": sorted((core.model.sequential or {}).get("threshold", {}))}}
    if data is not None:
        out["triples"] = int(data.stamp_ns.size)
        out["dropped"] = {k: v for k, v in data.dropped.items() if v}
    return out


def _runs(t: np.ndarray, s: np.ndarray) -> list[dict[str, Any]]:
    """Runs of equal status: [{t_s, status, decisions}]."""
    cut = np.flatnonzero(np.diff(s)) + 1
    starts = np.concatenate([[0], cut])
    ends = np.concatenate([cut, [s.size]])
    return [{"t_s": round(float(t[a]), 6), "status": STATUS_KEYS[int(s[a])],
             "decisions": int(b - a)} for a, b in zip(starts, ends)]


def _parse_offsets(text: str | None):
    from flight_fdi.cli.errors import CliError

    if text is None:
        return None
    try:
        vals = [float(v) for v in text.split(",")]
    except ValueError:
        raise CliError(f"--time-offsets: {text!r} is not two numbers T2,T3") from None
    if len(vals) != 2 or not all(math.isfinite(v) and abs(v) < 10 for v in vals):
        raise CliError(f"--time-offsets: give two offsets in seconds (|T| < 10), got {text!r}")
    return [0.0] + vals


def run(args: argparse.Namespace) -> int:
    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.voting import load_table

    if not (math.isfinite(args.confirm_s) and args.confirm_s >= 0):
        raise CliError(f"--confirm-s must be >= 0, got {args.confirm_s!r}")
    if args.release_windows < 0:
        raise CliError(f"--release-windows must be >= 0, got {args.release_windows}")
    topics = tuple(t.strip() for t in args.topics.split(","))
    if len(topics) != 3 or len(set(topics)) != 3:
        raise CliError(f"--topics: give three different topics, got {args.topics!r}")
    table = load_table(args.thresholds or DEFAULT_TABLE)
    res = vote_bag(args.bag, table, args.confirm_s, args.release_windows,
                   _parse_offsets(args.time_offsets), topics)
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print_text(res)
    return 0


def print_text(res: dict[str, Any]) -> None:
    tau = res["time_offsets_s"]
    print(f"{res['decisions']} decisions from {res['first_decision_s']} s "
          f"({res['triples']} triples); time offsets IMU2/IMU3: "
          + ("-" if tau is None else f"{1e3 * tau[1]:.1f} / {1e3 * tau[2]:.1f} ms"))
    for key, m in res["mounting"].items():
        print(f"mounting {key}: rotation {m['rotation_deg']} deg, scale {m['scale_pct']} %")
    tab = res["table"]
    print(f"offset baseline: {tab['baseline']}; linear model on: "
          + (", ".join(tab["linear"]) or "-") + "; sequential detector on: "
          + (", ".join(tab["sequential"]) or "-"))
    print("status (share of decisions): " + ", ".join(
        f"{k} {100 * v:.2f}%" for k, v in res["fraction_by_status"].items()))
    for q, runs in res["timeline"].items():
        text = ", ".join(f"{r['t_s']:.2f} {r['status']}" for r in runs[:12])
        more = f" ... ({len(runs)} runs)" if len(runs) > 12 else ""
        print(f"  {q:<8} {text}{more}")
    print(f"isolations: {len(res['isolations'])}")
    for i in res["isolations"]:
        print(f"  {i['t_s']:.3f} s  IMU{i['imu']} on {i['quantity']}")
    print("selected: " + ", ".join(f"IMU{s['imu']} from {s['t_s']:.3f} s"
                                   for s in res["selected"]))
    if res.get("dropped"):
        print("dropped: " + ", ".join(f"{k} {v}" for k, v in res["dropped"].items()))
