"""``flight-fdi report INPUT --out DIR``: figures and an HTML page of one analysed flight.

INPUT is one of

* a rosbag2 bag (a folder with metadata.yaml, or a .mcap / .db3 file; the input options name
  its topics): analysed like ``flight-fdi analyze``; a simulated bag's /sim/truth is drawn
  as the true error;
* the output folder of ``flight-fdi run`` (result.json and recording/): the forward pass is
  rebuilt from the recording exactly as the smoother node does, and the truth is taken from the
  input bag named in result.json when that bag still exists;
* a result JSON file (``flight-fdi analyze --json`` / ``run``'s result.json): the bag it names is
  analysed again (the JSON alone holds no time series to draw).

A run folder's recording holds what its filter ran with: options that would change it (the gate;
with --model ins3d also grade, rows, topics and error model) are refused, one line. With
--fail-on-fault the exit status is 3 when the verdict declares a fault. --out must be a folder
or one that can be made (checked before the analysis).

DIR receives index.html (the verdict on top), summary.json and the PNG figures: per state element
the true error, filtered and smoothed estimates with the chi-square and Fisher statistics and
their thresholds (like figures 7.2 / 7.3 of seed 000), the beta^2 gate with the alarms, the total
chi-square statistic, and the GLR statistic over the onset time.
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from flight_fdi.cli.analyze import add_analysis_options
from flight_fdi.cli.errors import CliError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("report", help="figures and an HTML page of an analysed flight",
                       description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("input", help="a bag, a 'flight-fdi run' output folder or a result JSON file")
    p.add_argument("--out", required=True, metavar="DIR", help="report folder (created)")
    add_analysis_options(p)
    p.set_defaults(func=run)


def _is_bag(path: Path) -> bool:
    return (path.is_dir() and (path / "metadata.yaml").exists()) or \
        (path.is_file() and path.suffix in (".mcap", ".db3"))


def _truth_of(flight: Any, model: Any, shift: float):
    """Truth (flight_fdi.report.Truth) of a read_flight result, times minus ``shift``."""
    from flight_fdi.report import Truth

    if flight.x_truth is None or flight.truth_state_names is None:
        return None
    if tuple(flight.truth_state_names) != tuple(model.state_names):
        return None  # truth of another model: nothing to compare
    return Truth(flight.t_truth - shift, flight.x_truth, flight.truth_state_names)


def analyse_bag(bag: Path, args: argparse.Namespace):
    """(AnalysisResult, Truth or None, model) of an input bag, as ``flight-fdi analyze`` does
    (the same input options and result, ``input`` per topic included)."""
    from flight_fdi.cli.analyze import analyse_flight_bag
    from flight_fdi.core.models import get_model

    res, flight = analyse_flight_bag(str(bag), args, with_truth=True)
    model = get_model(args.model)
    return res, _truth_of(flight, model, flight.t0), model


def _inputs_of(doc: dict, args: argparse.Namespace) -> None:
    """Take the input contract of a result (its ``source``) unless given as options."""
    src = doc.get("source") or {}
    if args.ins_topic is None and src.get("ins_topic"):
        args.ins_topic = src["ins_topic"]
    if args.reference_topic is None and src.get("reference_topics"):
        args.reference_topic = list(src["reference_topics"])
    if args.nav_frame is None and src.get("nav_frame"):
        args.nav_frame = src["nav_frame"]
    if args.odometry_twist_frame is None and src.get("odometry_twist_frame"):
        args.odometry_twist_frame = src["odometry_twist_frame"]
    if args.channel is None:
        args.channel = src.get("channel") or doc.get("channel")


def analyse_run_folder(folder: Path, args: argparse.Namespace):
    """(AnalysisResult, Truth or None, model, notes) of a ``flight-fdi run`` output folder."""
    result_json = folder / "result.json"
    recording = folder / "recording"
    doc = _load_json(result_json)
    input_bag = Path(doc["bag"]) if isinstance(doc.get("bag"), str) and doc["bag"] else None
    _inputs_of(doc, args)
    channel = args.channel or "x"
    if not recording.exists():
        if input_bag is not None and _is_bag(input_bag):
            res, truth, model = analyse_bag(input_bag, args)
            return res, truth, model, [f"{recording} is missing: the input bag {input_bag} was "
                                       "analysed again."]
        raise CliError(f"{folder}: no recording/ and the input bag named in result.json "
                       f"({doc.get('bag')!r}) does not exist")
    from flight_fdi.bagio.recording import read_recording
    from flight_fdi.core.recording import analyze_recording

    flight = None
    if input_bag is not None and _is_bag(input_bag):
        from flight_fdi.bagio import read_flight
        from flight_fdi.cli.analyze import input_spec

        flight = read_flight(input_bag, spec=input_spec(args), with_truth=True)
    rec = read_recording(recording, channel=channel)
    # times from the start of the input flight, as in result.json
    run = analyze_recording(rec, flight_start_s=None if flight is None else flight.t0,
                            bag_label=str(input_bag) if input_bag else None)
    return of_run(run.analysis, rec, flight, doc)


def of_run(analysis: Any, rec: Any, flight: Any, doc: dict):
    """(AnalysisResult, Truth or None, model, notes) for the report of a run: ``analysis`` of
    its recording ``rec`` -- the smoother's (``flight-fdi run``: no second analysis) or
    :func:`analyse_run_folder`'s --, ``flight`` the input bag read with its truth (or None) and
    ``doc`` the run's result (its input bag and ``input`` record)."""
    if isinstance(doc.get("bag"), str) and doc["bag"]:   # named as in result.json
        analysis.summary["bag"] = str(Path(doc["bag"]))
    truth = None if flight is None else _truth_of(flight, rec.model, 0.0)
    notes = [f"Rebuilt from the recording {rec.path} (gate of the recorded run)."]
    if isinstance(doc.get("input"), dict):      # what the run received and dropped: its record
        analysis.summary.setdefault("input", doc["input"])
    return analysis, truth, rec.model, notes


