"""The generated sections of docs/ins3d_eval.md, rendered from the studies' JSON (tools/ins3d_eval.py
writes it; ``render`` fills each ``<!-- BEGIN GENERATED <name> -->`` block whose results exist).

    sections() -> [(name, renderer(out) -> markdown or None)]
    render(out, doc=DOC)            every generated section of ``doc`` from the JSON in ``out``
    long_name(study, profile)       the file / section name of a long study on a profile
"""
from __future__ import annotations

import functools
import json
import pathlib
import re

REPO = pathlib.Path(__file__).resolve().parents[1]
DOC = REPO / "docs" / "ins3d_eval.md"
#: drops of the onset-calibration tables
ONSET_DROPS = (3.84, 6.0, 10.0, 15.0, 25.0)
#: onset bins of the long fault study's by-onset table, as fractions of the flight
ONSET_BINS = (0.1, 0.25, 0.4, 0.55, 0.7, 0.8)


def _load_note(doc: dict) -> str:
    lo_hi = doc.get("load_average")
    return "" if not lo_hi else f", load average {lo_hi[0]:.1f}-{lo_hi[1]:.1f}"


def section_detectable(out: pathlib.Path) -> str | None:
    from flight_fdi.eval.long3d import format_detectable

    doc = _load(out, "detectable")
    if doc is None:
        return None
    return format_detectable(doc, f"One nominal 1200-s `cruise_turns` flight (seed "
                                  f"{doc['seed']}, navigation grade)")


def long_name(study: str, profile: str) -> str:
    """The file and section name of a long study on ``profile``: the study's own for the
    ``random`` profile (the first long evaluation's names), ``<study>_<profile>`` otherwise."""
    return study if profile == "random" else f"{study}_{profile}"


def section_nominal_long(out: pathlib.Path, name: str = "nominal_long") -> str | None:
    from flight_fdi.core.ins3d.glr3d import thresholds_for
    from flight_fdi.eval.long3d import (format_nominal, format_nominal_maxima, nominal_maxima,
                                        nominal_maxima_by_hypothesis, read_study)

    doc, recs, note, dur = read_study(out, name)
    if not recs:
        return None
    head = note + (_settings(doc) if doc else "")
    thr = thresholds_for("navigation", dur)
    per = nominal_maxima_by_hypothesis(recs, thr)
    return "\n".join([head, "", format_nominal(recs), "", format_nominal_maxima(
        nominal_maxima(recs, thr))] + (["", format_nominal_maxima(per, "hypothesis")]
                                        if per else []))


def section_faults_long(out: pathlib.Path, name: str = "faults_long") -> str | None:
    from flight_fdi.eval.long3d import (format_by_onset, format_by_turn_after,
                                        format_onset_by_axis, read_study)
    from flight_fdi.eval.metrics3d import format_metrics, summarize

    doc, recs, note, dur = read_study(out, name)
    if not recs:
        return None
    head = note
    if doc:
        c = next(iter(doc["config"].values()))
        seeds = ", ".join(f"{s} {v['seed']}" for s, v in doc["config"].items())
        head = (f"Settings: {len(recs)} flights of {c['duration_s']:g} s, profile "
                f"`{c['profile']}`, grade {c['grade']}, seeds {seeds}, GNSS latency "
                f"{1000 * c['gnss_latency_s']:g} ms + Markov noise, onsets in "
                f"{c['onset_window'][0]:g}-{c['onset_window'][1]:g} of the flight; "
                f"{doc['elapsed_s'] / 60:.1f} min on {doc.get('engine', '?')}{_load_note(doc)}"
                + (f" ({doc['resumed']} flights resumed from earlier runs' records)"
                   if doc.get("resumed") else "") + f"; code {doc.get('commit', '?')}.")
    text = re.sub(r"nominal flights:\n\n(\|.*\n)+\n", "", format_metrics(summarize(recs)))
    return (head + "\n\n" + text + "\n\n" + format_onset_by_axis(recs) + "\n\n"
            + format_by_onset(recs, dur, ONSET_BINS) + "\n\n"
            + format_by_turn_after([r for r in recs if r["scenario"].startswith("gyro")]))


