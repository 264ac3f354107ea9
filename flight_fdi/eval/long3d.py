"""The 3-D model on long flights (issue 15, item 5; docs/ins3d_eval.md, "Long flights").

A gyro step's information comes from the time (x / y) and the turns (z) *after* its onset, so
the 20-min flights of the first studies leave too little for late onsets. These helpers run the
same studies (:mod:`flight_fdi.eval.montecarlo3d`) on flight-test-length flights and summarise
what the longer flights add:

* :class:`LoadSampler`: the load average while a study runs (its settings line states it);
* :func:`run_recorded`: a study whose per-flight records stream to a JSON-lines file and resume
  from it (:class:`~flight_fdi.eval.records.RecordsFile`): a long study survives a stop;
* :func:`merge_records`: the records of several studies as one set (indices renumbered);
* :func:`nominal_maxima`: per hypothesis kind, the nominal flights' largest GLR against the
  threshold (how close to a false alarm the flights came: the margin on long flights);
  :func:`nominal_maxima_by_hypothesis`: the same per hypothesis, against its own threshold;
* :func:`by_onset`: the right-isolation rate per scenario, axis and onset bin (where in the
  flight a fault is isolated in 95 %);
* :func:`detectable_steps`: from one analysed flight, the step size whose expected GLR equals
  the threshold, per onset (the GLR's own information: what the flight can show).
"""
from __future__ import annotations

import json
import os
import threading
from pathlib import Path
from typing import Sequence

import numpy as np

from .metrics3d import ISOLATION_LEVEL, outcome, pct, rates, summarize
from .montecarlo3d import SCENARIOS, Study3DConfig, Study3DResult, run_study, study_settings
from .records import RecordsFile, read_records

KINDS = ("step", "ramp", "jump", "outliers")


