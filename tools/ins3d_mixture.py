"""The onset mixture M (flight_fdi/eval/mixture3d.py) on nominal calibration flights or on the
2-h `cruise_turns` vertical gyro study (docs/ins3d_eval.md, "Seventh evaluation"). Each flight's
row is appended to --out (JSON lines) as it arrives. Usage::

    .venv/bin/python tools/ins3d_mixture.py nominal --flights 160 --seed0 20000 --jobs 2 \\
        --out out/mix/nominal_2h.jsonl
    .venv/bin/python tools/ins3d_mixture.py zstudy --jobs 2 --out out/mix/z.jsonl
    .venv/bin/python tools/ins3d_mixture.py xystudy --jobs 2 --out out/mix/xy.jsonl
    .venv/bin/python tools/ins3d_mixture.py randomz --jobs 2 --out out/mix/random_z.jsonl
    .venv/bin/python tools/ins3d_mixture.py nominal --flights 90 --duration 1800 --seed0 21000 \\
        --jobs 2 --out out/mix/nominal_30min.jsonl
    .venv/bin/python tools/ins3d_mixture.py report --out out/mix/nominal_2h.jsonl \\
        --faults out/mix/z.jsonl out/mix/xy.jsonl --short out/mix/nominal_30min.jsonl
"""
from __future__ import annotations

import argparse
import json
import math
import sys
import time

from flight_fdi.core.ins3d.grade_file import resolve_grade
from flight_fdi.eval.calibrate3d import plan
from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.mixture3d import fault_mixture, nominal_mixture
from flight_fdi.eval.montecarlo3d import Study3DConfig, plan_study
from flight_fdi.eval.parallel import parallel_map

#: the z study of the fifth evaluation: (seed, levels), 2-h `cruise_turns`, axes ("z",)
Z_STUDY = ((111, (0.05, 0.1, 0.2)), (115, (0.05,)))


def z_items(level: float | None = 0.05, axes: tuple[str, ...] = ("z",),
            study: tuple = Z_STUDY, profile: str = "cruise_turns") -> list[tuple]:
    """(case, config) of the z study's flights (``axes``: its x / y flights instead; ``study``
    and ``profile``: another 2-h gyro step study) at ``level`` (deg/h; None: all)."""
    items = []
    for seed, levels in study:
        cfg = Study3DConfig(nominal=0, per_scenario=90, scenarios=("gyro_step",),
                            levels={"gyro_step": levels}, duration_s=7200.0,
                            profile=profile, seed=seed, axes=axes)
        items += [(c, cfg) for c in plan_study(cfg) if level is None or c.level == level]
    return items


def _read(path: str) -> list[dict]:
    with open(path) as f:
        return [json.loads(x) for x in f if x.strip()]


def _excess_rule(rec: dict, thr: dict[str, float], key: str) -> tuple[str | None, int]:
    """(the hypothesis with the largest excess of ``key`` over its threshold if any exceeds,
    how many exceed): the decision by excess of ``glr3d.isolate`` without its margin."""
    ex = {h: rec[key][h] - thr[h] for h in thr}
    best = max(ex, key=ex.get)
    n = sum(v > 0 for v in ex.values())
    return (best if n else None), n


def report_procedure(short: str, nominal: str, faults: list[str]) -> None:
    """Both statistics' thresholds by the grade's procedure (``procedure_thresholds``) and the
    fault flights above them and named by the largest excess (sensor and axis)."""
    from flight_fdi.eval.mixture3d import procedure_thresholds

    s, lo = _read(short), _read(nominal)
    for k in ("M", "glr"):
        thr = procedure_thresholds(s, lo, k)
        print(f"grade's procedure, {k}: gyro z step {thr['gyro_z_step']:.2f}; held-in flights "
              f"above any: {sum(_excess_rule(r, thr, k)[0] is not None for r in lo)}/{len(lo)}")
        for path in faults:
            recs = _read(path)
            above = sum(r[k][f"{r['sensor']}_{r['axis']}_step"] > thr[
                f"{r['sensor']}_{r['axis']}_step"] for r in recs)
            named = sum((_excess_rule(r, thr, k)[0] or "").startswith(
                f"{r['sensor']}_{r['axis']}_") for r in recs)
            print(f"  {path}: above {above}/{len(recs)}, its sensor and axis the largest "
                  f"excess {named}")


