"""Calibrate the ins3d GLR thresholds on nominal simulated flights (docs/ins3d.md, "Thresholds").

The flights are the simulator's (sim/ins3d.py): scale factors and misalignments (not states of the
estimator's model), correlated GNSS noise with latency, a baro-damped INS -- not data the
estimator's own model generated. Per flight the maximum GLR over the onsets of every hypothesis
kind is recorded; the thresholds are then chosen above all of them (printed with the
distribution). Usage::

    .venv/bin/python tools/ins3d_calibrate.py --flights 20 --duration 1800 --out out/calib.json
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np

from flight_fdi.eval.parallel import parallel_map
from flight_fdi.bagio.ins3d_input import from_flight
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
from flight_fdi.sim.trajectory import TrajectoryConfig

KINDS = ("step", "ramp", "jump", "outliers")


def one(profile: str, duration: float, grade: str, seed: int) -> dict:
    """The largest GLR per hypothesis kind (and its hypothesis) of one nominal flight."""
    cfg = Sim3DConfig(TrajectoryConfig(profile=profile, duration_s=duration, rate_hz=100.0,
                                       seed=seed), grade=grade, seed=seed)
    inp = from_flight(simulate3d(cfg))
    a = analyze_ins3d(inp.steps, inp.refs, grade=grade, with_observability=False,
                      **inp.vertical())   # the flight's own height loop, as the evaluation
    best = {k: max((c.statistic, n) for n, c in a.glr.items() if c.hypothesis.kind == k)
            for k in KINDS}
    return {"profile": profile, "seed": seed, "grade": grade, "duration_s": duration,
            "max": {k: v[0] for k, v in best.items()},
            "argmax": {k: v[1] for k, v in best.items()},
            "verdict": a.post_flight_dict()["verdict"]}


def _one(item: tuple) -> dict:
    return one(*item)


def summary(rows: list[dict]) -> dict[str, dict[str, float]]:
    """Per kind: the largest, median and 90 % quantile of the flights' maxima."""
    out = {}
    for k in KINDS:
        m = np.array([r["max"][k] for r in rows])
        out[k] = {"max": float(m.max()), "median": float(np.median(m)),
                  "q90": float(np.quantile(m, 0.9))}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--flights", type=int, default=20)
    ap.add_argument("--duration", type=float, default=1800.0)
    ap.add_argument("--grade", default="navigation")
    ap.add_argument("--seed0", type=int, default=1000)
    ap.add_argument("--profiles", default="cruise_turns,random,survey_grid")
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", default="")
    a = ap.parse_args()
    profs = [p for p in a.profiles.split(",") if p]
    items = [(profs[i % len(profs)], a.duration, a.grade, a.seed0 + i) for i in range(a.flights)]
    t0 = time.time()

    def arrived(r: dict) -> None:
        print(f"{r['profile']} seed {r['seed']}: "
              + ", ".join(f"{k} {r['max'][k]:.1f} ({r['argmax'][k]})" for k in KINDS)
              + f" -> {r['verdict']}  [{time.time() - t0:.0f} s]", flush=True)

    rows = sorted(parallel_map(_one, items, a.jobs, desc="calibrate", on_result=arrived),
                  key=lambda r: r["seed"])
    for k, v in summary(rows).items():
        print(f"{k}: max over flights {v['max']:.1f}, median {v['median']:.1f}, "
              f"90 % {v['q90']:.1f}")
    if a.out:
        with open(a.out, "w") as f:
            json.dump(rows, f, indent=1)


if __name__ == "__main__":
    main()
