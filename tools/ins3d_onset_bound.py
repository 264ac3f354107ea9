#!/usr/bin/env python3
"""The Cramer-Rao bound of a bias step's onset on the evaluation's 3-D flights, beside what the
GLR achieves (docs/ins3d_onset_bound.md; the math: flight_fdi/eval/onset_bound.py).

* ``grid``: ``--grid-flights`` nominal flights of the long evaluation (``--duration`` s,
  ``--profile``; seeds from the nominal study's seed ``--seed`` + 6 as tools/ins3d_eval.py's
  ``nominal_long``): the bound per sensor, axis, level and onset (fractions ``--fractions``);
* ``study``: the fault flights of the evaluation's gyro- and accelerometer-step studies,
  regenerated from their seeds (``--study long``: tools/ins3d_eval.py's ``faults_long``, one study
  per scenario, seed ``--seed`` + 10 + its place in SCENARIOS; ``--study 20min``: its ``faults``,
  1200-s cruise_turns, seed ``--seed`` + 1): per flight the isolator's onset, the bound at the true
  onset and size, the GLR curve's own curvature and ``--reps`` onsets of the GLR on innovations
  drawn from the model itself.

Records stream to JSON lines in ``--out`` (resumable); the tables go to stdout and
``<out>/tables_<study>.md``. ``--render-only`` re-renders from the records.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys
import time

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

#: a median |error| of an efficient unbiased Gaussian estimator: 0.674 sd
HALF_NORMAL_MEDIAN = 0.6745
TARGET_S = 5.0
LEVELS = {"gyro_step": (0.05, 0.1, 0.2), "accel_step": (0.3,)}


def _parse_per(text: str) -> dict[str, int]:
    out = {}
    for item in filter(None, text.split(",")):
        name, _, n = item.partition("=")
        if name not in LEVELS or not n.isdigit():
            raise SystemExit(f"ins3d_onset_bound: bad --per item {item!r} (gyro_step=N or "
                             "accel_step=N)")
        out[name] = int(n)
    return out


def study_plan(args) -> tuple[list, object]:
    """(cases, config) of the chosen study's step flights, as the evaluation planned them."""
    from flight_fdi.eval.montecarlo3d import SCENARIOS, Study3DConfig, plan_study

    per = _parse_per(args.per)
    cases, cfg = [], None
    if args.study == "long":
        for scen, n in per.items():
            cfg = Study3DConfig(nominal=0, per_scenario=n, scenarios=(scen,),
                                duration_s=args.duration, profile=args.profile,
                                seed=args.seed + 10 + list(SCENARIOS).index(scen),
                                single_axis=False)
            cases += [(c, cfg) for c in plan_study(cfg)]
    else:
        cfg = Study3DConfig(nominal=0, per_scenario=30, duration_s=1200.0,
                            profile="cruise_turns", seed=args.seed + 1, single_axis=False)
        for c in plan_study(cfg):
            if c.scenario in per and sum(x.scenario == c.scenario for x, _ in cases) < \
                    per[c.scenario]:
                cases.append((c, cfg))
    return cases, cfg


def _run(items, fn, path: pathlib.Path, settings: dict, jobs: int, desc: str) -> list[dict]:
    from flight_fdi.eval.parallel import parallel_map
    from flight_fdi.eval.records import RecordsFile

    with RecordsFile(path, settings, key="key") as rec:
        todo = [it for key, it in items if key not in rec.done]
        if todo:
            parallel_map(fn, todo, jobs, progress=True, desc=desc, on_result=rec.write)
    from flight_fdi.eval.records import read_records
    return read_records(path, key="key")[1]


