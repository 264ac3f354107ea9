"""``flight-fdi calibrate --model ins3d --grade FILE.yaml``: the GLR thresholds of a custom IMU
grade, calibrated on nominal flights simulated with its noise (flight_fdi/eval/calibrate3d.py,
docs/ins3d.md "Calibrating a grade file").

N seeded nominal flights (seeds S .. S+N-1, the profiles in turn) are simulated with the grade's
values and analysed as ``analyze --model ins3d --grade FILE`` does; each threshold is set from
the distribution of the flights' largest GLR so that a nominal flight exceeds any of them with
probability at most the --false-isolation target P: per hypothesis (the 12 IMU steps / ramps
and 3 GNSS jumps: 0.75 P / 15 each, the isolator uses these) and per kind (P / 4 each; the
outliers' is used, the others are the fall-back), or with --per-kind per kind only. Flights
of another length than 30 min are moved to 30 min by the length rule (glr3d.growth_of); the
analysis raises the thresholds by the same rule for longer flights. From the same flights
the seed method's episode probability (``seed_episode_probability``: what its persistent J
episode's peak must fall below for the seed method to declare a flight the GLR finds clean) is
set so that at most the --seed-declaration target of them would be declared (never above the
default 1e-6). The grade file (or -o FILE) is written back with a ``thresholds:`` block, the
``seed_episode_probability``, a comment and a ``calibration`` record (flights, seeds, targets,
date, the rates reached on these flights with their 95 % intervals).
Cost: a 30-min flight (simulation and analysis) ~1.6 s of one core; 200 of them on 2 workers
3.5-6 min on the shared 2-core machine at load 5-7 (docs/ins3d.md).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from flight_fdi.cli.errors import CliError


def register(sub: argparse._SubParsersAction) -> None:
    from flight_fdi.cli.batch import add_engine_options
    from flight_fdi.core.ins3d.glr3d import CALIBRATED_LENGTH_S
    from flight_fdi.eval.calibrate3d import MIN_FLIGHTS, PROFILES

    p = sub.add_parser("calibrate", help="calibrate the GLR thresholds of a custom IMU grade "
                       "file on simulated nominal flights", description=__doc__,
                       formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--model", default="ins3d", metavar="MODEL",
                   help="the model whose thresholds are calibrated (ins3d, the default)")
    p.add_argument("--grade", required=True, metavar="FILE.yaml",
                   help="the YAML grade file (docs/ins3d.md, 'IMU grade from a file')")
    p.add_argument("--flights", type=int, default=200, metavar="N",
                   help=f"nominal flights (default 200, at least {MIN_FLIGHTS})")
    p.add_argument("--seed", type=int, default=1000, metavar="S",
                   help="seed of the first flight; flight i has seed S+i (default 1000)")
    p.add_argument("--false-isolation", type=float, default=0.01, metavar="P",
                   help="per-flight false-isolation target (default 0.01)")
    p.add_argument("--seed-declaration", type=float, default=None, metavar="P",
                   help="per-flight target of seed-method declarations on nominal flights "
                        "(default: the --false-isolation target)")
    p.add_argument("--profile", action="append", default=None, metavar="PROFILE",
                   help="trajectory profile, repeatable or comma-separated, taken in turn "
                        f"(default {','.join(PROFILES)})")
    p.add_argument("--duration", type=float, default=CALIBRATED_LENGTH_S, metavar="S",
                   help=f"flight length, 60..10800 s (default {CALIBRATED_LENGTH_S:g}: the "
                        "length the thresholds are stated for; others are moved by the "
                        "length rule)")
    p.add_argument("--per-kind", action="store_true",
                   help="calibrate one threshold per hypothesis kind only (step, ramp, jump, "
                        "outliers: a quarter of the target each), as before per-hypothesis "
                        "thresholds existed; default: per hypothesis too")
    p.add_argument("-o", "--output", default=None, metavar="OUT.yaml",
                   help="write the calibrated grade file here (default: the grade file itself)")
    add_engine_options(p, "--jobs", "--workers")
    p.add_argument("--json", action="store_true",
                   help="print the calibration as JSON (thresholds, spread, rate, maxima)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.set_defaults(func=run)


def _profiles(args: argparse.Namespace) -> tuple[str, ...]:
    from flight_fdi.eval.calibrate3d import PROFILES
    from flight_fdi.sim.trajectory import PROFILES as ALL

    given = [s.strip() for item in (args.profile or []) for s in item.split(",") if s.strip()]
    for p in given:
        if p not in ALL:
            raise CliError(f"--profile {p!r}: unknown profile; choose from {', '.join(ALL)}")
    return tuple(given) or PROFILES


def _inputs(args: argparse.Namespace):
    """(grade, its file's text, output path, profiles) of the options, checked."""
    from flight_fdi.core.errors import CoreError
    from flight_fdi.core.ins3d.grade_file import load_grade
    from flight_fdi.core.ins3d.grades import GRADES
    from flight_fdi.eval.calibrate3d import MIN_FLIGHTS

    if args.model != "ins3d":
        raise CliError(f"--model {args.model!r}: only ins3d has calibrated GLR thresholds")
    if args.flights < MIN_FLIGHTS:
        raise CliError(f"--flights must be at least {MIN_FLIGHTS}, got {args.flights}")
    if not 0.0 < args.false_isolation < 1.0:
        raise CliError(f"--false-isolation must be within (0, 1), got {args.false_isolation:g}")
    if args.seed_declaration is not None and not 0.0 < args.seed_declaration < 1.0:
        raise CliError(f"--seed-declaration must be within (0, 1), got "
                       f"{args.seed_declaration:g}")
    if args.seed < 0:
        raise CliError(f"--seed must be >= 0, got {args.seed}")
    profiles = _profiles(args)
    if args.grade in GRADES:
        raise CliError(f"--grade {args.grade!r} is a preset (its thresholds are calibrated: "
                       f"glr3d.THRESHOLDS_BY_GRADE); give a YAML grade file (base: {args.grade})")
    try:
        grade = load_grade(args.grade)
    except CoreError as exc:
        raise CliError(f"--grade: {exc}") from None
    text = Path(args.grade).read_text(encoding="utf-8")
    out = Path(args.output or args.grade)
    if not out.parent.is_dir():
        raise CliError(f"-o: cannot write {out}: directory '{out.parent}' does not exist")
    return grade, text, out, profiles


def run(args: argparse.Namespace) -> int:
    from flight_fdi.campaign.engine import default_workers
    from flight_fdi.cli.batch import engine_spec
    from flight_fdi.core.ins3d.grade_file import load_grade, with_thresholds
    from flight_fdi.eval.calibrate3d import run_calibration

    grade, text, out, profiles = _inputs(args)
    spec = engine_spec(args)
    cal = run_calibration(grade, args.flights, args.seed, args.false_isolation, profiles,
                          args.duration, jobs=spec.workers or default_workers(),
                          progress=not args.no_progress, scheduler=spec.scheduler,
                          seed_target=args.seed_declaration, per_hypothesis=not args.per_kind)
    new = with_thresholds(text, cal.thresholds, cal.metadata(), cal.episode_probability)
    tmp = out.with_name(out.name + ".tmp")
    try:
        tmp.write_text(new, encoding="utf-8")
        load_grade(tmp)                         # what was written loads (and nothing is lost)
        tmp.replace(out)
    except OSError as exc:
        raise CliError(f"cannot write {out}: {exc.strerror or exc}") from None
    _print(cal, out, args.json)
    return 0


def _print(cal, out: Path, as_json: bool) -> None:
    from flight_fdi.eval.calibrate3d import summary

    if as_json:
        json.dump({"grade": cal.grade.name, "output": str(out), "thresholds": cal.thresholds,
                   "seed_episode_probability": cal.episode_probability,
                   "spread": cal.spread, "calibration": cal.metadata(),
                   "summary": summary(cal.rows),
                   "summary_hypotheses": summary(cal.rows, per_hypothesis=True),
                   "elapsed_s": cal.elapsed_s, "flights": cal.rows}, sys.stdout)
        sys.stdout.write("\n")
        return
    _table(cal, summary(cal.rows), "kind")
    if cal.per_hypothesis:
        print()
        _table(cal, summary(cal.rows, per_hypothesis=True), "hypothesis")
    m = cal.metadata()
    lo, hi = m["interval95"]
    print(f"\n{m['flights']} nominal flights of {m['duration_s']:g} s in {cal.elapsed_s:.0f} s "
          f"({cal.engine}); target {100 * cal.target:g} % per flight: {m['exceeded']} of "
          f"{m['flights']} above a threshold ({100 * m['rate']:.1f} %, 95 % interval "
          f"{100 * lo:.1f}-{100 * hi:.1f} %)")
    sh = m["shares"]
    print("budget: " + (f"{100 * sh['hypothesis']:.3g} % per hypothesis (15), outliers "
                        f"{100 * sh['outliers']:.3g} %; the kinds' step / ramp / jump are "
                        "the fall-back" if cal.per_hypothesis else
                        f"{100 * sh['step']:.3g} % per kind (--per-kind)")
          + f"; thresholds for 30-min flights (maxima moved from {m['duration_s']:g} s by "
          "the length rule)")
    sd = m["seed"]
    lo, hi = sd["interval95"]
    print(f"seed method: episode probability {sd['episode_probability']:.3g} (target "
          f"{100 * sd['target']:g} %): {sd['declared']} of {m['flights']} flights declared "
          f"({100 * sd['rate']:.1f} %, 95 % interval {100 * lo:.1f}-{100 * hi:.1f} %; with the "
          f"default {sd['default']:g}: {sd['declared_default']}); wrote {out}")


def _table(cal, summ: dict, what: str) -> None:
    """The flights' maxima (at their length), the calibrated threshold (for 30 min), its
    bootstrap spread and the grade's threshold before (``glr3d.threshold_of``: a
    hypothesis' own, else its kind's) per kind or per hypothesis."""
    from flight_fdi.core.ins3d.glr3d import hypotheses, threshold_of
    from flight_fdi.core.ins3d.grade_file import grade_thresholds

    before, w = grade_thresholds(cal.grade), max(9, max(len(k) for k in summ))
    by_name = {h.name: h for h in hypotheses(3)}
    print(f"{what:<{w}} {'median':>7} {'90 %':>7} {'largest':>8} {'threshold':>10} "
          f"{'spread':>7} {'before':>7}")
    for k, s in summ.items():
        old = threshold_of(before, by_name[k]) if k in by_name else before[k]
        print(f"{k:<{w}} {s['median']:7.1f} {s['q90']:7.1f} {s['max']:8.1f} "
              f"{cal.thresholds[k]:10.2f} {cal.spread[k]:7.2f} {old:7.1f}")
