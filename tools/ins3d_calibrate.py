"""Calibrate the ins3d GLR thresholds on nominal simulated flights (docs/ins3d.md, "Thresholds"),
or check a grade file's thresholds on held-out flights.

The flights are the simulator's (sim/ins3d.py): scale factors and misalignments (not states of the
estimator's model), correlated GNSS noise with latency, a baro-damped INS -- not data the
estimator's own model generated. Per flight the maximum GLR over the onsets of every hypothesis
kind is recorded (flight_fdi/eval/calibrate3d.py, as ``flight-fdi calibrate``); printed with the
distribution and the thresholds the calibration rule gives for --target, per kind and per
hypothesis (``calibrate3d.calibrate_hypotheses``: an equal share of the budget each; the
navigation preset's were made from two such runs, 30 min and 2 h, docs/ins3d_eval.md).
``--out X.json`` also streams each flight's row to ``X.jsonl`` as it arrives. ``--grade`` is a preset
or a YAML grade file. ``--check``: instead, per threshold set (the grade's own -- e.g. calibrated
by ``flight-fdi calibrate`` -- and its base preset's) the false isolations and declarations on
these flights with 95 % intervals (use seeds the calibration did not use). Usage::

    .venv/bin/python tools/ins3d_calibrate.py --flights 20 --duration 1800 --out out/calib.json
    .venv/bin/python tools/ins3d_calibrate.py --grade my.yaml --check --seed0 50000 --flights 100
"""
from __future__ import annotations

import argparse
import json
import time

from flight_fdi.core.ins3d.glr3d import thresholds_for
from flight_fdi.core.ins3d.grade_file import KINDS, CustomGrade, grade_thresholds, resolve_grade
from flight_fdi.eval.calibrate3d import (bootstrap_spread, calibrate, calibrate_hypotheses,
                                         check_rates, exceeded, exceeded_hypotheses, plan, rate,
                                         run_flights, summary)


def _pct(r: dict) -> str:
    lo, hi = r["interval95"]
    return (f"{r['k']}/{r['n']} = {100 * r['rate']:.1f} % "
            f"(95 % interval {100 * lo:.1f}-{100 * hi:.1f} %)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=20)
    ap.add_argument("--duration", type=float, default=1800.0)
    ap.add_argument("--grade", default="navigation", help="preset or YAML grade file")
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--profiles", default="cruise_turns,random,survey_grid")
    ap.add_argument("--target", type=float, default=0.01, help="per-flight false isolation")
    ap.add_argument("--check", action="store_true",
                    help="held-out check of the grade's thresholds and its base preset's")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    grade = resolve_grade(a.grade)
    checks = None
    if a.check:
        checks = {"grade": grade_thresholds(grade), "base": _base_thresholds(a.grade, grade)}
    items = plan(grade, a.flights, a.seed0, tuple(p for p in a.profiles.split(",") if p),
                 a.duration, checks)
    t0 = time.time()

    def arrived(r: dict) -> None:
        print(f"{r['profile']} seed {r['seed']}: "
              + ", ".join(f"{k} {r['max'][k]:.1f} ({r['argmax'][k]})" for k in KINDS)
              + f" -> {r['verdict']}  [{time.time() - t0:.0f} s]", flush=True)
        if a.out:      # each flight's row as it arrives (a stopped run keeps what it made)
            with open(a.out + "l", "a") as f:
                f.write(json.dumps(r) + "\n")

    rows = run_flights(items, a.jobs, on_result=arrived)
    print(f"{len(rows)} flights in {time.time() - t0:.0f} s")
    for k, v in summary(rows).items():
        print(f"{k}: max over flights {v['max']:.1f}, median {v['median']:.1f}, "
              f"90 % {v['q90']:.1f}")
    verdicts = {v: sum(r["verdict"] == v for r in rows)
                for v in sorted({r["verdict"] for r in rows})}
    print(f"verdicts (the grade's own thresholds; the seed method where the GLR finds nothing): "
          f"{verdicts}")
    if a.check:
        for name, r in check_rates(rows).items():
            print(f"{name} thresholds {checks[name]}: false isolation "
                  f"{_pct(r['false_isolation'])}; declared {_pct(r['declared'])}")
    elif len(rows) >= 20:
        thr, spread = calibrate(rows, a.target), bootstrap_spread(rows, a.target)
        print(f"thresholds for {100 * a.target:g} %: "
              + ", ".join(f"{k} {thr[k]:.1f} +- {spread[k]:.1f}" for k in KINDS)
              + f"; exceeded on {_pct(rate(exceeded(rows, thr), len(rows)))}")
        hyp = calibrate_hypotheses(rows, a.target)      # moved to 30 min by glr3d's growth
        print(f"per hypothesis ({100 * a.target:g} %, outliers as above): "
              + ", ".join(f"{h} {v:.1f}" for h, v in hyp.items()) + "; exceeded on "
              + _pct(rate(exceeded_hypotheses(rows, {**thr, **hyp}), len(rows))))
    if a.out:      # the flights' rows (tools/ins3d_eval.py reads them; --check: with "checks")
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


def _base_thresholds(path: str, grade) -> dict[str, float]:
    """The thresholds a grade file had before any calibration: its base preset's."""
    import yaml

    if not isinstance(grade, CustomGrade):
        return thresholds_for(grade.name)
    with open(path, encoding="utf-8") as f:
        return thresholds_for(yaml.safe_load(f)["base"])


if __name__ == "__main__":
    main()
