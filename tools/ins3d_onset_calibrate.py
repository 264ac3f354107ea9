#!/usr/bin/env python3
"""Calibrate the ins3d onset intervals (``core/ins3d/result3d.py``'s ``ONSET_DROP``).

The onset interval of an isolated fault is the set of onsets whose GLR is within ``drop`` of the
peak (profile likelihood; chi^2(1) 95 % = 3.84; a step or ramp's also takes in the onsets where
the other kind of the same sensor and axis is within the drop: ``result3d.onset_interval``). On seeded simulated fault flights (the Monte
Carlo's ``cruise_turns`` flights, seed 7: independent of the evaluation's seeds 0-4) this prints,
per scenario, the coverage of the true onset by the interval of each drop over the flights
isolated to the right sensor and axis, and the median width; ``ONSET_DROP`` takes the smallest
drop that covers >= 95 %. The coverage is also split by the kind the isolator reported (a
ramp fault is often reported as a step of the right sensor and axis; the drop applies to the
reported hypothesis: ``ONSET_DROP`` is keyed by sensor and kind). The flights run on the
campaign engine (``--jobs``; each case carries its seeds). Usage::

    .venv/bin/python tools/ins3d_onset_calibrate.py --per-scenario 30 --out out/onset.json
    .venv/bin/python tools/ins3d_onset_calibrate.py --scenarios accel_ramp,gyro_ramp --jobs 2
"""
from __future__ import annotations

import argparse
import json
import pathlib
import sys
import time

import numpy as np

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parents[1]))

DROPS = (3.84, 6.0, 8.0, 10.0, 12.0, 15.0, 20.0, 25.0, 40.0)


def one(case, config) -> dict:
    """Truth, isolation and the intervals of each drop of one flight."""
    from flight_fdi.bagio.ins3d_input import from_flight
    from flight_fdi.core.ins3d.analysis import analyze_ins3d
    from flight_fdi.core.ins3d.result3d import onset_interval
    from flight_fdi.eval.montecarlo3d import simulate_case

    inp = from_flight(simulate_case(case, config))
    a = analyze_ins3d(inp.steps, inp.refs, rows=config.rows, with_observability=False,
                      **inp.vertical())
    iso = a.isolation
    c = a.glr.get(iso.best) if iso is not None and iso.isolation == "single" else None
    right = c is not None and c.hypothesis.sensor == case.sensor and \
        c.hypothesis.axis == case.axis
    return {"index": case.index, "scenario": case.scenario, "axis": case.axis,
            "level": case.level, "onset_s": case.onset_s, "right": right,
            "reported_kind": c.hypothesis.kind if right else None,
            "estimate_s": float(c.t[c.best]) if right else None,
            "intervals": {str(d): onset_interval(c, a.glr, d) for d in DROPS} if right else None}


def _one(item) -> dict:
    return one(*item)


def main() -> None:
    from flight_fdi.eval.long3d import format_onset_coverage
    from flight_fdi.eval.montecarlo3d import Study3DConfig, plan_study
    from flight_fdi.eval.parallel import parallel_map

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--per-scenario", type=int, default=30)
    ap.add_argument("--scenarios", default="accel_step,gyro_step")
    ap.add_argument("--duration", type=float, default=1200.0)
    ap.add_argument("--profile", default="cruise_turns")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    cfg = Study3DConfig(nominal=0, per_scenario=a.per_scenario,
                        scenarios=tuple(a.scenarios.split(",")), duration_s=a.duration,
                        profile=a.profile, seed=a.seed, single_axis=False)
    t0 = time.time()

    def arrived(r: dict) -> None:
        print(f"{r['index'] + 1} {r['scenario']} {r['axis']} {r['level']}: right {r['right']} "
              f"[{time.time() - t0:.0f} s]", file=sys.stderr, flush=True)

    rows = sorted(parallel_map(_one, [(c, cfg) for c in plan_study(cfg)], a.jobs,
                               desc="onset calibration", on_result=arrived),
                  key=lambda r: r["index"])
    print(format_onset_coverage(rows, DROPS))
    if a.out:
        pathlib.Path(a.out).write_text(json.dumps(rows, indent=1) + "\n")


if __name__ == "__main__":
    main()
