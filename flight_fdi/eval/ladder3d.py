"""The smallest body-axis fault the 3-D model isolates in 95 % of runs, per sensor, axis and
IMU grade (a preset or a YAML grade file): a descending ladder of magnitudes (issue 15, item 5).

A grade file's flights are simulated with its values and analysed with its model and GLR
thresholds (``montecarlo3d.study_grade``, the path of ``montecarlo --grade FILE``); its ladder
starts at its base preset's top (``ladder_top``).

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
from .montecarlo3d import (SCENARIOS, Case3D, Study3DConfig, fault_case, grade_name,
                           run_cases, study_grade)

#: top of the ladder per grade and scenario (scenario units): a fault the grade's isolator
#: should find every time (the turn-on bias and instability of the preset set the scale)
LADDER_TOP = {
    "navigation": {"accel_step": 1.0, "gyro_step": 0.2, "accel_ramp": 4.0, "gyro_ramp": 2.0},
    "tactical": {"accel_step": 4.0, "gyro_step": 4.0, "accel_ramp": 16.0, "gyro_ramp": 32.0},
    "mems": {"accel_step": 20.0, "gyro_step": 100.0, "accel_ramp": 80.0, "gyro_ramp": 800.0},
}


def ladder_top(grade: Any) -> dict[str, float]:
    """The top levels of a preset name, or of an ImuGrade: its preset's, a grade file's its
    base's (``grade_file.CustomGrade.base``)."""
    name = grade if isinstance(grade, str) else getattr(grade, "base", "") or grade.name
    if name not in LADDER_TOP:
        raise EvalError(f"grade {grade_name(grade)!r}: no ladder top for base {name!r} "
                        f"(choose a base among {', '.join(LADDER_TOP)})")
    return LADDER_TOP[name]


def grade_info(grade: Any, duration_s: float) -> dict:
    """What a ladder records of a grade: its name, its GLR thresholds for the flights' length
    (``grade_file.grade_thresholds``: what the analysis uses) and, for a grade file, its
    values (SI)."""
    from flight_fdi.core.ins3d.grade_file import grade_thresholds, resolve_grade

    g = resolve_grade(grade)
    out = {"name": grade_name(grade), "preset": isinstance(grade, str),
           "thresholds": grade_thresholds(g, duration_s)}
    if not isinstance(grade, str):
        out["values"] = g.to_dict()
    return out


def _group_cases(config: Study3DConfig, key: tuple[int, int, int], grade: Any, scenario: str,
                 axis: str, rung: int, level: float, runs: int, start: int) -> list[Case3D]:
    rng = np.random.default_rng(np.random.SeedSequence([config.seed, *key, rung]))
    return [fault_case(start + j, scenario, axis, level, rng, config, grade=grade)
            for j in range(runs)]


def _climb(gr: dict, records: list[dict], factor: float, rungs: int) -> None:
    """Record a rung's outcomes and choose the next level: down while the rungs pass (from a
    passing top), up until one passes (from a failing top), at most ``rungs`` rungs. A rung
    also records the median over its flights of the true hypothesis' largest GLR."""
    level = gr["next"]
    oc = [outcome(r, "ins3d") for r in records]
    rate = oc.count("right") / len(oc)
    st = [r["ins3d"]["glr_statistics"][gr["hypothesis"]] for r in records
          if gr["hypothesis"] in (r["ins3d"].get("glr_statistics") or {})]
    gr["rungs"].append({"level": level, "n": len(oc), "right_rate": rate,
                        **{o: oc.count(o) for o in OUTCOMES},
                        "statistic_median": float(np.median(st)) if st else None})
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


def run_ladder(config: Study3DConfig, grades: tuple = ("navigation",),
               scenarios: tuple[str, ...] = ("accel_step", "gyro_step"), runs: int = 10,
               rungs: int = 5, factor: float = 2.0, jobs: int = 1, progress: bool = False,
               scheduler: str | None = None) -> dict:
    """The ladder of every (grade, scenario, axis): rungs run, their rates, the smallest level
    isolated in >= 95 % (None when no rung passed). ``grades``: preset names, YAML grade files
    or ImuGrades (``montecarlo3d.study_grade``). ``config`` gives the flights (duration,
    profile, GNSS, onset window, seed); its grade is replaced per group. A group's flights'
    seeds come from its grade's position in ``grades``, not its name: a grade file in the
    place of a preset flies the preset's flights."""
    grades = tuple(study_grade(g) for g in grades)
    names = [grade_name(g) for g in grades]
    if len(set(names)) < len(names):
        raise EvalError(f"ladder: two grades named alike ({', '.join(names)})")
    tops = [ladder_top(g) for g in grades]
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
                groups[(gi, si, ai)] = {"grade": names[gi], "of": g, "scenario": s,
                                        "axis": ax, "unit": SCENARIOS[s][5], "rungs": [],
                                        "hypothesis": f"{SCENARIOS[s][2]}_{ax}_{SCENARIOS[s][3]}",
                                        "active": True, "direction": None, "next": tops[gi][s]}
    start = time.perf_counter()
    rung = 0
    while any(gr["active"] for gr in groups.values()):
        cases: list[Case3D] = []
        owner: dict[int, tuple[int, int, int]] = {}
        for key, gr in groups.items():
            if gr["active"]:
                new = _group_cases(cfg, key, gr["of"], gr["scenario"], gr["axis"], rung,
                                   gr["next"], runs, len(cases))
                owner.update({c.index: key for c in new})
                cases += new
        records = run_cases(cases, cfg, jobs, progress, scheduler=scheduler,
                            desc=f"ladder rung {rung + 1}/{rungs}")
        for key, gr in groups.items():
            if gr["active"]:
                _climb(gr, [r for r in records if owner[r["index"]] == key], factor, rungs)
        rung += 1
    out = []
    for gr in groups.values():
        ok = [r["level"] for r in gr["rungs"] if r["right_rate"] >= ISOLATION_LEVEL]
        out.append({k: gr[k] for k in ("grade", "scenario", "axis", "hypothesis", "unit",
                                       "rungs", "direction")}
                   | {"smallest_95": min(ok) if ok else None,
                      "bottom_reached": gr["direction"] == "down"
                      and len(ok) == len(gr["rungs"])})
    return {"runs_per_rung": runs, "factor": factor, "max_rungs": rungs,
            "duration_s": config.duration_s, "profile": config.profile, "seed": config.seed,
            "grades": [grade_info(g, config.duration_s) for g in grades],
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


__all__ = ["LADDER_TOP", "format_ladder", "grade_info", "ladder_top", "run_ladder"]