def run_study(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.onset_bound import study_record

    cases, _ = study_plan(args)
    deltas = tuple(int(d) for d in args.deltas.split(","))
    items = [(f"{c.scenario}:{c.index}", (c, cfg, args.reps, deltas)) for c, cfg in cases]
    settings = {"study": args.study, "seed": args.seed, "reps": args.reps,   # --per: any
                "deltas": list(deltas), "duration_s": args.duration, "profile": args.profile}
    _run(items, study_record, out / f"study_{args.study}.jsonl", settings, args.jobs,
         "onset bound (study)")


def run_grid(args, out: pathlib.Path) -> None:
    from flight_fdi.eval.montecarlo3d import Study3DConfig, plan_study
    from flight_fdi.eval.onset_bound import grid_record

    cfg = Study3DConfig(nominal=args.grid_flights, per_scenario=0, duration_s=args.duration,
                        profile=args.profile, seed=args.seed + 6, single_axis=False)
    fr = tuple(float(f) for f in args.fractions.split(","))
    items = [(c.index, (c, cfg, fr, LEVELS)) for c in plan_study(cfg)]
    settings = {"grid_flights": args.grid_flights, "seed": args.seed + 6, "fractions": list(fr),
                "duration_s": args.duration, "profile": args.profile}
    _run(items, grid_record, out / f"grid_{args.study}.jsonl", settings, args.jobs,
         "onset bound (grid)")


# --------------------------------------------------------------------------- tables

def _med(x) -> float:
    x = [v for v in x if v is not None and math.isfinite(v)]
    return float(np.median(x)) if x else math.nan


def _f(x: float, spec: str = ".1f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def grid_table(recs: list[dict]) -> str:
    fr = sorted({r["fraction"] for g in recs for r in g["rows"]})
    dur = recs[0]["rows"][0]["onset_s"] / recs[0]["rows"][0]["fraction"]
    lines = [f"Median over {len(recs)} nominal flights of the onset's Cramer-Rao bound with "
             "the magnitude estimated (CRLB) / the Hammersley-Chapman-Robbins bound with it "
             "profiled out (HCR), s, by onset:", "",
             "| step | axis | level | " + " | ".join(f"{f * dur:.0f} s" for f in fr) +
             " | CRLB b known / b estimated |", "|---" * (4 + len(fr)) + "|"]
    for scen, levels in LEVELS.items():
        for axis in "xyz":
            rows = [r for g in recs for r in g["rows"] if r["scenario"] == scen and
                    r["axis"] == axis]
            ratio = _med([r["sd_known_s"] / r["sd_joint_s"] for r in rows])
            for lev in levels:
                cells = [f"{_f(_med([r['sd_joint_s'] / lev for r in rows if r['fraction'] == f]))}"
                         f" / {_f(_med([r['hcr'][str(lev)]['sd_profiled_s'] for r in rows if r['fraction'] == f]))}"
                         for f in fr]
                lines.append(f"| {scen} | {axis} | {lev:g} {rows[0]['unit']} | "
                             + " | ".join(cells) + f" | {_f(ratio, '.3f')} |")
    return "\n".join(lines)


def _flight_numbers(r: dict) -> dict:
    from flight_fdi.eval.metrics3d import outcome

    b = r["bounds"][0]
    right = outcome(r, "ins3d") == "right"
    syn = r["synthetic"]
    sds = [x["sd_joint_s"] for x in r["bounds"]]
    return {"right": right, "bound": b["sd_joint_s"], "known": b["sd_known_s"],
            "hcr": r["hcr"]["sd_profiled_s"], "hcr_known": r["hcr"]["sd_known_s"],
            "err": abs(r["ins3d"]["onset_s"] - r["onset_s"]) if right else None,
            "syn": np.abs(np.asarray(syn.get("mle", [])) - r["onset_s"]),
            "p_known": syn.get("p_known", []), "p_marginal": syn.get("p_marginal", []),
            "obs": r["true_hypothesis"]["sd_observed_s"],
            "fd_spread": (max(sds) - min(sds)) / min(sds), "glr": b["expected_glr"]}


def _groups(recs: list[dict]) -> list[tuple[tuple, list[dict]]]:
    groups: dict[tuple, list[dict]] = {}
    for r in recs:
        groups.setdefault((r["scenario"], r["axis"], r["level"]), []).append(r)
        groups.setdefault((r["scenario"], "all", r["level"]), []).append(r)
        groups.setdefault((r["scenario"], "all", 0.0), []).append(r)
    keys = sorted(groups, key=lambda k: (k[0] != "gyro_step", k[1] == "all", k[1], k[2] == 0.0,
                                         k[2]))
    return [(k, groups[k]) for k in keys]


def _rms(x) -> float:
    x = np.asarray([v for v in x if v is not None], dtype=float)
    return float(np.sqrt(np.mean(x * x))) if x.size else math.nan


def _label(key, g) -> str:
    return "all" if key[2] == 0.0 else f"{key[2]:g} {g[0]['unit']}"


def bounds_table(recs: list[dict]) -> str:
    lines = ["| step | axis | level | flights | expected GLR (median) | CRLB, b known (s) | "
             "CRLB, b estimated (s) | HCR, b profiled (s) | flights with HCR > 5 s | "
             "GLR curve's curvature sd / CRLB |", "|---" * 10 + "|"]
    for key, g in _groups(recs):
        x = [_flight_numbers(r) for r in g]
        lines.append(
            f"| {key[0]} | {key[1]} | {_label(key, g)} | {len(g)} | "
            f"{_f(_med([v['glr'] for v in x]), '.0f')} | {_f(_med([v['known'] for v in x]))} | "
            f"{_f(_med([v['bound'] for v in x]))} | {_f(_med([v['hcr'] for v in x]))} | "
            f"{sum(v['hcr'] > TARGET_S for v in x)}/{len(g)} | "
            f"{_f(_med([v['obs'] / v['bound'] for v in x if v['obs']]), '.2f')} |")
    spread = {}
    for r in recs:
        spread[r["scenario"]] = max(spread.get(r["scenario"], 0.0),
                                    _flight_numbers(r)["fd_spread"])
    lines += ["", "Medians over the flights. Central difference: largest relative spread of the "
              f"CRLB over the half steps {recs[0]['bounds'][0]['delta_s']:.2g}-"
              f"{recs[0]['bounds'][-1]['delta_s']:.2g} s: "
              + ", ".join(f"{k} {v:.1e}" for k, v in spread.items()) + "."]
    return "\n".join(lines)


def achieved_table(recs: list[dict]) -> str:
    lines = ["| step | axis | level | right / flights | GLR (flights): median abs error, "
             "rms, within 5 s | median abs error / CRLB | model-drawn data: GLR median abs "
             "error, rms, within 5 s (draws) | best estimator within 5 s: b known, b "
             "marginalised (mean posterior probability) |", "|---" * 8 + "|"]
    for key, g in _groups(recs):
        x = [_flight_numbers(r) for r in g]
        right = [v for v in x if v["right"]]
        e = [v["err"] for v in right]
        syn = np.concatenate([v["syn"] for v in x])
        pk = np.concatenate([v["p_known"] for v in x])
        pm = np.concatenate([v["p_marginal"] for v in x])
        within = f"{sum(v <= TARGET_S for v in e)}/{len(e)}" if e else "-"
        lines.append(
            f"| {key[0]} | {key[1]} | {_label(key, g)} | {len(right)}/{len(g)} | "
            f"{_f(_med(e))}, {_f(_rms(e))}, {within} | "
            f"{_f(_med([v['err'] / v['bound'] for v in right]), '.2f')} | "
            f"{_f(_med(syn))}, {_f(_rms(syn))}, {int(np.sum(syn <= TARGET_S))}/{syn.size} | "
            f"{_f(float(np.mean(pk)) if pk.size else math.nan, '.2f')}, "
            f"{_f(float(np.mean(pm)) if pm.size else math.nan, '.2f')} |")
    lines += ["", f"An efficient unbiased estimator's median abs error is {HALF_NORMAL_MEDIAN:.3f}"
              " x its sd. The last column bounds P(abs error <= 5 s) of any estimator (uniform "
              "onset prior over the study's onset window; b known: more than any estimator "
              "knows)."]
    return "\n".join(lines)


def render(args, out: pathlib.Path) -> str:
    from flight_fdi.eval.records import read_records

    parts = []
    g = out / f"grid_{args.study}.jsonl"
    if g.exists():
        parts.append(grid_table(read_records(g, key="key")[1]))
    s = out / f"study_{args.study}.jsonl"
    if s.exists():
        recs = read_records(s, key="key")[1]
        if recs:
            parts += [bounds_table(recs), achieved_table(recs)]
    text = "\n\n".join(parts)
    (out / f"tables_{args.study}.md").write_text(text + "\n")
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", default="grid,study", help="grid, study (comma-separated)")
    ap.add_argument("--study", choices=("long", "20min"), default="long")
    ap.add_argument("--per", default="gyro_step=90,accel_step=30",
                    help="step flights per scenario (the first N of the evaluation's plan)")
    ap.add_argument("--duration", type=float, default=7200.0, help="long study / grid (s)")
    ap.add_argument("--profile", default="random")
    ap.add_argument("--seed", type=int, default=0, help="tools/ins3d_eval.py's --seed")
    ap.add_argument("--reps", type=int, default=6, help="model-drawn GLR onsets per flight")
    ap.add_argument("--deltas", default="1,2,5",
                    help="central-difference half steps (boundaries of 0.1 s)")
    ap.add_argument("--grid-flights", type=int, default=4)
    ap.add_argument("--fractions", default="0.1,0.2,0.3,0.4,0.5,0.6,0.7,0.8")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=str(REPO / "out" / "ins3d_onset_bound"))
    ap.add_argument("--render-only", action="store_true")
    args = ap.parse_args(argv)
    _parse_per(args.per)                # a bad --per fails before anything runs
    if args.study == "20min":
        args.duration, args.profile = 1200.0, "cruise_turns"
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def work() -> None:
        if not args.render_only:
            only = set(args.only.split(","))
            if "grid" in only:
                run_grid(args, out)
            if "study" in only:
                run_study(args, out)
        print(render(args, out))

    return reported("ins3d_onset_bound", work)


def reported(name: str, work) -> int:
    """Run ``work()``; an evaluation, file or value error is one line on stderr and exit code 2
    (no traceback), else the elapsed time on stderr and 0."""
    t0 = time.perf_counter()
    try:
        work()
    except Exception as exc:            # one line on stderr, no traceback
        from flight_fdi.eval.errors import EvalError

        if not isinstance(exc, (EvalError, OSError, ValueError)):
            raise
        print(f"{name}: {exc}", file=sys.stderr)
        return 2
    print(f"({time.perf_counter() - t0:.0f} s)", file=sys.stderr)
    return 0

if __name__ == "__main__":
    sys.exit(main())
