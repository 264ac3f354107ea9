#!/usr/bin/env python3
"""Regenerate the evaluation of the 3-D model (docs/ins3d_eval.md, issue 15 item 5).

Runs the studies below (each through ``flight-fdi montecarlo --model ins3d``'s code, on the
campaign engine with ``--jobs`` workers; seeded, so the numbers depend only on the options) and
writes their JSON to ``--out`` (default out/ins3d_eval/), then renders the generated sections of
docs/ins3d_eval.md from whatever JSON files exist (``--render-only``: no new runs). A study that
was cut short leaves no JSON; its section says so.

Studies (``--only`` picks some):

* ``nominal``: ``--nominal`` nominal flights (default 200), ``random`` profile (one seeded
  trajectory per flight), ``--nominal-duration`` s (default 900), navigation grade: false
  isolation of both models;
* ``faults``: ``--per-scenario`` flights (default 30) of each fault scenario (accelerometer and
  gyro steps and ramps on x/y/z, GNSS jumps east/north; onsets uniform in 10-80 % of the
  flight), ``cruise_turns`` (turns at 300 s and 985 s, a climb at 620 s), both models;
* ``ladder``: the smallest accelerometer / gyro step isolated in 95 % per axis, navigation grade
  (``--ladder-runs`` flights per rung, default 10; ``--ladder-rungs``), cruise_turns of
  ``--duration`` s, 3-D model only;
* ``ladder_grades``: the same for the other presets (``--ladder-grades``, default
  tactical,mems; ``--grades-runs`` flights per rung, default 5; ``--grades-rungs``, default 3);
* ``detectable``: the smallest accelerometer z and gyro x/y/z step each onset of one nominal
  1200-s ``cruise_turns`` flight can show (GLR expected at the step threshold:
  sqrt(threshold) x the GLR's sd at that onset), the loop model with 3 rows beside the damped
  vertical channel with 2: what the flight's observability allows;
* ``latency``: a GNSS receiver with ``--latency-ms`` (default 80) of latency instead of 20:
  ``--latency-nominal`` nominal flights (default 50, random profile) and ``--latency-per``
  flights (default 12) of accelerometer steps, gyro steps and GNSS jumps (cruise_turns).

Long flights (docs/ins3d_eval.md, "Long flights"; ``--long-duration`` s, default 7200, profile
``--long-profile``, default ``random``: a seeded trajectory per flight; per-flight records stream
to ``<out>/<study>*.jsonl`` and a stopped study resumes from them). On another profile the
studies' files and doc sections are named ``<study>_<profile>`` (``nominal_long_cruise_turns``:
"Long flights on the cruise_turns profile"), so the ``random`` studies' results stay as they are:

* ``nominal_long``: ``--long-nominal`` nominal flights (default 200), both models, with the
  largest GLR per hypothesis kind against its threshold;
* ``faults_long``: per scenario the flights of ``--long-per`` (``gyro_step=90,...``), both
  models, one study (seed) per scenario; the rate of right isolations per onset bin;
* ``detectable_long``: the detectable-step table of one long flight per profile of
  ``--long-detect-profiles`` (default random,cruise_turns).

Progress: stderr (a tqdm bar per study) and ``<out>/progress.log``.
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))

# the document's generated sections (--render-only: that alone) are rendered by a sibling
# module, tools/ins3d_eval_sections.py (tools/ on the path)
from ins3d_eval_sections import DOC, long_name, render  # noqa: E402

STUDIES = ("nominal", "faults", "ladder", "ladder_grades", "latency", "detectable",
           "nominal_long", "faults_long", "detectable_long")
#: steps of the detectable-step tables: (GLR hypothesis, scenario of its unit)
DETECT_STEPS = (("accelerometer_z_step", "accel_step"), ("gyro_x_step", "gyro_step"),
                ("gyro_y_step", "gyro_step"), ("gyro_z_step", "gyro_step"))
#: onsets (s) of the detectable-step table (the fault flights' 1200-s cruise_turns)
DETECT_ONSETS = (150, 250, 330, 450, 600, 800, 950, 1050, 1150)


def commit() -> str:
    import subprocess

    rev = subprocess.run(["git", "-C", str(REPO), "rev-parse", "--short", "HEAD"],
                         capture_output=True, text=True).stdout.strip()
    dirty = subprocess.run(["git", "-C", str(REPO), "status", "--porcelain", "--",
                            "flight_fdi"], capture_output=True, text=True).stdout.strip()
    return rev + ("+changes" if dirty else "")


def _save(out: pathlib.Path, name: str, doc: dict, args=None) -> None:
    """Write a study's JSON with the code's commit and (a run of main) the load it ran under."""
    doc["commit"] = getattr(args, "code", None) or commit()
    load = getattr(args, "load", None)
    if load is not None:
        doc["load_average"] = load.stop()
    (out / f"{name}.json").write_text(json.dumps(doc, indent=1) + "\n")


def log(out: pathlib.Path, text: str) -> None:
    line = f"{time.strftime('%H:%M:%S')} {text}"
    print(line, file=sys.stderr, flush=True)
    with (out / "progress.log").open("a", encoding="utf-8") as f:
        f.write(line + "\n")


def run_nominal(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.long3d import run_recorded
    from flight_fdi.eval.montecarlo3d import Study3DConfig

    cfg = Study3DConfig(nominal=args.nominal, per_scenario=0,
                        duration_s=args.nominal_duration, profile="random", seed=args.seed)
    res = run_recorded(cfg, out / "nominal.jsonl", args.jobs, progress=True)
    _save(out, "nominal", res.to_dict(), args)


def run_faults(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.montecarlo3d import Study3DConfig, run_study

    cfg = Study3DConfig(nominal=0, per_scenario=args.per_scenario, duration_s=args.duration,
                        profile="cruise_turns", seed=args.seed + 1)
    res = run_study(cfg, jobs=args.jobs, progress=True)
    _save(out, "faults", res.to_dict(), args)


def run_latency(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.metrics3d import summarize
    from flight_fdi.eval.montecarlo3d import Study3DConfig, run_study

    lat = args.latency_ms / 1000.0
    nom = run_study(Study3DConfig(nominal=args.latency_nominal, per_scenario=0,
                                  duration_s=args.nominal_duration, profile="random",
                                  gnss_latency_s=lat, seed=args.seed + 3),
                    jobs=args.jobs, progress=True)
    flt = run_study(Study3DConfig(nominal=0, per_scenario=args.latency_per,
                                  scenarios=("accel_step", "gyro_step", "ref_jump"),
                                  duration_s=args.duration, profile="cruise_turns",
                                  gnss_latency_s=lat, seed=args.seed + 4),
                    jobs=args.jobs, progress=True)
    recs = nom.records + [{**r, "index": r["index"] + len(nom.records)} for r in flt.records]
    doc = {"config": {"nominal": nom.config.describe(), "faults": flt.config.describe()},
           "latency_ms": args.latency_ms, "elapsed_s": nom.elapsed_s + flt.elapsed_s,
           "metrics": summarize(recs), "flights": recs}
    _save(out, "latency", doc, args)


def _ladder(args, out: pathlib.Path, name: str, grades: tuple, runs: int, rungs: int) -> None:
    from flight_fdi.eval.ladder3d import run_ladder
    from flight_fdi.eval.montecarlo3d import Study3DConfig

    cfg = Study3DConfig(nominal=0, per_scenario=1, duration_s=args.duration,
                        profile="cruise_turns", seed=args.seed + 2)
    lad = run_ladder(cfg, grades, runs=runs, rungs=rungs, jobs=args.jobs, progress=True)
    _save(out, name, {"config": cfg.describe(), "ladder": lad}, args)


def run_ladder_study(args, out: pathlib.Path) -> None:
    _ladder(args, out, "ladder", ("navigation",), args.ladder_runs, args.ladder_rungs)


def run_ladder_grades(args, out: pathlib.Path) -> None:
    grades = tuple(g for g in args.ladder_grades.split(",") if g)
    _ladder(args, out, "ladder_grades", grades, args.grades_runs, args.grades_rungs)


def run_detectable(args, out: pathlib.Path) -> None:
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    t0 = time.perf_counter()
    fl = simulate3d(Sim3DConfig(TrajectoryConfig(profile="cruise_turns",
                                                 duration_s=args.duration, seed=args.seed + 5),
                                grade="navigation", seed=args.seed + 5))
    inp = from_flight(fl)
    doc: dict = {"onsets_s": list(DETECT_ONSETS), "seed": args.seed + 5, "models": {}}
    for label, kw in (("loop, 3 rows", {"rows": 3, **inp.vertical()}),
                      ("damped, 2 rows", {"rows": 2, "vertical": "damped"})):
        a = analyze_ins3d(inp.steps, inp.refs, **kw)
        doc["models"][label] = _detect_doc(a, DETECT_ONSETS)
    doc["elapsed_s"] = time.perf_counter() - t0
    _save(out, "detectable", doc, args)


def _detect_doc(a, onsets) -> dict:
    """The detectable-step rows, turns and first-excited times of one analysis."""
    from flight_fdi.eval.long3d import detectable_steps

    ex = a.observability.excited_at
    return {"rows": detectable_steps(a, onsets, DETECT_STEPS), "turns": a.turns(),
            "excited_at": {k: ex.get(k) for k in ("ba_z", "bg_x", "bg_y", "bg_z", "phi_u")}}


# --------------------------------------------------------------------------- long flights

def _long_cfg(args, **kw):
    from flight_fdi.eval.montecarlo3d import Study3DConfig

    return Study3DConfig(duration_s=args.long_duration, profile=args.long_profile, **kw)


def _long_per(args) -> dict[str, int]:
    from flight_fdi.eval.montecarlo3d import SCENARIOS

    per = {}
    for item in filter(None, args.long_per.split(",")):
        name, _, n = item.partition("=")
        if name not in SCENARIOS or not n.isdigit():
            raise SystemExit(f"ins3d_eval: bad --long-per item {item!r} (scenario=count)")
        per[name] = int(n)
    return per


def run_nominal_long(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.long3d import run_recorded

    name = long_name("nominal_long", args.long_profile)
    cfg = _long_cfg(args, nominal=args.long_nominal, per_scenario=0, seed=args.seed + 6)
    res = run_recorded(cfg, out / f"{name}.jsonl", args.jobs, progress=True)
    _save(out, name, res.to_dict(), args)


def _fault_seed(args, scenario: str) -> int:
    """One study per scenario, its seed from the scenario's place in SCENARIOS (stable whatever
    --long-per holds)."""
    from flight_fdi.eval.montecarlo3d import SCENARIOS

    return args.seed + 10 + list(SCENARIOS).index(scenario)


def run_faults_long(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.long3d import merge_records, run_recorded

    name = long_name("faults_long", args.long_profile)
    parts, doc = [], {"config": {}, "elapsed_s": 0.0}
    for scen, n in _long_per(args).items():
        cfg = _long_cfg(args, nominal=0, per_scenario=n, scenarios=(scen,),
                        seed=_fault_seed(args, scen))
        log(out, f"{name}: {n} {scen} flights (seed {cfg.seed})")
        res = run_recorded(cfg, out / f"{name}_{scen}.jsonl", args.jobs, progress=True)
        parts.append(res.records)
        doc["config"][scen] = cfg.describe()
        doc["elapsed_s"] += res.elapsed_s
        doc["resumed"] = doc.get("resumed", 0) + res.resumed
        if res.engine:                 # a scenario wholly resumed from its records ran nowhere
            doc["engine"] = res.engine
    doc["flights"] = merge_records(parts)
    _save(out, name, doc, args)


def run_detectable_long(args, out: pathlib.Path) -> None:
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig

    t0, seed = time.perf_counter(), args.seed + 8
    onsets = [round(f * args.long_duration) for f in (0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7,
                                                       0.8, 0.9, 0.97)]
    doc: dict = {"onsets_s": onsets, "seed": seed, "duration_s": args.long_duration,
                 "models": {}}
    for prof in filter(None, args.long_detect_profiles.split(",")):
        fl = simulate3d(Sim3DConfig(TrajectoryConfig(profile=prof, duration_s=args.long_duration,
                                                     seed=seed), grade="navigation", seed=seed))
        inp = from_flight(fl)
        a = analyze_ins3d(inp.steps, inp.refs, rows=3, **inp.vertical())
        doc["models"][f"{prof}, loop, 3 rows"] = _detect_doc(a, onsets)
    doc["thresholds"] = dict(a.thresholds)
    doc["elapsed_s"] = time.perf_counter() - t0
    _save(out, long_name("detectable_long", args.long_profile), doc, args)


def main() -> int:
    from flight_fdi.eval.long3d import LoadSampler
    from flight_fdi.eval.montecarlo3d import PROFILES

    ap = argparse.ArgumentParser(description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", default=str(REPO / "out" / "ins3d_eval"))
    ap.add_argument("--only", default=",".join(STUDIES), help="studies to run (comma list)")
    ap.add_argument("--nominal", type=int, default=200)
    ap.add_argument("--per-scenario", type=int, default=30)
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--nominal-duration", type=float, default=900.0)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--ladder-runs", type=int, default=10)
    ap.add_argument("--ladder-rungs", type=int, default=4)
    ap.add_argument("--ladder-grades", default="tactical,mems")
    ap.add_argument("--grades-runs", type=int, default=5)
    ap.add_argument("--grades-rungs", type=int, default=3)
    ap.add_argument("--latency-ms", type=float, default=80.0)
    ap.add_argument("--latency-nominal", type=int, default=50)
    ap.add_argument("--latency-per", type=int, default=12)
    ap.add_argument("--long-duration", type=float, default=7200.0)
    ap.add_argument("--long-profile", default="random", choices=PROFILES,
                    help="trajectory of the long studies (default random)")
    ap.add_argument("--long-nominal", type=int, default=200)
    ap.add_argument("--long-per", default="gyro_step=90,accel_step=30,ref_jump=30,"
                                          "gyro_ramp=30,accel_ramp=30")
    ap.add_argument("--long-detect-profiles", default="random,cruise_turns")
    ap.add_argument("--render-only", action="store_true")
    ap.add_argument("--doc", default=str(DOC), help="the document whose generated sections are "
                    "rendered (default docs/ins3d_eval.md)")
    args = ap.parse_args()
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if not args.render_only:
        runners = {"nominal": run_nominal, "faults": run_faults, "ladder": run_ladder_study,
                   "ladder_grades": run_ladder_grades, "latency": run_latency,
                   "detectable": run_detectable, "nominal_long": run_nominal_long,
                   "faults_long": run_faults_long, "detectable_long": run_detectable_long}
        for name in args.only.split(","):
            if name not in runners:
                ap.error(f"unknown study {name!r}; choose from {', '.join(STUDIES)}")
            args.code, args.load = commit(), LoadSampler()
            log(out, f"{name}: start (code {args.code})")
            t0 = time.perf_counter()
            runners[name](args, out)
            log(out, f"{name}: done in {(time.perf_counter() - t0) / 60:.1f} min")
            render(out, pathlib.Path(args.doc))
    render(out, pathlib.Path(args.doc))
    print(f"rendered {args.doc} from {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
