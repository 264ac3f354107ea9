"""``report --model ins3d`` (``cli.report.run`` hands over to :func:`run_report`) and the report
of ``run --model ins3d`` (``cli.run.complete3d``): the per-axis figures (``report.figures3d``) of
a bag analysed as ``analyze --model ins3d`` does (``cli.ins3d.analyze_bag``), of a ``run`` output
folder rebuilt from its recording, or of a result JSON whose bag is analysed again with the
options it records (``cli.ins3d.options_of_result``).
"""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from flight_fdi.cli.analyze import exit_status, gate_flags_given
from flight_fdi.cli.errors import CliError
from flight_fdi.cli.ins3d import ERROR_MODEL_OPTIONS, analyze_bag, is_ins3d, options_of_result
from flight_fdi.cli.ins3d_height import HEIGHT_OPTIONS


def _load_result(path: Path) -> dict:
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise CliError(f"cannot read the result {path}: {exc}") from None
    if not isinstance(doc, dict) or "post_flight" not in doc:
        raise CliError(f"{path} is not an analysis result (no 'post_flight')")
    return doc


def _run_folder(src: Path) -> Path | None:
    """The ``flight-fdi run`` output folder that ``src`` names (the folder or its result.json)."""
    folder = src.parent if src.name == "result.json" else src
    return folder if (folder / "result.json").exists() and (folder / "recording").exists() \
        else None


def wants_ins3d(args: argparse.Namespace) -> bool:
    """``report``: --model ins3d, or a result / run folder of the ins3d model (then the ins3d
    options apply without --model)."""
    if getattr(args, "model", None) != "ins3d":
        src = Path(args.input)
        doc = src / "result.json" if src.is_dir() else src
        if doc.suffix == ".json" and doc.is_file() and _load_result(doc).get("model") == "ins3d":
            args.model = "ins3d"
    return is_ins3d(args)


def _is_bag(p: Path) -> bool:
    return (p.is_dir() and (p / "metadata.yaml").exists()) or p.suffix in (".mcap", ".db3")


def _truth(bag: str | None, t0_ns: int):
    from flight_fdi.bagio.ins3d_input import read_truth3d

    return read_truth3d(bag, t0_ns) if bag and _is_bag(Path(bag)) and Path(bag).exists() \
        else None


def report_of_run(folder: Path, out: str | Path, doc: dict | None = None,
                  analysed: tuple | None = None) -> Path:
    """The report of a ``run --model ins3d`` folder, rebuilt from its recording -- or of
    ``analysed``, (Ins3dAnalysis, recording dict, truth of ``truth_of_raw`` or None): what the
    run itself read and analysed (``cli.run.complete3d``: nothing read or analysed again)."""
    from flight_fdi.bagio.ins3d_input import truth_relative
    from flight_fdi.cli.report import written
    from flight_fdi.core.ins3d_result import ins3d_result
    from flight_fdi.bagio.recording_analysis import analyze_recording3d
    from flight_fdi.report.figures3d import write_report3d

    doc = doc or _load_result(folder / "result.json")
    if analysed is None:
        res, analysis, rec = analyze_recording3d(folder / "recording", bag_label=doc.get("bag"))
        truth = _truth(doc.get("bag"), rec["t0_ns"])
    else:
        analysis, rec, raw_truth = analysed
        res = ins3d_result(analysis, doc.get("bag") or str(folder / "recording"))
        truth = truth_relative(raw_truth, rec["t0_ns"])
    for key in ("source", "input"):         # the run's record: its options, what it received
        if doc.get(key):
            res[key] = doc[key]
    notes = [f"Rebuilt from the recording {folder / 'recording'} of the node pipeline."]
    return written(write_report3d, res, analysis, out, truth=truth, notes=notes)


#: the options a run folder's recording fixes (dest, flag): what its filter ran with
RUN_FIXED = (("grade", "--grade"), ("rows", "--rows"), ("ins_topic", "--ins-topic"),
             ("reference_topic", "--reference-topic"), ("imu_topic", "--imu-topic"),
             ("fix_topic", "--fix-topic")) + ERROR_MODEL_OPTIONS + HEIGHT_OPTIONS


def refuse_for_run(args: argparse.Namespace, folder: Path, bag: str | None) -> None:
    """``report RUN_FOLDER``: the recording holds what the filter ran with (grade, rows,
    topics, gate, error model); an option that would change it is refused, one line naming
    it (before: silently ignored)."""
    given = [flag for dest, flag in RUN_FIXED if getattr(args, dest, None) is not None]
    given += gate_flags_given(args)
    if given:
        raise CliError(f"{folder} is a run folder: its recording holds the analysis it was "
                       "filtered with (grade, rows, topics, gate, error model); "
                       f"{', '.join(given)} cannot change it -- report the bag {bag!r} with "
                       "them instead")


def run_report(args: argparse.Namespace) -> int:
    """``flight-fdi report INPUT --model ins3d --out DIR``: INPUT a bag, a ``run`` output folder
    or a result JSON naming its bag."""
    from flight_fdi.cli.report import report_folder

    src = Path(args.input)
    if not src.exists():
        raise CliError(f"input {str(src)!r} does not exist")
    folder = _run_folder(src)
    if folder is not None:
        doc = _load_result(folder / "result.json")
        refuse_for_run(args, folder, doc.get("bag"))
        index = report_of_run(folder, report_folder(args.out), doc)
    else:
        if not _is_bag(src):
            doc = _load_result(src)
            options_of_result(args, doc)
            src = Path(doc.get("bag") or "")
            if not (_is_bag(src) and src.exists()):
                raise CliError(f"{args.input} names the bag {doc.get('bag')!r}, which does not "
                               "exist; the figures need the flight's data")
        index = report_of_bag(str(src), args, report_folder(args.out),
                              notes=[f"Analysed from the bag {src}."])
    res = json.loads((Path(index).parent / "summary.json").read_text(encoding="utf-8"))
    if args.json:
        json.dump({"index": str(index), "summary": res}, sys.stdout, allow_nan=False)
        sys.stdout.write("\n")
    else:
        print(f"{res['post_flight']['verdict'].upper()}: {res['post_flight']['headline']}\n"
              f"report in {index}")
    return exit_status(res, args)


def report_of_bag(bag: str, args: argparse.Namespace, out: str | Path,
                  notes: list[str]) -> Path:
    """Analyse ``bag`` (``analyze_bag``) and write its report in ``out``; the index path."""
    from flight_fdi.cli.report import written
    from flight_fdi.report.figures3d import write_report3d

    res, analysis, inp = analyze_bag(bag, args)
    return written(write_report3d, res, analysis, out, truth=_truth(bag, inp.t0_ns),
                   notes=notes)


__all__ = ["RUN_FIXED", "refuse_for_run", "report_of_bag", "report_of_run", "run_report",
           "wants_ins3d"]