def section_calibration_long(out: pathlib.Path) -> str | None:
    """The threshold calibration of the length rule, from tools/ins3d_calibrate.py's JSON:
    ``calibrate_30min.json`` and ``calibrate_long*.json`` in ``out``."""
    from flight_fdi.core.ins3d.glr3d import LENGTH_GROWTH, thresholds_for
    from flight_fdi.eval.long3d import calibration_table

    short = _load(out, "calibrate_30min")
    long = [r for p in sorted(out.glob("calibrate_long*.json")) for r in json.loads(p.read_text())]
    if short is None or not long:
        return None
    return calibration_table(short, long, thresholds_for("navigation"),
                             thresholds_for("navigation", long[0]["duration_s"]), LENGTH_GROWTH)


def section_calibration_hypotheses(out: pathlib.Path) -> str | None:
    """The per-hypothesis thresholds' calibration table, from the same rows as
    ``section_calibration_long`` (with ``max_by_hypothesis``: tools/ins3d_calibrate.py of
    this code)."""
    from flight_fdi.core.ins3d.glr3d import THRESHOLDS_BY_GRADE
    from flight_fdi.eval.long3d import hypothesis_calibration_table

    short = _load(out, "calibrate_30min")
    long = [r for p in sorted(out.glob("calibrate_long*.json")) for r in json.loads(p.read_text())]
    if short is None or not long or not all("max_by_hypothesis" in r for r in short + long):
        return None
    return hypothesis_calibration_table(short, long, THRESHOLDS_BY_GRADE["navigation"])


def section_onset_calibration(out: pathlib.Path) -> str | None:
    """The onset-interval calibration tables from ``onset_*.json`` (tools/ins3d_onset_calibrate.py
    --out) in ``out``: one table per file."""
    from flight_fdi.eval.long3d import format_onset_coverage

    parts = []
    for p in sorted(out.glob("onset_*.json")):
        rows = json.loads(p.read_text())
        parts.append(f"`{p.name}`:\n\n" + format_onset_coverage(rows, ONSET_DROPS))
    return "\n\n".join(parts) or None


def section_detectable_long(out: pathlib.Path, name: str = "detectable_long") -> str | None:
    from flight_fdi.eval.long3d import format_detectable

    doc = _load(out, name)
    if doc is None:
        return None
    return format_detectable(doc, f"One nominal {doc['duration_s']:g}-s flight per profile "
                                  f"(seed {doc['seed']}, navigation grade; step threshold "
                                  f"{doc['thresholds']['step']:.3g})")


def _load(out: pathlib.Path, name: str) -> dict | None:
    p = out / f"{name}.json"
    return json.loads(p.read_text()) if p.exists() else None


def section_nominal(out: pathlib.Path) -> str | None:
    from flight_fdi.eval.long3d import format_nominal
    from flight_fdi.eval.records import read_records

    doc = _load(out, "nominal")
    if doc is None:
        p = out / "nominal.jsonl"
        recs = read_records(p)[1] if p.exists() else []
        if not recs:
            return None
        head = (f"**Partial: {len(recs)} of the planned flights had finished when this was "
                f"rendered (the run did not complete).**\n\n")
    else:
        recs, head = doc["flights"], _settings(doc) + "\n\n"
    return head + format_nominal(recs)


def section_faults(out: pathlib.Path) -> str | None:
    from flight_fdi.eval.metrics3d import format_metrics, summarize

    doc = _load(out, "faults")
    if doc is None:
        return None
    text = format_metrics(summarize(doc["flights"]))
    # the nominal table of the fault study is empty (no nominal flights): drop it
    text = re.sub(r"nominal flights:\n\n(\|.*\n)+\n", "", text)
    return _settings(doc) + "\n\n" + text


