"""Per-flight reports of a batch, made on demand (``flight-fdi batch ... --reports WHICH``) on
the campaign engine: the figures and page of ``flight-fdi report`` for the chosen flights, in
``DIR/reports/<flight>/`` (the workers write there: on a remote cluster DIR must be a path they
see)."""
from __future__ import annotations

import argparse
import json
from dataclasses import dataclass
from pathlib import Path

from .batch import BatchError, BatchResult, error_text

DECLARED = ("failure", "glitch", "ambiguous")


@dataclass(frozen=True)
class ReportTask:
    name: str
    result: str    # the flight's result JSON
    out: str       # its report folder
    args: argparse.Namespace


def report_task(task: ReportTask) -> dict:
    """Make one flight's report (runs on a worker): ``{"index": path | None, "error": ...}``."""
    from flight_fdi.cli.report import analyse_bag
    from flight_fdi.report import write_report

    try:
        doc = json.loads(Path(task.result).read_text(encoding="utf-8"))
        notes = [f"Flight {task.name} of a batch; analysed from the bag {doc['bag']}."]
        if getattr(task.args, "model", None) == "ins3d":  # the 3-D report (cli/ins3d_report.py)
            from flight_fdi.cli.ins3d_report import report_of_bag

            index = report_of_bag(doc["bag"], task.args, task.out, notes)
        else:
            res, truth, model = analyse_bag(Path(doc["bag"]), task.args)
            index = write_report(res, task.out, truth=truth, model=model, notes=notes)
    except Exception as exc:
        return {"index": None, "error": error_text(exc)}
    return {"index": str(index), "error": None}


def choose(rows: list[dict], which: str) -> list[str]:
    """The flights whose report ``which`` asks for: ``all`` (every analysed flight), ``faults``
    (a fault declared: failure, glitch, ambiguous) or comma-separated flight names."""
    analysed = [r["flight"] for r in rows if r["verdict"] is not None]
    if which == "all":
        return analysed
    if which == "faults":
        return [r["flight"] for r in rows if r["verdict"] in DECLARED]
    names = [n.strip() for n in which.split(",") if n.strip()]
    unknown = [n for n in names if n not in analysed]
    if unknown:
        raise BatchError(f"--reports: no analysed flight named {', '.join(unknown)} (flights: "
                         f"{', '.join(analysed[:5])}{', ...' if len(analysed) > 5 else ''})")
    return names


def make_reports(batch, res: BatchResult, engine, which: str, progress: bool = False) -> int:
    """Make the chosen reports that are older than their flight's result; rewrite the fleet
    page with their links. Returns how many reports failed (each named in the summary's error
    column is not touched: a report error is printed by the caller)."""
    tasks = []
    for name in choose(res.rows, which):
        result = batch.result_path(name)
        index = batch.out / "reports" / name / "index.html"
        if index.is_file() and index.stat().st_mtime > result.stat().st_mtime:
            continue
        tasks.append(ReportTask(name, str(result), str(index.parent), batch.args))
    failed = []
    for i, out, err in engine.run(report_task, tasks, progress=progress, desc="reports",
                                  unit="report"):
        msg = error_text(err) if err is not None else out["error"]
        if msg:
            failed.append(f"{tasks[i].name}: {msg}")
    batch.write_outputs(res)
    return failed
