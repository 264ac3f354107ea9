"""Metrics of a 3-D Monte Carlo study (:mod:`flight_fdi.eval.montecarlo3d`) from its records,
for the 3-D model and the single-axis model side by side.

Outcome of one flight for one model (:func:`outcome`):

* ``none``: no fault declared (verdict ``no_fault`` / ``insufficient_data``, isolation none);
* ``right``: one fault isolated with confidence (isolation ``single``) naming the true sensor
  *and* axis (the kind -- step or ramp -- is scored separately: ``right_kind``);
* ``wrong``: isolated with confidence, but another sensor or another axis (on a nominal flight:
  any confident isolation -- a *false isolation*);
* ``ambiguous``: a fault declared but no single sensor named (isolation ``ambiguous``: two
  explanations within the margin, both named; or ``unexplained``). Not a false isolation, but
  counted: on a nominal flight it is a false *declaration*;
* ``unnamed``: GLR isolates nothing but the verdict still declares a fault (the seed method's
  chi-square episode: ``failure`` / ``glitch`` without a sensor). Also a declaration.

The single-axis model works on one navigation-frame velocity channel: it can name the sensor but
not a body axis, so for IMU faults only its right-*sensor* rate is scored (its sensor+axis rate is
``None``); for GNSS jumps its axis is the channel (east / north) and is scored.

Onset error: estimated minus true onset over the ``right`` flights (median of the absolute value
is the issue's target, <= 5 s); onset coverage: the fraction of the right flights whose stated
95 % onset interval (``onset_interval_s``) contains the true onset; magnitude error:
estimated / true - 1 over the right flights whose kind is right too (a ramp reported as a step has
a magnitude in other units).
Smallest fault isolated in 95 %: the smallest level from which the rate of ``right`` is >= 95 %
at that level and at every larger level (per scenario and axis).
"""
from __future__ import annotations

from typing import Any, Iterable, Sequence

import numpy as np

from .decisions import rate_of, stats_of
from .montecarlo3d import DECLARED, MODELS, SCENARIOS

ISOLATION_LEVEL = 0.95
OUTCOMES = ("none", "right", "wrong", "ambiguous", "unnamed")


def outcome(record: dict, model: str) -> str:
    """The outcome of ``model`` on this flight (see the module docstring)."""
    d = record[model]
    iso = d.get("isolation", "none")
    if d["verdict"] not in DECLARED:
        return "none"
    if iso == "none":
        return "unnamed"
    if iso != "single":
        return "ambiguous"
    if record["sensor"] is None:
        return "wrong"
    if d["sensor"] != record["sensor"]:
        return "wrong"
    if axis_scored(record, model) and d["axis"] != record["axis"]:
        return "wrong"
    return "right"


def axis_scored(record: dict, model: str) -> bool:
    """Whether ``model``'s axis can be judged on this flight (not the single-axis model on a
    body-axis IMU fault)."""
    return not (model == "single_axis" and record["sensor"] in ("accelerometer", "gyro"))


def named(record: dict, model: str) -> bool:
    """The true sensor and axis are isolated, or among the candidates of an ambiguous result."""
    oc = outcome(record, model)
    if oc == "right":
        return True
    if oc != "ambiguous":
        return False
    scored = axis_scored(record, model)
    return any(c.get("sensor") == record["sensor"]
               and (not scored or c.get("axis") == record["axis"])
               for c in record[model].get("candidates", []))


def _stats(values: Iterable[float | None]) -> dict:
    """``decisions.stats_of`` of the values given (None: left out), with the median of their
    absolute values (``median_abs``)."""
    v = [x for x in values if x is not None]
    return {**stats_of(v), "median_abs": float(np.median(np.abs(v))) if v else None}


def rates(records: Sequence[dict], model: str) -> dict:
    """Counts and rates of the outcomes, onset and magnitude errors of ``model``."""
    n = len(records)
    oc = [outcome(r, model) for r in records]
    right = [r for r, o in zip(records, oc) if o == "right"]
    scored = all(axis_scored(r, model) for r in records) if records else True
    out: dict[str, Any] = {"n": n, **{o: oc.count(o) for o in OUTCOMES}}
    out["right_rate"] = rate_of(oc.count("right"), n) if scored else None
    out["right_sensor_rate"] = rate_of(sum(o in ("right", "wrong") and r[model]["sensor"] ==
                                         r["sensor"] for r, o in zip(records, oc)), n)
    out["wrong_rate"] = rate_of(oc.count("wrong"), n)
    out["ambiguous_rate"] = rate_of(oc.count("ambiguous"), n)
    out["missed_rate"] = rate_of(oc.count("none"), n)
    out["unnamed_rate"] = rate_of(oc.count("unnamed"), n)
    out["named_rate"] = rate_of(sum(named(r, model) for r in records), n) if scored else None
    out["right_kind"] = sum(r[model]["kind"] == r["kind"] for r in right)
    out["right_kind_rate"] = rate_of(out["right_kind"], n) if scored else None
    out["onset_error_s"] = _stats(None if r[model]["onset_s"] is None
                                  else r[model]["onset_s"] - r["onset_s"] for r in right)
    ivs = [(r[model].get("onset_interval_s"), r["onset_s"]) for r in right]
    ivs = [(iv, t) for iv, t in ivs if iv is not None and t is not None]
    out["onset_covered"] = sum(iv[0] - 1e-6 <= t <= iv[1] + 1e-6 for iv, t in ivs)
    out["onset_coverage"] = rate_of(out["onset_covered"], len(ivs))
    out["onset_interval_n"] = len(ivs)
    out["onset_interval_width_s"] = _stats(iv[1] - iv[0] for iv, _ in ivs)
    out["magnitude_error"] = _stats(None if r[model]["magnitude"] is None or not r["magnitude"]
                                    else r[model]["magnitude"] / r["magnitude"] - 1.0
                                    for r in right if r[model]["kind"] == r["kind"])
    return out


