"""The onset mixture M (flight_fdi/eval/mixture3d.py) on nominal calibration flights or on the
2-h `cruise_turns` vertical gyro study (docs/ins3d_eval.md, "Seventh evaluation"). Each flight's
row is appended to --out (JSON lines) as it arrives. Usage::

    .venv/bin/python tools/ins3d_mixture.py nominal --flights 160 --seed0 20000 --jobs 2 \\
        --out out/mix/nominal_2h.jsonl
    .venv/bin/python tools/ins3d_mixture.py zstudy --jobs 2 --out out/mix/z.jsonl
"""
from __future__ import annotations

import argparse
import json
import time

from flight_fdi.core.ins3d.grade_file import resolve_grade
from flight_fdi.eval.calibrate3d import plan
from flight_fdi.eval.mixture3d import fault_mixture, nominal_mixture
from flight_fdi.eval.montecarlo3d import Study3DConfig, plan_study
from flight_fdi.eval.parallel import parallel_map

#: the z study of the fifth evaluation: (seed, levels), 2-h `cruise_turns`, axes ("z",)
Z_STUDY = ((111, (0.05, 0.1, 0.2)), (115, (0.05,)))


def z_items(level: float = 0.05) -> list[tuple]:
    """(case, config) of the z study's flights at ``level`` (deg/h)."""
    items = []
    for seed, levels in Z_STUDY:
        cfg = Study3DConfig(nominal=0, per_scenario=90, scenarios=("gyro_step",),
                            levels={"gyro_step": levels}, duration_s=7200.0,
                            profile="cruise_turns", seed=seed, axes=("z",))
        items += [(c, cfg) for c in plan_study(cfg) if c.level == level]
    return items


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("nominal", "zstudy"))
    ap.add_argument("--flights", type=int, default=160)
    ap.add_argument("--seed0", type=int, default=20000)
    ap.add_argument("--duration", type=float, default=7200.0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", required=True)
    a = ap.parse_args()
    if a.what == "nominal":
        fn, items = nominal_mixture, plan(resolve_grade("navigation"), a.flights, a.seed0,
                                          duration_s=a.duration)
    else:
        fn, items = fault_mixture, z_items()
    t0 = time.time()

    def arrived(r: dict) -> None:
        r["elapsed_s"] = round(time.time() - t0, 1)
        with open(a.out, "a") as f:
            f.write(json.dumps(r) + "\n")

    parallel_map(fn, items, a.jobs, on_result=arrived)
    print(f"{len(items)} flights in {time.time() - t0:.0f} s")


if __name__ == "__main__":
    main()
