#!/usr/bin/env python3
"""Detection and isolation power bounds of IMU bias steps on the evaluation's 3-D flights, beside
what the GLR achieves (docs/ins3d_power_bound.md; the math: flight_fdi/eval/power_bound.py).

``--study random`` / ``cruise_turns``: the first ``--flights`` gyro-step flights of the 2-h
evaluation's study on that profile (tools/ins3d_eval.py ``faults_long``: seed ``--seed`` + 11,
``--seed 100`` for cruise_turns' 111), ``20min``: the 1200-s cruise_turns fault study (seed
``--seed`` + 1), regenerated from their seeds (tools/ins3d_onset_bound.py ``study_plan``). Per
flight, at its own onset and ``--extra`` onsets from the study's prior, for every IMU step
column and level: the information, the nearest rivals and the GLR's decisions on ``--noise``
model-drawn data sets (eval/power_bound.py ``flight_record``).

Records stream to JSON lines in ``--out`` (resumable); the tables go to stdout and
``<out>/tables_<study>.md``; progress on stderr. ``--render-only`` re-renders from the records.
"""
from __future__ import annotations

import argparse
import math
import pathlib
import sys
from collections import Counter

import numpy as np

REPO = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tools"))

STUDIES = {"random": ("long", 7200.0, "random", 0),
           "cruise_turns": ("long", 7200.0, "cruise_turns", 100),
           "20min": ("20min", 1200.0, "cruise_turns", 0)}

from ins3d_onset_bound import reported  # noqa: E402  (a sibling tool: tools/ on the path)


def plan(args) -> list:
    """(case, config) of the study's first ``--flights`` gyro-step flights."""
    from ins3d_onset_bound import study_plan

    kind, dur, prof, seed = STUDIES[args.study]
    ns = argparse.Namespace(per=f"gyro_step={args.flights}", study=kind, duration=dur,
                            profile=prof, seed=seed if args.seed is None else args.seed)
    return study_plan(ns)[0]


def run(args, out: pathlib.Path) -> list[dict]:
    from ins3d_onset_bound import _run

    from flight_fdi.eval.power_bound import flight_record

    cases = plan(args)
    cols = [tuple(c.split("_")) for c in args.columns.split(",")]
    if any(len(c) != 2 or c[0] not in ("gyro", "accelerometer") or c[1] not in ("x", "y", "z")
           for c in cols):
        raise ValueError(f"bad --columns {args.columns!r} (e.g. gyro_z,accelerometer_x)")
    items = [(f"{c.scenario}:{c.index}", (c, cfg, args.extra, args.noise, cols))
             for c, cfg in cases]
    settings = {"study": args.study, "seed": args.seed, "extra": args.extra,
                "noise": args.noise, "columns": args.columns}
    return _run(items, flight_record, out / f"power_{args.study}.jsonl", settings, args.jobs,
                f"power bound ({args.study})")


# --------------------------------------------------------------------------- tables

def _f(x: float, spec: str = ".2f") -> str:
    return "-" if x is None or not math.isfinite(x) else format(x, spec)


def row_bounds(r: dict, thr: dict, scale: float = 1.0) -> dict:
    """The bounds of one (flight, onset, column, level) row (the fault ``scale`` x its size).
    The GLR told the onsets: the column's own threshold (``glr3d.threshold_of``: per kind in
    records made before per-hypothesis thresholds), isolated when its excess beats the nearest
    rival's by the margin (``glr3d.isolate``: the raw gap >= margin + c_own - c_rival)."""
    from flight_fdi.core.ins3d.glr3d import AMBIGUITY_MARGIN, hypotheses, threshold_of
    from flight_fdi.eval.power_bound import (glr_known_onsets, np_power,
                                             separation_bound)

    hyps = {h.name: h for h in hypotheses(3)}
    lam = (scale * r["b"]) ** 2 * r["info"]
    cos2 = r["rivals"][0]["cos2"] if r["rivals"] else 0.0
    d2 = lam * (1.0 - cos2)
    own = threshold_of(thr, hyps[f"{r['sensor']}_{r['axis']}_step"])
    rival = threshold_of(thr, hyps[r["rivals"][0]["name"]]) if r["rivals"] else own
    det, iso = glr_known_onsets(lam, cos2, own, AMBIGUITY_MARGIN + own - rival)
    p_np, p_sep = float(np_power(lam)), float(separation_bound(d2))
    return {"lam": lam, "np": p_np, "sep": p_sep, "iso": min(p_np, p_sep), "glr_det": det,
            "glr_iso": iso, "rival": r["rivals"][0]["name"] if r["rivals"] else "-"}


def _groups(recs: list[dict]) -> dict[tuple, list[tuple[dict, dict]]]:
    g: dict[tuple, list] = {}
    for rec in recs:
        for r in rec["rows"]:
            g.setdefault((r["sensor"], r["axis"], r["level"]), []).append((rec, r))
    return dict(sorted(g.items(), key=lambda kv: (kv[0][0] != "gyro", kv[0][1], kv[0][2])))