def binomial_interval(k: int, n: int, level: float = 0.95) -> tuple[float, float] | None:
    """The exact (Clopper-Pearson) two-sided ``level`` interval of a rate of ``k`` in ``n``
    (None when n = 0): the beta quantiles of k and k + 1; 0 / 1 at the ends."""
    from scipy.stats import beta

    if n == 0:
        return None
    if not 0 <= k <= n:
        raise ValueError(f"binomial_interval: need 0 <= k <= n, got k={k}, n={n}")
    a = (1.0 - level) / 2.0
    lo = 0.0 if k == 0 else float(beta.ppf(a, k, n - k + 1))
    hi = 1.0 if k == n else float(beta.ppf(1.0 - a, k + 1, n - k))
    return lo, hi


def _interval(k: int, n: int) -> list[float] | None:
    """:func:`binomial_interval` as JSON has it (a list): metrics equal after a round trip."""
    iv = binomial_interval(k, n)
    return None if iv is None else list(iv)


def nominal_rates(records: Sequence[dict], model: str) -> dict:
    """False isolation (a confident sensor on a nominal flight; its rate with the exact 95 %
    interval), false declaration (any fault declared, ambiguous included) and ambiguous counts
    on the nominal flights."""
    nom = [r for r in records if r["scenario"] == "nominal"]
    oc = [outcome(r, model) for r in nom]
    n = len(nom)
    return {"n": n, "false_isolations": oc.count("wrong"),
            "false_isolation_rate": rate_of(oc.count("wrong"), n),
            "false_isolation_interval": _interval(oc.count("wrong"), n),
            "ambiguous": oc.count("ambiguous"), "unnamed": oc.count("unnamed"),
            "false_declaration_rate": rate_of(n - oc.count("none"), n),
            "isolated_as": _count(r[model]["sensor"] for r, o in zip(nom, oc) if o == "wrong")}


def _count(items: Iterable[Any]) -> dict:
    out: dict[str, int] = {}
    for it in items:
        out[str(it)] = out.get(str(it), 0) + 1
    return out


def by_level(records: Sequence[dict], model: str, scenario: str) -> list[dict]:
    """Per axis and level of ``scenario``: n and the rates of :func:`rates`."""
    rows = []
    rs = [r for r in records if r["scenario"] == scenario]
    for axis in SCENARIOS[scenario][4]:
        for level in sorted({r["level"] for r in rs if r["axis"] == axis}):
            sel = [r for r in rs if r["axis"] == axis and r["level"] == level]
            x = rates(sel, model)
            rows.append({"axis": axis, "level": level, "n": x["n"],
                         "right_rate": x["right_rate"], "right_sensor_rate":
                         x["right_sensor_rate"], "ambiguous_rate": x["ambiguous_rate"],
                         "wrong_rate": x["wrong_rate"],
                         "onset_error_median_abs_s": x["onset_error_s"]["median_abs"]})
    return rows


def smallest_isolated(rows: Sequence[dict], key: str = "right_rate",
                      level: float = ISOLATION_LEVEL) -> float | None:
    """Smallest level from which ``key`` >= ``level`` there and at every larger level."""
    best = None
    for row in sorted(rows, key=lambda r: r["level"], reverse=True):
        if row[key] is None or row[key] < level:
            break
        best = row["level"]
    return best


def summarize(records: Sequence[dict]) -> dict:
    """All metrics of a 3-D study, per model present in the records."""
    records = sorted(records, key=lambda r: r["index"])
    models = [m for m in MODELS if records and all(m in r for r in records)]
    scenarios = [s for s in SCENARIOS if any(r["scenario"] == s for r in records)]
    out: dict[str, Any] = {"flights": _count(r["scenario"] for r in records),
                           "models": models}
    for m in models:
        per: dict[str, Any] = {"nominal": nominal_rates(records, m), "scenarios": {},
                               "by_level": {}, "smallest_isolated_95": {}}
        for s in scenarios:
            rs = [r for r in records if r["scenario"] == s]
            per["scenarios"][s] = {
                "all": rates(rs, m),
                "in_turn": rates([r for r in rs if r["onset_in_turn"]], m),
                "straight": rates([r for r in rs if r["onset_in_turn"] is False], m)}
            rows = by_level(records, m, s)
            per["by_level"][s] = rows
            key = "right_rate" if rows and rows[0]["right_rate"] is not None \
                else "right_sensor_rate"
            per["smallest_isolated_95"][s] = {
                axis: smallest_isolated([r for r in rows if r["axis"] == axis], key)
                for axis in SCENARIOS[s][4] if any(r["axis"] == axis for r in rows)}
        out[m] = per
    return out


