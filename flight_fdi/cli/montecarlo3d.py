"""``flight-fdi montecarlo --model ins3d``: the Monte Carlo study of the 3-D model on simulated
3-D flights (turns, climbs, body-axis faults, GNSS with latency and Markov noise), with the
single-axis model on the same flights beside it (flight_fdi/eval/montecarlo3d.py).

The options shared with the single-axis study keep their meaning: --nominal, --per-fault (here:
flights per fault scenario), --duration, --onset, --seed, --jobs / --workers / --scheduler,
--out, --records (and --restart: the records file resumes the 3-D study exactly as the
single-axis one), --json, --no-progress; the gate options and --glr-p-false-alarm configure the
single-axis analysis (the gate also the 3-D forward filter). --accel-levels / --gyro-levels set
the body-axis step levels when given.
"""
from __future__ import annotations

import argparse
import dataclasses
import json

from flight_fdi.cli.errors import CliError

MODELS = ("channel", "ins3d")


def add_ins3d_options(p: argparse.ArgumentParser) -> None:
    """--model and the options of the 3-D study (an argument group of ``montecarlo``)."""
    from flight_fdi.eval.montecarlo3d import GRADES, PROFILES, SCENARIOS

    p.add_argument("--model", default="channel", metavar="MODEL",
                   help="channel (the single-axis study, default) or ins3d (3-D flights, "
                        "the 3-D model beside the single-axis one)")
    g = p.add_argument_group("--model ins3d")
    g.add_argument("--grade", default="navigation", metavar="GRADE|FILE.yaml",
                   help=f"IMU grade of the flights and the analysis: a preset "
                        f"({', '.join(GRADES)}; default navigation) or a YAML grade file "
                        "(docs/ins3d.md, 'IMU grade from a file': its values and thresholds)")
    g.add_argument("--profile", default="random", metavar="PROFILE",
                   help=f"trajectory ({', '.join(PROFILES)}; random: one seeded trajectory per "
                        "flight; default random)")
    g.add_argument("--scenarios", default=None, metavar="NAME,...",
                   help="fault scenarios (default all: " + ",".join(SCENARIOS) + ")")
    g.add_argument("--level", action="append", default=[], metavar="SCENARIO=A,B,...",
                   help="levels of a scenario in its unit (mg, deg/h, mg/h, deg/h^2, m/s); "
                        "repeatable")
    g.add_argument("--gnss-latency", type=float, default=20.0, metavar="MS",
                   help="GNSS latency in ms (default 20; Markov noise: the simulator's)")
    g.add_argument("--no-single-axis", action="store_true",
                   help="do not run the single-axis model beside the 3-D one")
    g.add_argument("--ladder", action="store_true",
                   help="instead of the study: the smallest body-axis step isolated in 95 %% "
                        "per sensor and axis (descending ladder; --ladder-grades, "
                        "--ladder-runs, --ladder-rungs; --scenarios if given, else "
                        "accel_step,gyro_step) for the --grade (a preset or a grade file: its "
                        "values simulated, its thresholds used)")
    g.add_argument("--ladder-grades", default=None, metavar="GRADE|FILE.yaml,...",
                   help="grades of the ladder, presets or YAML grade files (default: --grade)")
    g.add_argument("--ladder-runs", type=int, default=10, metavar="N",
                   help="flights per rung (default 10)")
    g.add_argument("--ladder-rungs", type=int, default=5, metavar="N",
                   help="rungs at most, each half the previous level (default 5)")


def check_model(args: argparse.Namespace) -> str:
    model = args.model
    if model not in MODELS:
        raise CliError(f"--model must be one of {', '.join(MODELS)}, got {model!r}")
    return model