def section_ladder(out: pathlib.Path, names: tuple = ("ladder",)) -> str | None:
    from flight_fdi.eval.ladder3d import format_ladder

    parts = []
    for name in names:
        doc = _load(out, name)
        if doc is None:
            continue
        lad = doc["ladder"]
        parts.append(f"Seed {lad['seed']}, code {doc.get('commit', '?')}, "
                     f"{lad['elapsed_s'] / 60:.1f} min on the shared machine.\n\n"
                     + format_ladder(lad))
    return "\n\n".join(parts) or None


def section_ladder_grades(out: pathlib.Path) -> str | None:
    return section_ladder(out, ("ladder_grades",))


def section_latency(out: pathlib.Path) -> str | None:
    from flight_fdi.eval.metrics3d import format_metrics, summarize

    doc = _load(out, "latency")
    if doc is None:
        return None
    c = doc["config"]
    return (f"GNSS latency {doc['latency_ms']:g} ms (the model estimates it as a state): "
            f"{c['nominal']['nominal']} nominal flights of {c['nominal']['duration_s']:g} s "
            f"(`random`, seed {c['nominal']['seed']}) and {c['faults']['per_scenario']} flights "
            f"per fault scenario of {c['faults']['duration_s']:g} s (`cruise_turns`, seed "
            f"{c['faults']['seed']}); {doc['elapsed_s'] / 60:.1f} min; code "
            f"{doc.get('commit', '?')}.\n\n" + format_metrics(summarize(doc["flights"])))


def _settings(doc: dict) -> str:
    c = doc["config"]
    return (f"Settings: {sum(doc['metrics']['flights'].values())} flights of "
            f"{c['duration_s']:g} s, profile `{c['profile']}`, grade {c['grade']}, seed "
            f"{c['seed']}, GNSS latency {1000 * c['gnss_latency_s']:g} ms + Markov noise, "
            f"onsets in {c['onset_window'][0]:g}-{c['onset_window'][1]:g} of the flight; "
            f"{doc['elapsed_s'] / 60:.1f} min on {doc['engine']}{_load_note(doc)}; code "
            f"{doc.get('commit', '?')}.")


def sections() -> list[tuple]:
    """(section name, its renderer): the studies' sections, and the long studies' once more per
    profile other than ``random`` (``nominal_long_cruise_turns``, ...)."""
    from flight_fdi.eval.montecarlo3d import PROFILES

    out = [("nominal", section_nominal), ("faults", section_faults),
           ("ladder", section_ladder), ("ladder_grades", section_ladder_grades),
           ("latency", section_latency), ("detectable", section_detectable),
           ("nominal_long", section_nominal_long), ("faults_long", section_faults_long),
           ("calibration_long", section_calibration_long),
           ("calibration_hypotheses", section_calibration_hypotheses),
           ("onset_calibration", section_onset_calibration),
           ("detectable_long", section_detectable_long)]
    for prof in PROFILES:
        for study, fn in (("nominal_long", section_nominal_long),
                          ("faults_long", section_faults_long),
                          ("detectable_long", section_detectable_long)):
            if prof != "random":
                name = long_name(study, prof)
                out.append((name, functools.partial(fn, name=name)))
    return out


def render(out: pathlib.Path, doc: pathlib.Path = DOC) -> None:
    text = doc.read_text()
    for name, fn in sections():
        begin, end = f"<!-- BEGIN GENERATED {name} -->", f"<!-- END GENERATED {name} -->"
        if begin not in text:
            continue
        body = fn(out)
        if body is None:          # no results in ``out``: the section keeps what it has
            continue
        a, rest = text.split(begin, 1)
        _, b = rest.split(end, 1)
        text = f"{a}{begin}\n{body}\n{end}{b}"
    doc.write_text(text)