def _binom(k: int, n: int) -> str:
    return f"{k}/{n}" if n else "-"


def bound_table(recs: list[dict]) -> str:
    """Per sensor, axis and level, averaged over the flights and the onsets drawn from the
    prior: the bounds, the GLR told the onsets, the GLR on model-drawn data and on the flights."""
    from flight_fdi.eval.metrics3d import outcome
    from flight_fdi.eval.power_bound import mixture_achieved, mixture_power_bound

    lines = ["| sensor | axis | level | onsets | lambda (median) | NP bound, onset known "
             "| onset unknown: reached (L > 1/alpha) - bound | separation bound (nearest rival) | isolation bound (± se) "
             "| GLR told the onsets: detected, isolated | GLR on model data: detected, right "
             "(draws) | GLR on the flights: right |", "|---" * 12 + "|"]
    above = []
    for (sensor, axis, lev), rows in _groups(recs).items():
        b = [row_bounds(r, rec["thresholds"]) for rec, r in rows]
        dr = [r["draws"] for _, r in rows]
        right = sum(sum(d["right"]) for d in dr)
        det = sum(sum(d["detected"]) for d in dr)
        n = sum(len(d["right"]) for d in dr)
        m = lambda key: float(np.mean([x[key] for x in b]))   # noqa: E731
        se = lambda key: float(np.std([x[key] for x in b]) / math.sqrt(len(b)))  # noqa: E731
        lr = np.concatenate([d["log_lr"] for d in dr])
        mix = f"{_f(mixture_achieved(lr))}-{_f(mixture_power_bound(lr))}"
        own = [rec for rec in recs if rec["sensor"] == sensor and rec["axis"] == axis
               and rec["level"] == lev]
        k = sum(outcome(rec, "ins3d") == "right" for rec in own)
        rival = Counter(x["rival"] for x in b).most_common(1)[0][0]
        unit = UNITS[sensor]
        lines.append(
            f"| {sensor} | {axis} | {lev:g} {unit} | {len(rows)} | "
            f"{_f(float(np.median([x['lam'] for x in b])), '.1f')} | {_f(m('np'))} | "
            f"{mix} | {_f(m('sep'))} ({rival}) | {_f(m('iso'))} ± {_f(se('iso'))} | "
            f"{_f(m('glr_det'))}, {_f(m('glr_iso'))} | {_f(det / n if n else math.nan)}, "
            f"{_f(right / n if n else math.nan)} ({n}) | {_binom(k, len(own))} |")
        if n and right / n > m("iso") + 3.0 * math.sqrt(max(m("iso") * (1 - m("iso")), 1 / n) / n):
            above.append(f"{sensor} {axis} {lev:g}")
    lines += ["", "Model-drawn GLR rate of right isolations above the isolation bound by more than "
              "3 binomial sd: " + (", ".join(above) if above else "none") + "."]
    return "\n".join(lines)


#: onset bins (fractions of the flight) of the by-onset table: the evaluation's 2-h bins
#: 720-3600-4320-5040-5760 s
BINS = (0.1, 0.5, 0.6, 0.7, 0.8)
UNITS = {"gyro": "deg/h", "accelerometer": "mg"}