def _levels(args: argparse.Namespace) -> dict:
    from flight_fdi.eval.montecarlo import DEFAULT_ACCEL_LEVELS_MG, DEFAULT_GYRO_LEVELS_DEG_H
    from flight_fdi.eval.montecarlo3d import SCENARIOS

    levels = {}
    if tuple(args.accel_levels) != tuple(DEFAULT_ACCEL_LEVELS_MG):
        levels["accel_step"] = tuple(args.accel_levels)
    if tuple(args.gyro_levels) != tuple(DEFAULT_GYRO_LEVELS_DEG_H):
        levels["gyro_step"] = tuple(args.gyro_levels)
    for item in args.level:
        name, _, vals = item.partition("=")
        if name.strip() not in SCENARIOS:
            raise CliError(f"--level {item!r}: unknown scenario {name.strip()!r}; choose from "
                           f"{', '.join(SCENARIOS)}")
        try:
            levels[name.strip()] = tuple(float(v) for v in vals.split(",") if v.strip())
        except ValueError:
            raise CliError(f"--level {item!r}: expected SCENARIO=A,B,... numbers") from None
    return levels


def study_config(args: argparse.Namespace):
    """Study3DConfig from the options (validated by the evaluation package)."""
    from flight_fdi.cli.analyze import analysis_config
    from flight_fdi.eval.errors import EvalError
    from flight_fdi.eval.montecarlo3d import SCENARIOS, Study3DConfig

    if args.channel != "x":
        raise CliError("--channel belongs to the single-axis study; --model ins3d analyses "
                       "the east and north channels")
    analysis = dataclasses.replace(analysis_config(args),
                                   glr_p_false_alarm=args.glr_p_false_alarm)
    try:
        return Study3DConfig(
            nominal=args.nominal, per_scenario=args.per_fault,
            scenarios=tuple(SCENARIOS) if args.scenarios is None else
            tuple(s.strip() for s in args.scenarios.split(",") if s.strip()),
            levels=_levels(args), duration_s=args.duration, profile=args.profile,
            grade=args.grade, onset_window=tuple(args.onset),
            gnss_latency_s=args.gnss_latency / 1000.0, seed=args.seed,
            single_axis=not args.no_single_axis, analysis=analysis)
    except EvalError as exc:
        raise CliError(str(exc)) from None


def run_ins3d(args: argparse.Namespace) -> int:
    """The 3-D study (or its ladder)."""
    from flight_fdi.campaign.engine import default_workers
    from flight_fdi.cli.batch import engine_spec
    from flight_fdi.cli.montecarlo import emit_result, open_records, writable
    from flight_fdi.eval.errors import EvalError
    from flight_fdi.eval.metrics3d import format_metrics
    from flight_fdi.eval.montecarlo3d import run_study, study_settings

    config = study_config(args)
    spec = engine_spec(args)
    workers = spec.workers or default_workers()
    out = writable(args.out, "--out")
    if args.ladder:
        return _ladder(args, config, workers, spec.scheduler, out)
    try:
        with open_records(args, study_settings(config)) as records:
            result = run_study(config, jobs=workers, progress=not args.no_progress,
                               on_record=records.write if records else None,
                               scheduler=spec.scheduler,
                               done=records.done if records else None)
    except EvalError as exc:
        raise CliError(str(exc)) from None
    emit_result(result, out, args, format_metrics(result.metrics),
                f"{len(result.records)} flights of {config.duration_s:g} s "
                f"({config.profile}, {config.grade_name})")
    return 0


def _ladder(args: argparse.Namespace, config, workers: int, scheduler: str | None,
            out) -> int:
    """``--ladder``: the smallest body-axis step isolated in 95 % per sensor and axis."""
    from flight_fdi.eval.errors import EvalError
    from flight_fdi.eval.ladder3d import format_ladder, run_ladder

    if args.records:
        raise CliError("--records streams a study's flights; --ladder runs several studies "
                       "and does not take it")
    grades = (config.grade,) if args.ladder_grades is None else \
        tuple(g.strip() for g in args.ladder_grades.split(",") if g.strip())
    given = {} if args.scenarios is None else {"scenarios": config.scenarios}
    try:
        ladder = run_ladder(config, grades, runs=args.ladder_runs, rungs=args.ladder_rungs,
                            jobs=workers, progress=not args.no_progress, scheduler=scheduler,
                            **given)
    except EvalError as exc:
        raise CliError(str(exc)) from None
    doc = {"model": "ins3d", "config": config.describe(), "ladder": ladder}
    if out is not None:
        out.write_text(json.dumps(doc, indent=1) + "\n")
    print(json.dumps(doc) if args.json else format_ladder(ladder))
    return 0