class LoadSampler:
    """The machine's 1-min load average sampled every ``every_s`` seconds on a daemon thread
    while a study runs (the machine is shared: the settings lines state the load)."""

    def __init__(self, every_s: float = 30.0) -> None:
        self.samples: list[float] = []
        self._stop = threading.Event()
        self._every = every_s
        self._thread = threading.Thread(target=self._run, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            self.samples.append(os.getloadavg()[0])
            if self._stop.wait(self._every):
                return

    def stop(self) -> list[float]:
        """Stop sampling; the [lowest, highest] load average seen (a last sample included)."""
        self._stop.set()
        self._thread.join()
        self.samples.append(os.getloadavg()[0])
        return [min(self.samples), max(self.samples)]


def run_recorded(config: Study3DConfig, path: str | Path, jobs: int = 1,
                 progress: bool = False) -> Study3DResult:
    """:func:`run_study` with its records streamed to ``path`` (JSON lines, flushed per
    flight); flights already in the file (an interrupted run of the same study) are not run
    again."""
    with RecordsFile(path, study_settings(config)) as rec:
        return run_study(config, jobs=jobs, progress=progress, on_record=rec.write,
                         done=rec.done)


def merge_records(parts: Sequence[Sequence[dict]]) -> list[dict]:
    """The records of several studies as one list, flight indices renumbered 0..n-1 in order
    (each study numbers its flights from 0)."""
    out: list[dict] = []
    for recs in parts:
        for r in sorted(recs, key=lambda r: r["index"]):
            out.append({**r, "index": len(out)})
    return out


def nominal_maxima(records: Sequence[dict], thresholds: dict[str, float],
                   model: str = "ins3d") -> dict[str, dict]:
    """Per hypothesis kind over the nominal flights' records (``glr_max``): the number of
    flights, the largest and the median maximum, the threshold, and how many flights exceeded
    it (a flight above the threshold of a kind is a GLR detection of that kind)."""
    nom = [r[model].get("glr_max") or {} for r in records if r["scenario"] == "nominal"]
    out = {}
    for k in KINDS:
        m = np.array([g[k] for g in nom if k in g], dtype=float)
        thr = float(thresholds[k])
        out[k] = {"n": int(m.size), "threshold": thr,
                  "max": float(m.max()) if m.size else None,
                  "median": float(np.median(m)) if m.size else None,
                  "above": int(np.sum(m > thr))}
    return out


def nominal_maxima_by_hypothesis(records: Sequence[dict], thresholds: dict[str, float],
                                 model: str = "ins3d") -> dict[str, dict]:
    """:func:`nominal_maxima` per hypothesis (step / ramp / jump) from the records'
    ``glr_statistics`` (every hypothesis' largest GLR), against each one's own threshold
    (``glr3d.threshold_of``: its own where the grade has one, else its kind's); records
    without them: {}."""
    from flight_fdi.core.ins3d.glr3d import hypotheses, threshold_of

    nom = [r[model].get("glr_statistics") for r in records if r["scenario"] == "nominal"]
    if not nom or not all(nom):
        return {}
    out = {}
    for h in hypotheses(3):
        if h.kind == "outliers" or h.name not in nom[0]:
            continue
        m = np.array([g[h.name] for g in nom], dtype=float)
        thr = threshold_of(thresholds, h)
        out[h.name] = {"n": int(m.size), "threshold": thr, "max": float(m.max()),
                       "median": float(np.median(m)), "above": int(np.sum(m > thr))}
    return out


def by_onset(records: Sequence[dict], bins_s: Sequence[float], model: str = "ins3d",
             levels: Sequence[float] | None = None) -> list[dict]:
    """The rate of ``right`` per (scenario, axis, onset bin) over the faulty flights (optionally
    only those whose level is in ``levels``): bins [bins_s[i], bins_s[i+1]). A row per
    non-empty cell, with ``n``, ``right`` and ``rate``; ``reached``: rate >= 95 %."""
    edges = np.asarray(bins_s, dtype=float)
    cells: dict[tuple, list[int]] = {}
    for r in records:
        if r["scenario"] == "nominal" or (levels is not None and r["level"] not in levels):
            continue
        b = int(np.searchsorted(edges, r["onset_s"], side="right")) - 1
        if not 0 <= b < edges.size - 1:
            continue
        c = cells.setdefault((r["scenario"], r["axis"], b), [0, 0])
        c[0] += 1
        c[1] += outcome(r, model) == "right"
    return [{"scenario": s, "axis": a, "bin": (float(edges[b]), float(edges[b + 1])), "n": n,
             "right": k, "rate": k / n, "reached": k / n >= ISOLATION_LEVEL}
            for (s, a, b), (n, k) in sorted(cells.items(), key=lambda kv: (
                list(SCENARIOS).index(kv[0][0]), kv[0][1], kv[0][2]))]


def format_by_turn_after(records: Sequence[dict], model: str = "ins3d") -> str:
    """Right sensor+axis per scenario, axis and level, split by whether the aircraft turned
    after the onset (``next_turn_s``: the first turn entry after it, from the truth)."""
    cells: dict[tuple, list[int]] = {}
    for r in records:
        if r["scenario"] == "nominal":
            continue
        c = cells.setdefault((r["scenario"], r["axis"], r["level"]), [0, 0, 0, 0])
        j = 0 if r.get("next_turn_s") is not None else 2
        c[j] += 1
        c[j + 1] += outcome(r, model) == "right"
    lines = [f"right sensor+axis ({model}) by a turn after the onset (right/n):", "",
             "| scenario | axis | level | a turn after the onset | no turn after it |",
             "|---|---|---|---|---|"]
    order = list(SCENARIOS)
    for (s, a, lev), (n1, k1, n0, k0) in sorted(cells.items(), key=lambda kv: (
            order.index(kv[0][0]), kv[0][1], kv[0][2])):
        lines.append(f"| {s} | {a} | {lev:g} | {f'{k1}/{n1}' if n1 else '-'} | "
                     f"{f'{k0}/{n0}' if n0 else '-'} |")
    return "\n".join(lines)


def format_onset_by_axis(records: Sequence[dict], model: str = "ins3d") -> str:
    """Per scenario and axis over the faulty flights (all levels): right sensor+axis, the
    median and 90th percentile of the absolute onset error over the right ones, and how many
    of their 95 % onset intervals hold the true onset."""
    lines = [f"onset error by axis ({model}, over the right isolations of all levels):", "",
             "| scenario | axis | right / n | median abs onset err s | 90 % of abs errors "
             "below s | true onset in 95 % interval (median width s) |",
             "|---|---|---|---|---|---|"]
    for scen in SCENARIOS:
        for axis in SCENARIOS[scen][4]:
            sel = [r for r in records if r["scenario"] == scen and r["axis"] == axis]
            if not sel:
                continue
            x = rates(sel, model)
            err = [abs(r[model]["onset_s"] - r["onset_s"]) for r in sel
                   if outcome(r, model) == "right" and r[model]["onset_s"] is not None]
            med = f"{np.median(err):.1f}" if err else "-"
            p90 = f"{np.percentile(err, 90):.0f}" if err else "-"
            cov = (f"{x['onset_covered']}/{x['onset_interval_n']} "
                   f"({x['onset_interval_width_s']['median']:.0f})"
                   if x["onset_interval_n"] else "-")
            lines.append(f"| {scen} | {axis} | {x['right']}/{x['n']} | {med} | {p90} | {cov} |")
    return "\n".join(lines)


def detectable_steps(analysis, onsets_s: Sequence[float], names: Sequence[tuple[str, str]]
                     ) -> dict[str, dict]:
    """For each (hypothesis name, scenario) of ``names``: the step whose expected GLR equals the
    step threshold at each onset (seconds from the first step), sqrt(threshold) x the GLR's
    magnitude sd there, in the scenario's unit (mg, deg/h). A step of that size is detected
    about half the time; ~1.5x it in 95 %."""
    rows = {}
    thr = float(analysis.thresholds["step"])
    for name, scen in names:
        c = analysis.glr[name]
        k = np.minimum(np.searchsorted(c.t - c.t[0], np.asarray(onsets_s, float)), c.t.size - 1)
        rows[name] = {"unit": SCENARIOS[scen][5],
                      "values": [float(v) for v in np.sqrt(thr) * c.sd[k] / SCENARIOS[scen][6]]}
    return rows


def format_nominal_maxima(maxima: dict[str, dict], what: str = "kind") -> str:
    """The table of :func:`nominal_maxima` (``what``: "hypothesis" for
    :func:`nominal_maxima_by_hypothesis`'s)."""
    lines = [f"largest GLR per {'hypothesis kind' if what == 'kind' else what} over the nominal "
             "flights (3-D model), against the threshold of the flight's length"
             + ("" if what == "kind" else " (its own)") + ":", "",
             f"| {what} | flights | median of the flights' maxima | largest | threshold | "
             "flights above |", "|---|---|---|---|---|---|"]
    for k, v in maxima.items():
        if v["n"]:
            lines.append(f"| {k} | {v['n']} | {v['median']:.1f} | {v['max']:.1f} | "
                         f"{v['threshold']:.1f} | {v['above']} |")
    return "\n".join(lines)


def format_by_onset(records: Sequence[dict], duration_s: float, fractions: Sequence[float],
                    model: str = "ins3d") -> str:
    """Right sensor+axis per scenario, axis and onset bin (bins: ``fractions`` of the flight's
    ``duration_s``), over all levels and over the scenario's smallest level, as ``right/n``."""
    recs = [r for r in records if r["scenario"] != "nominal"]
    if not recs:
        return ""
    edges = [round(duration_s * f) for f in fractions]
    lines = [f"right sensor+axis ({model}) by onset time (right/n):", "",
             "| scenario | axis | level | " + " | ".join(
                 f"{a}-{b} s" for a, b in zip(edges[:-1], edges[1:])) + " |",
             "|---" * (2 + len(edges)) + "|"]
    for scen in dict.fromkeys(r["scenario"] for r in recs):
        mine = [r for r in recs if r["scenario"] == scen]
        for lev in (None, min(r["level"] for r in mine)):
            cells: dict = {}
            for row in by_onset(mine, edges, model, None if lev is None else [lev]):
                cells.setdefault(row["axis"], {})[row["bin"][0]] = f"{row['right']}/{row['n']}"
            for axis, c in cells.items():
                lines.append(f"| {scen} | {axis} | {'all' if lev is None else f'{lev:g}'} | "
                             + " | ".join(c.get(float(a), "-") for a in edges[:-1]) + " |")
    return "\n".join(lines)


def calibration_table(short: Sequence[dict], long: Sequence[dict], base: dict[str, float],
                      rule: dict[str, float], growth: dict[str, float]) -> str:
    """The threshold calibration on nominal flights of two lengths (``tools/ins3d_calibrate.py``
    rows: per flight the largest GLR per kind): quantiles of the flights' maxima, the growth of
    the median, and how many long flights exceed the fixed thresholds ``base`` and the length
    rule's ``rule`` (growth coefficient per kind: ``growth``)."""
    def q(rows, k, qs):
        m = np.array([r["max"][k] for r in rows])
        return [float(np.quantile(m, x)) for x in qs], m

    ts, tl = short[0]["duration_s"], long[0]["duration_s"]
    lines = [f"| kind | {ts / 60:g} min, {len(short)} flights: median / 90 % / largest | "
             f"{tl / 60:g} min, {len(long)} flights: median / 90 % / 99 % / largest | growth "
             f"of the median (/ ln {tl / ts:g}) | fixed threshold: flights above | rule: c, "
             "threshold, flights above |", "|---|---|---|---|---|---|"]
    for k in KINDS:
        (s50, s90, s100), _ = q(short, k, (0.5, 0.9, 1.0))
        (l50, l90, l99, l100), m = q(long, k, (0.5, 0.9, 0.99, 1.0))
        g = l50 - s50
        lines.append(f"| {k} | {s50:.1f} / {s90:.1f} / {s100:.1f} | {l50:.1f} / {l90:.1f} / "
                     f"{l99:.1f} / {l100:.1f} | {g:+.1f} ({g / np.log(tl / ts):.2f}) | "
                     f"{int(np.sum(m > base[k]))} | {growth[k]:g}, {rule[k]:.1f}, "
                     f"{int(np.sum(m > rule[k]))} |")
    n_fixed = sum(any(r["max"][k] > base[k] for k in KINDS) for r in long)
    n_rule = sum(any(r["max"][k] > rule[k] for k in KINDS) for r in long)
    verdicts: dict[str, int] = {}
    for r in long:
        verdicts[r["verdict"]] = verdicts.get(r["verdict"], 0) + 1
    lines += ["", f"{tl / 60:g}-min flights with any kind above its threshold: fixed "
              f"{n_fixed} ({100 * n_fixed / len(long):.1f} %), rule {n_rule} "
              f"({100 * n_rule / len(long):.1f} %); verdicts: "
              + ", ".join(f"{k} {v}" for k, v in sorted(verdicts.items())) + "."]
    return "\n".join(lines)


def hypothesis_calibration_table(short: Sequence[dict], long: Sequence[dict],
                                 kinds: dict[str, float]) -> str:
    """The per-hypothesis calibration (``calibrate3d.calibrate_hypotheses`` on
    ``tools/ins3d_calibrate.py`` rows with ``max_by_hypothesis``): per hypothesis the maxima on
    the short and long flights, the measured growth and the grade's thresholds (its own at
    30 min and at the long flights' length, against its kind's: ``kinds``, the grade's
    per-kind thresholds at 30 min) and the long flights above each."""
    from flight_fdi.core.ins3d.glr3d import (PER_HYPOTHESIS, growth_of, hypotheses,
                                             threshold_of, thresholds_for)
    from flight_fdi.core.ins3d.grade_file import at_length

    ts, tl = short[0]["duration_s"], long[0]["duration_s"]
    hyps = {h.name: h for h in hypotheses(3)}
    own, own_l = thresholds_for("navigation"), thresholds_for("navigation", tl)
    kind_l = at_length(kinds, tl)
    lines = [f"| hypothesis | {ts / 60:g} min, {len(short)} flights: median / 90 % / largest | "
             f"{tl / 60:g} min, {len(long)} flights: median / 90 % / largest | growth c "
             f"(kind's) | threshold {ts / 60:g} min (kind's) | threshold {tl / 60:g} min "
             f"(kind's) | {tl / 60:g}-min flights above: own (kind's) |", "|---" * 7 + "|"]
    for name in PER_HYPOTHESIS:
        h = hyps[name]
        q = [np.quantile([r["max_by_hypothesis"][name] for r in rows], (0.5, 0.9, 1.0))
             for rows in (short, long)]
        m = np.array([r["max_by_hypothesis"][name] for r in long])
        lines.append(
            f"| {name} | {' / '.join(f'{v:.1f}' for v in q[0])} | "
            f"{' / '.join(f'{v:.1f}' for v in q[1])} | {growth_of(name):.2f} "
            f"({growth_of(h.kind):g}) | {threshold_of(own, h):.1f} ({kinds[h.kind]:.1f}) | "
            f"{threshold_of(own_l, h):.1f} ({kind_l[h.kind]:.1f}) | "
            f"{int(np.sum(m > threshold_of(own_l, h)))} ({int(np.sum(m > kind_l[h.kind]))}) |")
    return "\n".join(lines)


def format_detectable(doc: dict, intro: str) -> str:
    """The detectable-step table of ``tools/ins3d_eval.py``'s ``detectable*.json``: per flight /
    model and step the sizes per onset, then the turns and first-excited times."""
    on = doc["onsets_s"]
    lines = [f"{intro}, code {doc.get('commit', '?')}: the step whose expected GLR equals the "
             "step threshold, per onset (detected about half the time; ~1.5x that for 95 %).",
             "", "| flight / model | step | " + " | ".join(f"{t:g} s" for t in on) + " |",
             "|---" * (2 + len(on)) + "|"]
    for label, m in doc["models"].items():
        for name, r in m["rows"].items():
            lines.append(f"| {label} | {name} ({r['unit']}) | "
                         + " | ".join(f"{v:.3g}" for v in r["values"]) + " |")
    for label, m in doc["models"].items():
        turns = ", ".join(f"{a:.0f}-{b:.0f} s" for a, b in m["turns"])
        ex = ", ".join(f"{k} {'never' if v is None else f'{v:.0f} s'}"
                       for k, v in m["excited_at"].items())
        lines.append(f"\n{label}: turns {turns}; observability report (first excited): {ex}.")
    return "\n".join(lines)


def study_files(out: Path, name: str) -> list[Path]:
    """The records files of study ``name`` in ``out``: ``<name>.jsonl`` and one
    ``<name>_<scenario>.jsonl`` per fault scenario -- not the files of another study whose name
    merely begins with ``name`` (``nominal_long_cruise_turns`` is not part of ``nominal_long``)."""
    names = [f"{name}.jsonl"] + [f"{name}_{s}.jsonl" for s in SCENARIOS]
    return [out / n for n in sorted(names) if (out / n).exists()]


def read_study(out: Path, name: str) -> tuple[dict | None, list[dict], str, float]:
    """A study of ``tools/ins3d_eval.py`` in ``out``: (the finished study's JSON or None, its
    records -- from the .jsonl files of an unfinished one --, a note saying it is partial, the
    flights' duration)."""
    p = out / f"{name}.json"
    doc = json.loads(p.read_text()) if p.exists() else None
    if doc is not None:
        c = doc["config"]
        return doc, doc["flights"], "", c.get("duration_s") or next(iter(c.values()))[
            "duration_s"]
    parts, dur = [], 0.0
    for p in study_files(out, name):
        study, recs = read_records(p)
        dur = study["duration_s"]
        parts.append(recs)
    recs = merge_records(parts)
    note = (f"**Partial: {len(recs)} flights had finished when this was rendered (the run did "
            "not complete).**\n\n") if recs else ""
    return None, recs, note, dur


def format_nominal(recs: Sequence[dict]) -> str:
    """The nominal-flight table of both models (false isolation, declarations)."""
    m = summarize(recs)
    lines = ["| model | nominal flights | false isolation (confident sensor) | its exact 95 % "
             "interval | ambiguous / unexplained | declared, no sensor (seed method) | any fault "
             "declared | named as |", "|---|---|---|---|---|---|---|---|"]
    for model in m["models"]:
        x = m[model]["nominal"]
        lo, hi = x["false_isolation_interval"] or (None, None)
        iv = "-" if lo is None else f"{100 * lo:.1f}-{100 * hi:.1f} %"
        lines.append(f"| {model} | {x['n']} | {pct(x['false_isolation_rate'])} "
                     f"({x['false_isolations']}) | {iv} | {x['ambiguous']} | {x['unnamed']} | "
                     f"{pct(x['false_declaration_rate'])} | "
                     f"{', '.join(f'{k} {v}' for k, v in x['isolated_as'].items()) or '-'} |")
    return "\n".join(lines)


def format_onset_coverage(rows: Sequence[dict], drops: Sequence[float]) -> str:
    """The onset-interval calibration (``tools/ins3d_onset_calibrate.py`` rows): per scenario
    and reported kind, over the right isolations, the true onsets inside the interval of each
    drop and the median width."""
    lines = ["| scenario | right sensor+axis | reported as | " + " | ".join(
        f"drop {d:g}: covered (median width s)" for d in drops) + " |",
        "|---" * (3 + len(drops)) + "|"]
    for s in dict.fromkeys(r["scenario"] for r in rows):
        mine = [r for r in rows if r["scenario"] == s]
        right = [r for r in mine if r["right"]]
        for kind in sorted({r["reported_kind"] for r in right}):
            rk = [r for r in right if r["reported_kind"] == kind]
            cells = []
            for d in drops:
                iv = [r["intervals"][str(d)] for r in rk]
                cov = sum(lo - 1e-6 <= r["onset_s"] <= hi + 1e-6
                          for (lo, hi), r in zip(iv, rk))
                cells.append(f"{cov}/{len(rk)} ({np.median([hi - lo for lo, hi in iv]):.0f})")
            lines.append(f"| {s} | {len(right)}/{len(mine)} | {kind} | " + " | ".join(cells)
                         + " |")
    return "\n".join(lines)


__all__ = ["KINDS", "LoadSampler", "by_onset", "calibration_table", "detectable_steps",
           "format_by_onset",
           "format_by_turn_after", "format_detectable", "format_nominal",
           "format_onset_by_axis", "study_files",
           "format_nominal_maxima",
           "format_onset_coverage", "merge_records",
           "nominal_maxima", "read_study", "run_recorded"]