def onset_table(recs: list[dict], axis: str = "z") -> str:
    """The gyro ``axis`` by onset bin: isolation bound, the GLR told the onsets, the GLR on
    model-drawn data."""
    dur = recs[0]["window"][1] / BINS[-1]
    edges = [f * dur for f in BINS]
    lines = [f"gyro {axis} by onset: isolation bound / GLR told the onsets, isolated / GLR on "
             "model data, right (onsets)", "",
             "| level | " + " | ".join(f"{a:.0f}-{b:.0f} s" for a, b in zip(edges, edges[1:]))
             + " |", "|---" * len(edges) + "|"]
    for (sensor, ax, lev), rows in _groups(recs).items():
        if sensor != "gyro" or ax != axis:
            continue
        cells = []
        for a, b in zip(edges, edges[1:]):
            sel = [(rec, r) for rec, r in rows if a <= r["onset_s"] < b]
            if not sel:
                cells.append("-")
                continue
            x = [row_bounds(r, rec["thresholds"]) for rec, r in sel]
            right = [v for _, r in sel for v in r["draws"]["right"]]
            cells.append(f"{np.mean([v['iso'] for v in x]):.2f} / "
                         f"{np.mean([v['glr_iso'] for v in x]):.2f} / "
                         f"{np.mean(right):.2f} ({len(sel)})")
        lines.append(f"| {lev:g} deg/h | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def smallest_level(rows: list[tuple[dict, dict]], key: str, target: float = 0.95) -> float:
    """The smallest size (the rows' level x s) whose mean ``key`` over the rows (onsets from the
    prior) reaches ``target`` (bisection in log s; the bounds grow with the size)."""
    def mean(s: float) -> float:
        return float(np.mean([row_bounds(r, rec["thresholds"], s)[key] for rec, r in rows]))

    lo, hi = 1e-3, 1e3
    if mean(hi) < target:
        return math.inf
    for _ in range(40):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if mean(mid) < target else (lo, mid)
    return hi * rows[0][1]["level"]


def smallest_table(recs: list[dict]) -> str:
    """Per IMU axis, the smallest step whose isolation bound (any test) and whose GLR-told-the-
    onsets isolation reach 95 % averaged over the onset prior."""
    lines = ["| sensor | axis | smallest step with isolation bound >= 95 % | ... with the GLR "
             "told the onsets >= 95 % |", "|---|---|---|---|"]
    seen = set()
    for (sensor, axis, _), rows in _groups(recs).items():
        if (sensor, axis) in seen:
            continue
        seen.add((sensor, axis))
        u = UNITS[sensor]
        lines.append(f"| {sensor} | {axis} | {smallest_level(rows, 'iso'):.3g} {u} | "
                     f"{smallest_level(rows, 'glr_iso'):.3g} {u} |")
    return "\n".join(lines)


def h0_line(recs: list[dict]) -> str:
    """The GLR's isolations on the model-drawn noise alone."""
    named = [x for rec in recs for x in rec["h0_named"]]
    c = Counter(x for x in named if x)
    return (f"GLR on model-drawn nominal data (the same noise draws, no fault): "
            f"{sum(c.values())}/{len(named)} declared"
            + (" (" + ", ".join(f"{k} {v}" for k, v in c.most_common()) + ")" if c else "")
            + ".")


def rules_table(recs: list[dict]) -> str | None:
    """The decision rules of ``power_bound.RULES`` on the same model-drawn draws: per sensor,
    axis and level the rate of right isolations, and on the noise alone the false isolations
    (a single isolation naming a sensor) per rule; records without them: None."""
    from flight_fdi.eval.power_bound import RULES

    if not all("h0_rules" in rec for rec in recs):
        return None
    names = list(RULES)
    lines = ["decision rules on the same model-drawn data (thresholds per kind or per "
             "hypothesis; best and rival by raw statistic or by excess over the own threshold): "
             "rate of right isolations (draws)", "",
             "| sensor | axis | level | " + " | ".join(names) + " |", "|---" * (3 + len(names))
             + "|"]
    for (sensor, axis, lev), rows in _groups(recs).items():
        d = [x for _, r in rows for x in r["draws"]["rules"]]
        lines.append(f"| {sensor} | {axis} | {lev:g} {UNITS[sensor]} | " + " | ".join(
            f"{np.mean([x[n][2] for x in d]):.2f} ({len(d)})" for n in names) + " |")
    h0 = [x for rec in recs for x in rec["h0_rules"]]
    lines += ["", "nominal model-drawn data (no fault): single isolations / any declaration: "
              + ", ".join(f"{n} {sum(x[n][1] == 'single' for x in h0)} / "
                          f"{sum(x[n][1] != 'none' for x in h0)}" for n in names)
              + f" of {len(h0)}."]
    return "\n".join(lines)


def render(args, out: pathlib.Path) -> str:
    from flight_fdi.eval.records import read_records

    p = out / f"power_{args.study}.jsonl"
    if not p.exists():
        raise OSError(f"no records {p}")
    recs = read_records(p, key="key")[1]
    text = "\n\n".join(t for t in [bound_table(recs), h0_line(recs), onset_table(recs),
                                    smallest_table(recs), rules_table(recs)] if t)
    (out / f"tables_{args.study}.md").write_text(text + "\n")
    return text


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--study", choices=tuple(STUDIES), default="random")
    ap.add_argument("--flights", type=int, default=27,
                    help="the first N gyro-step flights of the study's plan")
    ap.add_argument("--extra", type=int, default=2, help="onsets from the prior per flight")
    ap.add_argument("--noise", type=int, default=4, help="model-drawn data sets per flight")
    ap.add_argument("--columns", default=",".join(f"{s}_{a}" for s in ("gyro", "accelerometer")
                                                  for a in "xyz"),
                    help="IMU step columns (sensor_axis, comma-separated)")
    ap.add_argument("--seed", type=int, default=None,
                    help="tools/ins3d_eval.py's --seed (default: the study's)")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default=str(REPO / "out" / "ins3d_power_bound"))
    ap.add_argument("--render-only", action="store_true")
    args = ap.parse_args(argv)
    if args.flights < 1 or args.extra < 0 or args.noise < 1:
        print("ins3d_power_bound: --flights and --noise must be >= 1, --extra >= 0",
              file=sys.stderr)
        return 2
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    def work() -> None:
        if not args.render_only:
            run(args, out)
        print(render(args, out))

    return reported("ins3d_power_bound", work)

if __name__ == "__main__":
    sys.exit(main())
