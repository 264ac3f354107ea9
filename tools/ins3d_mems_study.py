"""The seeded MEMS study of docs/ins3d_relinearize.md: nominal and fault flights of the
simulator's ``mems`` preset on ``cruise_turns``, analysed with the ins3d model as it is, or with
``--linear`` as the model linear about zero (no relinearisation, no validity limit).

    .venv/bin/python tools/ins3d_mems_study.py --lengths 300,600,1200 --records out/mems.jsonl
    .venv/bin/python tools/ins3d_mems_study.py --linear --records out/mems_linear.jsonl

One JSON line per flight; a summary per flight length at the end (about 5 min for the three
lengths on the shared 2-core machine)."""
from __future__ import annotations

import argparse
import json
import sys
from collections import Counter

import numpy as np

from flight_fdi.core.ins3d import analysis, relinearize
from flight_fdi.eval.montecarlo3d import (Case3D, Study3DConfig, fault_case, ins3d_post_flight,
                                          simulate_case)

#: (scenario, axis, level in the scenario's unit), 4 flights each
FAULTS = [("accel_step", "x", 20), ("accel_step", "y", 20), ("accel_step", "z", 10),
          ("gyro_step", "x", 200), ("gyro_step", "y", 200), ("accel_ramp", "z", 40)]


def cases(cfg: Study3DConfig, nominal: int, per_fault: int, seed: int) -> list[Case3D]:
    rng = np.random.default_rng(seed)
    out = [Case3D(i, "nominal", int(rng.integers(0, 2**31 - 1)), int(rng.integers(0, 2**31 - 1)),
                  grade="mems") for i in range(nominal)]
    for sc, ax, lv in FAULTS:
        out += [fault_case(len(out) + j, sc, ax, lv, rng, cfg, grade="mems")
                for j in range(per_fault)]
    return out


def outcome(case: Case3D, post: dict) -> str:
    if post["isolation"] != "single":
        return post["isolation"]
    f = post["fault"] or {}
    named = (f.get("sensor"), f.get("axis"))
    return "right" if case.scenario != "nominal" and named == (case.sensor, case.axis) else "wrong"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--lengths", default="300,600,1200", help="flight lengths, s")
    ap.add_argument("--nominal", type=int, default=12)
    ap.add_argument("--per-fault", type=int, default=4)
    ap.add_argument("--seed", type=int, default=13)
    ap.add_argument("--linear", action="store_true", help="the model linear about zero")
    ap.add_argument("--records", required=True, help="JSON lines out")
    a = ap.parse_args(argv)
    if a.linear:
        analysis.RELINEARIZE_RAD = analysis.RELINEARIZE_MPS2 = float("inf")
        relinearize.VALID_RAD = float("inf")
    tally: dict[float, dict[str, Counter]] = {}
    with open(a.records, "w") as out:
        for dur in (float(x) for x in a.lengths.split(",")):
            cfg = Study3DConfig(nominal=0, per_scenario=1, grade="mems", duration_s=dur,
                                profile="cruise_turns", seed=2, single_axis=False)
            for c in cases(cfg, a.nominal, a.per_fault, a.seed):
                post, _ = ins3d_post_flight(simulate_case(c, cfg), cfg, "mems")
                res = outcome(c, post)
                group = "nominal" if c.scenario == "nominal" else "faults"
                tally.setdefault(dur, {}).setdefault(group, Counter())[res] += 1
                out.write(json.dumps({"duration_s": dur, "scenario": c.scenario, "axis": c.axis,
                                      "level": c.level, "onset_s": c.onset_s, "outcome": res,
                                      "model_validity": post.get("model_validity"),
                                      "relinearization": post.get("relinearization"),
                                      "headline": post["headline"]}) + "\n")
                out.flush()
    for dur, groups in tally.items():
        print(f"{dur:.0f} s: " + "; ".join(f"{g} {dict(c)}" for g, c in groups.items()))
    return 0


if __name__ == "__main__":
    sys.exit(main())