def report(nominal: str, faults: list[str], p: tuple[float, ...] = (5e-4, 0.01)) -> None:
    """Per hypothesis: the nominal flights' M and GLR (median / 90 % / largest), their tail
    thresholds at each p; per fault file: flights whose true hypothesis' M / GLR exceeds each."""
    import numpy as np

    from flight_fdi.eval.mixture3d import tail_thresholds

    rows = _read(nominal)
    thr = {(k, q): tail_thresholds(rows, q, k) for k in ("M", "glr") for q in p}
    print(f"{len(rows)} nominal flights, seeds {min(r['seed'] for r in rows)}-"
          f"{max(r['seed'] for r in rows)}")
    for h in rows[0]["M"]:
        line = []
        for k in ("M", "glr"):
            x = np.array([r[k][h] for r in rows])
            line.append(f"{k} {np.median(x):.1f}/{np.quantile(x, 0.9):.1f}/{x.max():.1f} thr "
                        + "/".join(f"{thr[(k, q)][h]:.1f}" for q in p))
        print(f"{h:22s} " + "  ".join(line))
    for q in p:     # Markov: E_0 BF = 1 under the filter's model, so P_0(M > 2 ln 1/p) <= p
        mk = {h: 2.0 * math.log(1.0 / q) for h in rows[0]["M"]}
        thr[("markov", q)] = mk
        print(f"nominal: M above 2 ln(1/{q:g}) = {mk['gyro_z_step']:.1f}: gyro_z_step on "
              f"{sum(r['M']['gyro_z_step'] > mk['gyro_z_step'] for r in rows)}, any on "
              f"{sum(_excess_rule(r, mk, 'M')[0] is not None for r in rows)} flights")
    for k in ("M", "glr"):
        for q in p:
            fa = sum(_excess_rule(r, thr[(k, q)], k)[0] is not None for r in rows)
            print(f"nominal (in-sample): a hypothesis' {k} above its p = {q:g} threshold on "
                  f"{fa}/{len(rows)} flights")
    for path in faults:
        recs = _read(path)
        for k in ("M", "glr"):
            for q in p:
                dec = [_excess_rule(r, thr[(k, q)], k) for r in recs]
                step = sum(b == f"{r['sensor']}_{r['axis']}_step" for (b, _), r in
                           zip(dec, recs))
                axis = sum(b is not None and b.startswith(f"{r['sensor']}_{r['axis']}_")
                           for (b, _), r in zip(dec, recs))
                print(f"{path}: {k} p = {q:g}: largest excess the true step {step}/{len(recs)}, "
                      f"its sensor and axis (step or ramp) {axis}; more than one above on "
                      f"{sum(n > 1 for _, n in dec)}")
        for k in ("M", "glr", "markov"):
            for q in p:
                hits = sum(r["glr" if k == "glr" else "M"][f"{r['sensor']}_{r['axis']}_step"]
                           > thr[(k, q)][
                    f"{r['sensor']}_{r['axis']}_step"] for r in recs)
                print(f"{path}: {k} above its p = {q:g} threshold: {hits}/{len(recs)}")
        right = sum(r["ins3d"]["isolation"] == "single" and (r["ins3d"]["sensor"],
                    r["ins3d"]["axis"]) == (r["sensor"], r["axis"]) for r in recs)
        print(f"{path}: the isolator (glr3d.isolate, main's thresholds) right: {right}/{len(recs)}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("what", choices=("nominal", "zstudy", "xystudy", "randomz", "report"))
    ap.add_argument("--faults", nargs="*", default=[], help="report: fault-flight files")
    ap.add_argument("--short", default="", help="report: 30-min nominal rows (the grade's "
                    "procedure: thresholds pooled over both lengths)")
    ap.add_argument("--flights", type=int, default=160)
    ap.add_argument("--seed0", type=int, default=20000)
    ap.add_argument("--duration", type=float, default=7200.0)
    ap.add_argument("--jobs", type=int, default=1)
    ap.add_argument("--out", required=True, help="rows (JSON lines); report: the nominal rows")
    a = ap.parse_args()
    if a.what == "report":
        report(a.out, a.faults)
        if a.short:
            report_procedure(a.short, a.out, a.faults)
        return
    if a.what == "nominal":
        fn, items = nominal_mixture, plan(resolve_grade("navigation"), a.flights, a.seed0,
                                          duration_s=a.duration)
    elif a.what == "zstudy":
        fn, items = fault_mixture, z_items()
    elif a.what == "xystudy":   # the x / y flights at 0.05 deg/h of seed 115 (90 extra)
        fn, items = fault_mixture, z_items(axes=("x", "y"), study=Z_STUDY[1:])
    else:           # the z flights of the 2-h `random` gyro step study (seed 11), all levels
        fn, items = fault_mixture, z_items(None, study=((11, (0.05, 0.1, 0.2)),),
                                           profile="random")
    t0 = time.time()

    def arrived(r: dict) -> None:
        r["elapsed_s"] = round(time.time() - t0, 1)
        with open(a.out, "a") as f:
            f.write(json.dumps(r) + "\n")

    parallel_map(fn, items, a.jobs, on_result=arrived)
    print(f"{len(items)} flights in {time.time() - t0:.0f} s")


if __name__ == "__main__":
    try:
        main()
    except (OSError, ValueError, KeyError, EvalError) as exc:
        sys.exit(f"ins3d_mixture: {exc}")