def _load_json(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except OSError as exc:
        raise CliError(f"cannot read {path}: {exc.strerror}") from None
    except ValueError as exc:
        raise CliError(f"{path} is not valid JSON ({exc})") from None
    if not isinstance(doc, dict) or "post_flight" not in doc:
        raise CliError(f"{path} is not an analysis result (no 'post_flight')")
    return doc


def report_folder(out: str | Path, what: str = "report folder") -> Path:
    """``--out``, checked before any analysis: a folder, or one that can be made (the writer
    makes it); CliError (one line) for a file of that name or a parent that is not a writable
    folder -- nothing is analysed or written then. (Also ``run --model ins3d``'s output folder:
    ``what``.)"""
    import os

    path = Path(out)
    parent = path
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    why = None
    if path.exists() and not path.is_dir():
        why = "a file of that name exists"
    elif not parent.is_dir():
        why = f"{str(parent)!r} is not a folder"
    elif not os.access(parent, os.W_OK | os.X_OK):
        why = f"{str(parent)!r} is not writable"
    if why:
        raise CliError(f"--out {str(path)!r}: cannot make the {what} there ({why})")
    return path


def written(write, *args, **kwargs) -> Path:
    """``write(*args, **kwargs)`` (a report writer; its index path), an OSError as a CliError
    (one line: a full disk, a folder made read-only meanwhile)."""
    try:
        return write(*args, **kwargs)
    except OSError as exc:
        where = f" {exc.filename}" if exc.filename else ""
        raise CliError(f"cannot write the report{where}: {exc.strerror or exc}") from None


def _no_gate(folder: Path, args: argparse.Namespace) -> Path:
    """``folder``; CliError (one line) when a gate option is given for a run folder whose
    recording holds the gate it was filtered with (before: silently ignored)."""
    from flight_fdi.cli.analyze import gate_flags_given

    given = gate_flags_given(args)
    if given and (folder / "recording").exists():
        bag = _load_json(folder / "result.json").get("bag")
        raise CliError(f"{folder} is a run folder: its recording holds the gate it was filtered "
                       f"with; {', '.join(given)} cannot change it -- report the bag {bag!r} "
                       "with them instead")
    return folder


def run(args: argparse.Namespace) -> int:
    from flight_fdi.cli import ins3d_report
    from flight_fdi.cli.analyze import exit_status
    from flight_fdi.report import write_report

    if ins3d_report.wants_ins3d(args):  # the 3-D model (cli/ins3d_report.py)
        return ins3d_report.run_report(args)
    src = Path(args.input)
    if not src.exists():
        raise CliError(f"input {str(src)!r} does not exist")
    report_folder(args.out)
    notes: list[str] = []
    if _is_bag(src):
        res, truth, model = analyse_bag(src, args)
        notes.append(f"Analysed from the bag {src}.")
    elif src.is_dir() and (src / "result.json").exists():
        res, truth, model, notes = analyse_run_folder(_no_gate(src, args), args)
    elif src.is_file() and src.suffix == ".json":
        if (src.parent / "recording").exists() and src.name == "result.json":
            res, truth, model, notes = analyse_run_folder(_no_gate(src.parent, args), args)
        else:
            doc = _load_json(src)
            bag = Path(doc.get("bag") or "")
            if not doc.get("bag") or not _is_bag(bag):
                raise CliError(f"{src} names the bag {doc.get('bag')!r}, which does not exist; "
                               "the figures need the flight's data")
            _inputs_of(doc, args)
            res, truth, model = analyse_bag(bag, args)
            notes.append(f"The bag {bag} named in {src} was analysed again.")
    else:
        raise CliError(f"{src} is neither a bag, a 'flight-fdi run' output folder nor a result "
                       "JSON file")
    index = written(write_report, res, args.out, truth=truth, model=model, notes=notes)
    post = res.summary["post_flight"]
    if args.json:
        json.dump({"index": str(index), "summary": res.summary}, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(f"{post['verdict'].upper()}: {post.get('headline', '')}\nreport in {index}")
    return exit_status(res.summary, args)
