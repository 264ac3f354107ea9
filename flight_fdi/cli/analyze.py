"""``flight-fdi analyze BAG``: the whole post-flight analysis of an input bag, without a ROS graph.

Reads INS and reference velocity from the bag, runs the forward filter with its gate, the backward
information filter, the seed method (chi-square with UDU^T localization, Fisher test) and the GLR
isolator, and prints a short table, or with ``--json`` one JSON object.
"""
from __future__ import annotations

import argparse
import json
import math
import sys

from flight_fdi.cli.errors import CliError


def add_analysis_options(p: argparse.ArgumentParser) -> None:
    """Options shared by ``analyze``, ``run`` and ``report`` (one set of names for one
    configuration)."""
    p.add_argument("--channel", default="x", choices=("x", "y"), help="velocity axis (default x)")
    p.add_argument("--model", default="ins_channel",
                   help="built-in model name or a model YAML file (default ins_channel)")
    add_gate_options(p)
    p.add_argument("--gate-action", default="flag", choices=("flag", "reject"),
                   help="fuse (flag) or drop (reject) a gated sample (default flag)")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")


def add_gate_options(p: argparse.ArgumentParser) -> None:
    """The in-flight gate and alarm options (read by :func:`analysis_config`)."""
    p.add_argument("--gate-rule", default="chi2", choices=("chi2", "seed"),
                   help="beta^2 gate: chi-square quantile or the seed's m + 3 sqrt(2m) (default chi2)")
    p.add_argument("--gate-probability", type=float, default=1e-3,
                   help="per-sample false-alarm probability of the chi2 gate (default 1e-3)")
    p.add_argument("--alarm", default="3/5", metavar="M/N",
                   help="alarm when M of the last N samples exceed the gate (default 3/5)")


def analysis_config(args: argparse.Namespace):
    """AnalysisConfig from the shared options (validated by the core)."""
    from flight_fdi.core.analysis import AnalysisConfig
    from flight_fdi.core.kalman import GateConfig

    try:
        m_txt, n_txt = args.alarm.split("/")
        alarm_m, alarm_n = int(m_txt), int(n_txt)
    except ValueError:
        raise CliError(f"--alarm must look like M/N (e.g. 3/5), got {args.alarm!r}") from None
    gate = GateConfig(rule=args.gate_rule, probability=args.gate_probability,
                      alarm_m=alarm_m, alarm_n=alarm_n, action=args.gate_action)
    return AnalysisConfig(gate=gate, jobs=getattr(args, "jobs", 1))


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("analyze", help="post-flight analysis of a bag without a ROS graph",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("bag", help="rosbag2 bag (folder) with /ins/velocity and /reference/velocity")
    add_analysis_options(p)
    p.add_argument("--jobs", type=int, choices=(1, 2), default=default_jobs(),
                   help="processes to use: with 2 the backward pass runs beside the forward "
                        "pass, same results (default 2 on a machine with 2 or more cores)")
    p.set_defaults(func=run)


def default_jobs() -> int:
    import os

    return 2 if (os.cpu_count() or 1) >= 2 else 1


def analyze_bag(bag: str, args: argparse.Namespace) -> dict:
    from flight_fdi.bagio import read_flight
    from flight_fdi.core.forked import ForkedCall

    # with two jobs the bag is read in a forked child while this process imports the estimation
    # core (SciPy: ~0.5 s); errors of either side come out here, the child never outlives this
    with ForkedCall(read_flight, (bag,), {"channel": args.channel, "with_truth": False},
                    fork=getattr(args, "jobs", 1) == 2) as job:
        from flight_fdi.core.analysis import analyze_flight
        from flight_fdi.core.models import get_model

        config = analysis_config(args)
        model = get_model(args.model)
        flight = job.result()
    # times relative to the first INS/reference message, exact from integer nanoseconds
    return analyze_flight(model, flight.ins_rel_s, flight.v_ins, flight.ref_rel_s, flight.v_ref,
                          flight.r_ref, config, bag=str(bag), channel=args.channel, t0=0.0)


def _fmt(value, spec: str = ".3g", none: str = "-") -> str:
    if value is None or (isinstance(value, float) and math.isnan(value)):
        return none
    return format(value, spec)


def format_result(res: dict) -> str:
    """A short human-readable table of an analysis result."""
    inf = res["in_flight"]
    post = res["post_flight"]
    seed = post["seed_method"]
    glr = post["glr"]
    lines = [
        f"bag {res['bag']}  channel {res['channel']}  {res['duration_s']:.1f} s  "
        f"{res['samples']} samples",
        "",
        f"in flight: gate beta2 > {inf['gate_threshold']:.3g}, exceeded on "
        f"{100 * inf['exceed_fraction']:.2f}% of samples; first alarm at "
        f"{_fmt(inf['first_alarm_s'], '.1f')} s; {len(inf['alarms'])} alarm(s)",
    ]
    for a in inf["alarms"][:5]:
        lines.append(f"  alarm {a['start_s']:9.1f} .. {a['end_s']:9.1f} s  peak beta2 "
                     f"{a['peak_beta2']:.3g}")
    if len(inf["alarms"]) > 5:
        lines.append(f"  ... {len(inf['alarms']) - 5} more")
    lines += [
        "",
        f"post flight: {post['verdict'].upper()}  element {_fmt(post['element'], 's')}  onset "
        f"{_fmt(post['onset_s'], '.1f')} s  magnitude {_fmt(post['magnitude'], '.4g')}  "
        f"(methods {'agree' if post['methods_agree'] else 'disagree'})",
        "",
        f"seed method (chi2/UDU^T + Fisher): {seed['verdict']}, element "
        f"{_fmt(seed['element'], 's')}",
        f"  {'element':<16}{'J peak':>10}{'gamma2':>9}{'F peak':>10}{'eta2':>8}{'exceed':>9}{'dof':>5}",
    ]
    for e in seed["elements"]:
        lines.append(f"  {e['name']:<16}{_fmt(e['J_peak']):>10}{_fmt(e['gamma2']):>9}"
                     f"{_fmt(e['F_peak']):>10}{_fmt(e['eta2']):>8}"
                     f"{100 * e['exceed_fraction']:>8.1f}%{e['dof']:>5}")
    lines += [
        f"GLR: {glr['hypothesis']}  onset {_fmt(glr['onset_s'], '.1f')} s  magnitude "
        f"{_fmt(glr['magnitude'], '.4g')}  statistic {glr['statistic']:.4g} "
        f"(threshold {glr['threshold']:.4g})",
    ]
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    res = analyze_bag(args.bag, args)
    if args.json:
        json.dump(res, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(format_result(res))
    return 0