# --------------------------------------------------------------------------- text

def pct(x: float | None) -> str:
    return "n/a" if x is None else f"{100 * x:.1f} %"


def _num(x: float | None, spec: str = ".2f") -> str:
    return "-" if x is None else format(x, spec)


def _coverage(a: dict) -> str:
    n = a.get("onset_interval_n", 0)
    if not n:
        return "-"
    return (f"{pct(a['onset_coverage'])} ({a['onset_covered']}/{n}; "
            f"{_num(a['onset_interval_width_s']['median'], '.1f')})")


def format_metrics(metrics: dict) -> str:
    """Markdown tables: nominal flights, per scenario (both models), smallest isolated."""
    models = metrics["models"]
    lines = ["flights: " + ", ".join(f"{v} {k}" for k, v in metrics["flights"].items())]
    lines += ["", "nominal flights:", "",
              "| model | n | false isolation | ambiguous / unexplained | declared, no sensor "
              "(seed method) | any fault declared |", "|---|---|---|---|---|---|"]
    for m in models:
        nr = metrics[m]["nominal"]
        lines.append(f"| {m} | {nr['n']} | {pct(nr['false_isolation_rate'])} "
                     f"({nr['false_isolations']}) | {nr['ambiguous']} | {nr['unnamed']} | "
                     f"{pct(nr['false_declaration_rate'])} |")
    lines += ["", "faulty flights (right = isolated, right sensor and axis; single-axis: sensor "
              "only for IMU faults):", "",
              "| scenario | model | n | right sensor+axis | right sensor | ambiguous | "
              "named | wrong (confident) | declared, no sensor | missed | right sensor+axis+kind "
              "| median abs onset err s | true onset in 95 % interval (median width s) "
              "| median magnitude err | right in turn | right straight |",
              "|---" * 16 + "|"]
    for s in SCENARIOS:
        for m in models:
            if s not in metrics[m]["scenarios"]:
                continue
            x = metrics[m]["scenarios"][s]
            a = x["all"]
            key = "right_rate" if a["right_rate"] is not None else "right_sensor_rate"
            lines.append(
                f"| {s} | {m} | {a['n']} | {pct(a['right_rate'])} | "
                f"{pct(a['right_sensor_rate'])} | {pct(a['ambiguous_rate'])} | "
                f"{pct(a['named_rate'])} | {pct(a['wrong_rate'])} | {pct(a['unnamed_rate'])} | "
                f"{pct(a['missed_rate'])} | {pct(a['right_kind_rate'])} | "
                f"{_num(a['onset_error_s']['median_abs'])} | {_coverage(a)} | "
                f"{pct(a['magnitude_error']['median'])} | "
                f"{pct(x['in_turn'][key])} ({x['in_turn']['n']}) | "
                f"{pct(x['straight'][key])} ({x['straight']['n']}) |")
    lines += ["", "by axis and level (rate of right sensor+axis; single-axis: right sensor):",
              "", "| scenario | axis | level | " + " | ".join(f"{m} n / right" for m in models)
              + " |", "|---" * (3 + len(models)) + "|"]
    for s in SCENARIOS:
        if not models or s not in metrics[models[0]]["by_level"]:
            continue
        unit = SCENARIOS[s][5]
        rows = {m: metrics[m]["by_level"][s] for m in models}
        for i, row in enumerate(rows[models[0]]):
            cells = []
            for m in models:
                rr = rows[m][i]
                v = rr["right_rate"] if rr["right_rate"] is not None else rr["right_sensor_rate"]
                cells.append(f"{rr['n']} / {pct(v)}")
            lines.append(f"| {s} | {row['axis']} | {row['level']:g} {unit} | "
                         + " | ".join(cells) + " |")
    lines += ["", f"smallest fault isolated in >= {100 * ISOLATION_LEVEL:.0f} % (at that level "
              "and every larger one of the study):"]
    for m in models:
        for s, per in metrics[m]["smallest_isolated_95"].items():
            unit = SCENARIOS[s][5]
            parts = [f"{ax} " + ("not reached" if v is None else f"{v:g} {unit}")
                     for ax, v in per.items()]
            lines.append(f"  {m}, {s}: " + ", ".join(parts))
    return "\n".join(lines)


__all__ = ["ISOLATION_LEVEL", "OUTCOMES", "axis_scored", "binomial_interval", "by_level",
           "format_metrics", "named",
           "nominal_rates", "outcome", "pct", "rates", "smallest_isolated", "summarize"]
