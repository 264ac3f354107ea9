"""The smallest body-axis fault the 3-D model isolates in 95 % of runs, per sensor, axis and
IMU grade preset: a descending ladder of magnitudes (issue 15, item 5).

For every (grade, scenario, axis) *group* the ladder starts at the grade's top level; every rung
runs ``runs`` flights. When the top rung isolates the fault (right sensor and axis) in >= 95 % the
ladder climbs down, dividing the level by ``factor`` per rung, and stops at the first rung below
95 %; when the top rung falls short it climbs up, multiplying by ``factor``, until a rung passes.
At most ``rungs`` rungs per group. All
active groups' rungs of one round run together on the campaign engine. Each flight's seeds come
from (study seed, grade, scenario, axis, rung, run), so the result does not depend on the worker
count or on which groups are still active.
"""
from __future__ import annotations

import time
from dataclasses import replace
from typing import Any

import numpy as np

from .errors import EvalError
from .metrics3d import ISOLATION_LEVEL, OUTCOMES, outcome
from .montecarlo3d import GRADES, SCENARIOS, Case3D, Study3DConfig, fault_case, run_cases

#: top of the ladder per grade and scenario (scenario units): a fault the grade's isolator
#: should find every time (the turn-on bias and instability of the preset set the scale)
LADDER_TOP = {
    "navigation": {"accel_step": 1.0, "gyro_step": 0.2, "accel_ramp": 4.0, "gyro_ramp": 2.0},
    "tactical": {"accel_step": 4.0, "gyro_step": 4.0, "accel_ramp": 16.0, "gyro_ramp": 32.0},
    "mems": {"accel_step": 20.0, "gyro_step": 100.0, "accel_ramp": 80.0, "gyro_ramp": 800.0},
}


def _group_cases(config: Study3DConfig, key: tuple[int, int, int], grade: str, scenario: str,
                 axis: str, rung: int, level: float, runs: int, start: int) -> list[Case3D]:
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, *key, rung]))
    return [fault_case(start + j, scenario, axis, level, rng, config, grade=grade)
            for j in range(runs)]


def _climb(gr: dict, oc: list[str], factor: float, rungs: int) -> None:
    """Record a rung's outcomes and choose the next level: down while the rungs pass (from a
    passing top), up until one passes (from a failing top), at most ``rungs`` rungs."""
    level = gr["next"]
    rate = oc.count("right") / len(oc)
    gr["rungs"].append({"level": level, "n": len(oc), "right_rate": rate,
                        **{o: oc.count(o) for o in OUTCOMES}})
    passed = rate >= ISOLATION_LEVEL
    if gr["direction"] is None:
        gr["direction"] = "down" if passed else "up"
    more = len(gr["rungs"]) < rungs
    if gr["direction"] == "down" and passed and more:
        gr["next"] = float(f"{level / factor:.3g}")
    elif gr["direction"] == "up" and not passed and more:
        gr["next"] = float(f"{level * factor:.3g}")
    else:
        gr["active"] = False


def run_ladder(config: Study3DConfig, grades: tuple[str, ...] = ("navigation",),
               scenarios: tuple[str, ...] = ("accel_step", "gyro_step"), runs: int = 10,
               rungs: int = 5, factor: float = 2.0, jobs: int = 1, progress: bool = False,
               scheduler: str | None = None) -> dict:
    """The ladder of every (grade, scenario, axis): rungs run, their rates, the smallest level
    isolated in >= 95 % (None when no rung passed). ``config`` gives the
    flights (duration, profile, GNSS, onset window, seed); its grade is replaced per group."""
    for g in grades:
        if g not in GRADES:
            raise EvalError(f"unknown grade {g!r}; choose from {', '.join(GRADES)}")
    for s in scenarios:
        if s not in SCENARIOS or s == "ref_jump":
            raise EvalError(f"ladder scenario must be an IMU scenario, got {s!r}")
    if isinstance(runs, bool) or not isinstance(runs, int) or runs < 1 or rungs < 1 \
            or not factor > 1.0:
        raise EvalError("ladder: runs and rungs must be >= 1 and factor > 1")
    cfg = replace(config, single_axis=False)
    groups: dict[tuple[int, int, int], dict[str, Any]] = {}
    for gi, g in enumerate(grades):
        for si, s in enumerate(scenarios):
            for ai, ax in enumerate(SCENARIOS[s][4]):
                groups[(gi, si, ai)] = {"grade": g, "scenario": s, "axis": ax,
                                        "unit": SCENARIOS[s][5], "rungs": [], "active": True,
                                        "direction": None, "next": LADDER_TOP[g][s]}
    start = time.perf_counter()
    rung = 0
    while any(gr["active"] for gr in groups.values()):
        cases: list[Case3D] = []
        owner: dict[int, tuple[int, int, int]] = {}
        for key, gr in groups.items():
            if gr["active"]:
                new = _group_cases(cfg, key, gr["grade"], gr["scenario"], gr["axis"], rung,
                                   gr["next"], runs, len(cases))
                owner.update({c.index: key for c in new})
                cases += new
        records = run_cases(cases, cfg, jobs, progress, scheduler=scheduler,
                            desc=f"ladder rung {rung + 1}/{rungs}")
        for key, gr in groups.items():
            if gr["active"]:
                _climb(gr, [outcome(r, "ins3d") for r in records if owner[r["index"]] == key],
                       factor, rungs)
        rung += 1
    out = []
    for gr in groups.values():
        ok = [r["level"] for r in gr["rungs"] if r["right_rate"] >= ISOLATION_LEVEL]
        out.append({k: gr[k] for k in ("grade", "scenario", "axis", "unit", "rungs",
                                       "direction")}
                   | {"smallest_95": min(ok) if ok else None,
                      "bottom_reached": gr["direction"] == "down"
                      and len(ok) == len(gr["rungs"])})
    return {"runs_per_rung": runs, "factor": factor, "max_rungs": rungs,
            "duration_s": config.duration_s, "profile": config.profile, "seed": config.seed,
            "elapsed_s": time.perf_counter() - start, "groups": out}


def format_ladder(ladder: dict) -> str:
    lines = [f"smallest fault isolated (right sensor and axis) in >= "
             f"{100 * ISOLATION_LEVEL:.0f} % of {ladder['runs_per_rung']} runs per rung "
             f"(ladder by x{ladder['factor']:g} from the top level, down while it passes, "
             f"up while it fails; flights of "
             f"{ladder['duration_s']:g} s, profile {ladder['profile']}):", "",
             "| grade | fault | axis | smallest 95 % | rungs (level: right/n) |",
             "|---|---|---|---|---|"]
    for g in ladder["groups"]:
        sm = g["smallest_95"]
        if sm is None:
            txt = f"not reached (> {max(r['level'] for r in g['rungs']):g} {g['unit']})"
        else:
            txt = f"{sm:g} {g['unit']}" + (" (bottom rung)" if g["bottom_reached"] else "")
        rungs = ", ".join(f"{r['level']:g}: {r['right']}/{r['n']}" for r in g["rungs"])
        lines.append(f"| {g['grade']} | {g['scenario']} | {g['axis']} | {txt} | {rungs} |")
    return "\n".join(lines)


__all__ = ["LADDER_TOP", "format_ladder", "run_ladder"]
