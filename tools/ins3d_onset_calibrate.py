#!/usr/bin/env python3
"""Calibrate the ins3d onset intervals (``core/ins3d/result3d.py``'s ``ONSET_DROP``).

The onset interval of an isolated fault is the set of onsets whose GLR is within ``drop`` of the
peak (profile likelihood; chi^2(1) 95 % = 3.84). On seeded simulated fault flights (the Monte
Carlo's ``cruise_turns`` flights, seed 7: independent of the evaluation's seeds 0-4) this prints,
per scenario, the coverage of the true onset by the interval of each drop over the flights
isolated to the right sensor and axis, and the median width; ``ONSET_DROP`` takes the smallest
drop that covers >= 95 %. Usage::

    .venv/bin/python tools/ins3d_onset_calibrate.py --per-scenario 30 --out out/onset.json
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

DROPS = (3.84, 6.0, 10.0, 15.0, 25.0, 40.0)


def one(case, config) -> dict:
    """Truth, isolation and the intervals of each drop of one flight."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.eval.montecarlo3d import simulate_case

    inp = from_flight(simulate_case(case, config))
    a = analyze_ins3d(inp.steps, inp.refs, rows=config.rows, with_observability=False,
                      **inp.vertical())
    iso = a.isolation
    c = a.glr.get(iso.best) if iso is not None and iso.isolation == "single" else None
    right = c is not None and c.hypothesis.sensor == case.sensor and \
        c.hypothesis.axis == case.axis
    return {"scenario": case.scenario, "axis": case.axis, "level": case.level,
            "onset_s": case.onset_s, "right": right,
            "estimate_s": float(c.t[c.best]) if right else None,
            "intervals": {str(d): c.onset_interval(d) for d in DROPS} if right else None}


def main() -> None:
    from flight_fdi.eval.montecarlo3d import Study3DConfig, plan_study

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-scenario", type=int, default=30)
    ap.add_argument("--scenarios", default="accel_step,gyro_step")
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    cfg = Study3DConfig(nominal=0, per_scenario=a.per_scenario,
                        scenarios=tuple(a.scenarios.split(",")), duration_s=a.duration,
                        profile="cruise_turns", seed=a.seed, single_axis=False)
    rows, t0 = [], time.time()
    for i, case in enumerate(plan_study(cfg)):
        rows.append(one(case, cfg))
        print(f"{i + 1} {case.scenario} {case.axis} {case.level}: right {rows[-1]['right']} "
              f"[{time.time() - t0:.0f} s]", file=sys.stderr, flush=True)
    for s in cfg.scenarios:
        right = [r for r in rows if r["scenario"] == s and r["right"]]
        n = sum(r["scenario"] == s for r in rows)
        print(f"{s}: {len(right)}/{n} right sensor and axis")
        for d in DROPS:
            iv = [r["intervals"][str(d)] for r in right]
            cov = sum(lo - 1e-6 <= r["onset_s"] <= hi + 1e-6 for (lo, hi), r in zip(iv, right))
            width = np.median([hi - lo for lo, hi in iv]) if iv else float("nan")
            print(f"  drop {d:5.2f}: true onset covered {cov}/{len(right)}, "
                  f"median width {width:.1f} s")
    if a.out:
        pathlib.Path(a.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
