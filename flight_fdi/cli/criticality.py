"""``flight-fdi criticality --model FILE``: sensor criticality of a model with redundant sensors.

For every set of failed sensors, the steady-state estimation accuracy J = tr(D P) of the Kalman
filter in the two modes of seed 001: KF2 (the anomaly covariance Gamma of the failed rows is
known) and AF (the failed rows are excluded). Sensors are classed as vital / less important by
the growth of J when each fails alone; fault sets as admissible / inadmissible against the
model's bound. The model file is a model YAML with a ``redundancy:`` section
(docs/criticality.md; example: config/models/redundant_5ch.yaml).
"""
from __future__ import annotations

import argparse
import json
import math


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("criticality", help="J = tr(D P) for every set of failed redundant sensors",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", required=True, metavar="FILE",
                   help="model YAML with a redundancy: section")
    p.add_argument("--max-failed", type=int, default=None, metavar="K",
                   help="enumerate fault sets of at most K failed sensors (default: all)")
    p.add_argument("--bound", type=float, default=None,
                   help="override the model's admissibility bound on J")
    p.add_argument("--vital-threshold", type=float, default=None, metavar="G",
                   help="override the relative growth of J that makes a sensor vital")
    p.add_argument("--json", action="store_true", help="print one JSON object instead of a table")
    p.set_defaults(func=run)


def _fmt(x: float) -> str:
    return "inf" if not math.isfinite(x) else f"{x:.6e}"


def _pct(x: float) -> str:
    return "inf" if not math.isfinite(x) else f"{100 * x:+.3f}%"


def table_text(res) -> str:
    """The human-readable report of a CriticalityResult."""
    names = res.sensors
    failed_txt = [",".join(names[k] for k in s.failed) or "-" for s in res.sets]
    w = max([6] + [len(f) for f in failed_txt])
    pw = max(7, len(names))
    lines = [f"model {res.model_name}: {len(names)} sensors "
             + ", ".join(f"{k + 1}={n}" for k, n in enumerate(names)),
             f"J = tr(D P), steady state (a posteriori); pattern: 1 = working, 0 = failed; "
             f"bound {res.bound:.6g}",
             f"{'pattern':<{pw}}  {'failed':<{w}} {'J KF2':>13} {'growth':>11} "
             f"{'adm':>3}  {'J AF':>13} {'growth':>11} {'adm':>3}"]
    for s, failed in zip(res.sets, failed_txt):
        lines.append(f"{s.pattern:<{pw}}  {failed:<{w}} {_fmt(s.J['kf2']):>13} "
                     f"{_pct(s.growth['kf2']):>11} {'yes' if s.admissible['kf2'] else 'no':>3}  "
                     f"{_fmt(s.J['af']):>13} {_pct(s.growth['af']):>11} "
                     f"{'yes' if s.admissible['af'] else 'no':>3}")
    lines.append("")
    for mode, label in (("kf2", "KF2 (anomaly covariance known)"),
                        ("af", "AF (failed rows excluded)")):
        vital = ", ".join(res.vital[mode]) or "none"
        less = ", ".join(res.less_important[mode]) or "none"
        adm = " ".join(f"[{s.pattern}]" for s in res.admissible_sets(mode)) or "none"
        inadm = " ".join(f"[{s.pattern}]" for s in res.inadmissible_sets(mode)) or "none"
        lines += [f"{label}:",
                  f"  vital (single failure grows J by >= {100 * res.vital_threshold:g}%): "
                  f"{vital}",
                  f"  less important: {less}",
                  f"  admissible fault sets (J <= {res.bound:.6g}): {adm}",
                  f"  inadmissible fault sets: {inadm}"]
    lines.append("KF2 at least as accurate as AF for every fault set: "
                 + ("yes" if res.kf2_never_worse() else "NO"))
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    from dataclasses import replace

    from flight_fdi.cli.errors import CliError
    from flight_fdi.core.redundancy import criticality, load_redundant_model

    model, spec = load_redundant_model(args.model)
    if args.bound is not None:
        if not (math.isfinite(args.bound) and args.bound > 0):
            raise CliError(f"--bound must be a positive number, got {args.bound!r}")
        spec = replace(spec, bound=float(args.bound))
    if args.vital_threshold is not None:
        if not (math.isfinite(args.vital_threshold) and args.vital_threshold > 0):
            raise CliError(f"--vital-threshold must be a positive number, got "
                           f"{args.vital_threshold!r}")
        spec = replace(spec, vital_threshold=float(args.vital_threshold))
    if args.max_failed is not None and not 0 <= args.max_failed <= len(spec.sensors):
        raise CliError(f"--max-failed must be in 0..{len(spec.sensors)}, got {args.max_failed}")
    res = criticality(model, spec, max_failed=args.max_failed)
    if args.json:
        print(json.dumps(res.to_dict(), indent=1))
    else:
        print(table_text(res))
    return 0
