"""Onset-error statistics of the Monte Carlo study (docs/montecarlo.md): GLR's onset estimate
per fault kind and magnitude level, over the flights where GLR names the true fault -- isolated
with confidence, or among the candidates of an ambiguous result (on one velocity channel a gyro
drift step and an accelerometer ramp of -g times it are the same fault signature, so a gyro step
is always reported beside its twin)."""
from __future__ import annotations

from typing import Any, Sequence

from .decisions import (FAULT_KINDS, LEVEL_UNITS, fmt_num, stats_of, declared, glr_class,
                        isolated)


def named_onset(record: dict) -> float | None:
    """GLR's onset for the true fault when GLR names it: isolated (one confident hypothesis of
    the true class), or ambiguous with the true class among the candidates (e.g. a gyro step
    beside its twin, the accelerometer ramp); None otherwise."""
    if record["kind"] == "nominal" or not declared(record, "glr"):
        return None
    if isolated(record, "glr"):
        return record["glr"]["onset_s"]
    for c in record["glr"].get("candidates", []):
        if glr_class(c["hypothesis"]) == record["true_element"]:
            return c["onset_s"]
    return None


def onset_errors(records: Sequence[dict]) -> dict:
    """GLR's onset error (estimate - truth) per fault kind, overall and per magnitude level,
    over the flights where GLR names the true fault (:func:`named_onset`): counts of isolated
    and named flights, median and 95th percentile of |error|, median signed error."""
    out: dict[str, Any] = {}
    for kind in FAULT_KINDS:
        rs = [r for r in records if r["kind"] == kind]
        if not rs:
            continue

        def row(group: list[dict]) -> dict:
            err = [named_onset(r) - r["onset_s"] for r in group if named_onset(r) is not None]
            a = stats_of(abs(e) for e in err)
            return {"n": len(group), "isolated": sum(isolated(r, "glr") for r in group),
                    "named": len(err), "median_abs_s": a["median"], "p95_abs_s": a["p95"],
                    "median_s": stats_of(err)["median"]}

        levels = sorted({r["level"] for r in rs})
        out[kind] = {"unit": LEVEL_UNITS[kind][0], "all": row(rs),
                     "by_level": [{"level": lv, **row([r for r in rs if r["level"] == lv])}
                                  for lv in levels]}
    named = [r for r in records if named_onset(r) is not None]
    out["all"] = {"named": len(named), "median_abs_s": stats_of(
        abs(named_onset(r) - r["onset_s"]) for r in named)["median"]}
    return out


def format_onset_errors(table: dict) -> str:
    """The onset-error table of :func:`onset_errors` as Markdown."""
    lines = ["| fault | level | flights | GLR isolated | GLR named (isolated or ambiguous) | "
             "median abs onset error s | 95 % abs s | median signed s |",
             "|---|---|---|---|---|---|---|---|"]
    for kind in FAULT_KINDS:
        if kind not in table:
            continue
        t = table[kind]
        for r in t["by_level"] + [{"level": "all", **t["all"]}]:
            lvl = r["level"] if r["level"] == "all" else f"{r['level']:g} {t['unit']}"
            lines.append(f"| {kind} | {lvl} | {r['n']} | {r['isolated']} | {r['named']} | "
                         f"{fmt_num(r['median_abs_s'], '.2f')} | "
                         f"{fmt_num(r['p95_abs_s'], '.1f')} | "
                         f"{fmt_num(r['median_s'], '.2f')} |")
    lines.append(f"\nall named faults: n {table['all']['named']}, median |onset error| "
                 f"{fmt_num(table['all']['median_abs_s'], '.2f')} s")
    return "\n".join(lines)


