"""``flight-fdi batch``: analyse a fleet's flights on the campaign engine.

Every bag is analysed by the per-bag function of ``flight-fdi analyze``
(:func:`flight_fdi.cli.analyze.analyze_bag`, or :func:`flight_fdi.cli.ins3d.analyze_bag` for
``--model ins3d``: :func:`flight_result`) with the options of ``analyze``
(:func:`~flight_fdi.cli.analyze.add_analysis_options`), one engine task per flight. The output
folder holds::

    DIR/flights/<flight>.json   the result of each flight (what ``analyze --json`` prints)
    DIR/summary.csv             one row per flight (campaign.summary.COLUMNS)
    DIR/index.html              the fleet page (campaign.fleet)
    DIR/batch.json              the analysis options and the last run's counts
    DIR/reports/<flight>/       per-flight reports, made on demand (--reports)

Resumable: a flight whose result is newer than its bag (and was made from the same bag with the
same analysis options) is not analysed again. A bag that cannot be analysed is a summary row with
its error; the batch goes on. The results are written by this process as they arrive, so an
interrupted batch keeps every finished flight.
"""
from __future__ import annotations

import argparse
import glob
import hashlib
import json
import os
import re
import resource
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Iterable

from .engine import Engine
from .summary import summary_row

BAG_SUFFIXES = (".mcap", ".db3")
#: estimated wall seconds of one flight's analysis per MB of its bag (``--model ins3d``; the
#: single-axis models: ``ANALYSIS_S_PER_MB``) -- the high end of what was measured in one
#: process after the first flight (0.03-0.09 s per MB single-axis, 0.09-0.17 s per MB 3-D:
#: docs/scaling.md), so that the estimate errs toward the cluster (the old default): a bag
#: with other topics (camera, lidar) or without compression only makes it larger
ANALYSIS_S_PER_MB = 0.1
ANALYSIS_S_PER_MB_3D = 0.2
#: a per-flight report's figures and page, beside the analysis it runs again
REPORT_S = 1.5
#: options that say where and how to run, not what the analysis computes
RUN_OPTIONS = ("json", "jobs", "fail_on_fault")


class BatchError(RuntimeError):
    """The batch cannot start (no bags, an output folder that cannot be written)."""


# --------------------------------------------------------------------------- finding bags

def is_bag(path: Path) -> bool:
    """A rosbag2 bag: a folder with metadata.yaml, or a lone .mcap / .db3 file."""
    return (path.is_dir() and (path / "metadata.yaml").is_file()) or \
        (path.is_file() and path.suffix in BAG_SUFFIXES)


def _bags_under(root: Path) -> list[Path]:
    found = []
    for here, dirs, files in os.walk(root, followlinks=False):
        d = Path(here)
        if "metadata.yaml" in files:
            found.append(d)
            dirs[:] = []
            continue
        dirs[:] = sorted(x for x in dirs if not x.startswith("."))
        found += [d / f for f in sorted(files) if Path(f).suffix in BAG_SUFFIXES]
    return found


def find_bags(inputs: Iterable[str]) -> tuple[list[tuple[Path, Path]], list[tuple[str, str]]]:
    """([(bag, the folder its name is relative to)], [(input, why it gave no bag)]) of bag
    folders, bag files, globs and folders searched for bags; each bag once."""
    bags: dict[Path, Path] = {}
    problems: list[tuple[str, str]] = []
    for text in inputs:
        paths = [Path(text)]
        if not paths[0].exists() and any(c in text for c in "*?["):
            paths = [Path(p) for p in sorted(glob.glob(text, recursive=True))]
            if not paths:
                problems.append((text, f"no path matches {text!r}"))
                continue
        for p in paths:
            if not p.exists():
                problems.append((text, f"{text!r} does not exist"))
            elif is_bag(p):
                bags.setdefault(p.resolve(), p.resolve().parent)
            elif p.is_dir():
                under = _bags_under(p)
                if not under:
                    problems.append((text, f"no rosbag2 bag in {str(p)!r}"))
                for b in under:
                    bags.setdefault(b.resolve(), p.resolve())
            else:
                problems.append((text, f"{str(p)!r} is neither a bag nor a folder"))
    return sorted(bags.items()), problems


def flight_names(bags: list[tuple[Path, Path]]) -> dict[Path, str]:
    """A file-name-safe name per bag: its path below the input folder ('/' -> '__', no bag
    suffix); names that collide get a short hash of the bag's absolute path."""
    raw: dict[Path, str] = {}
    for bag, root in bags:
        rel = bag.relative_to(root) if bag != root else Path(bag.name)
        text = "__".join(rel.with_suffix("").parts if bag.is_file() else rel.parts)
        raw[bag] = re.sub(r"[^A-Za-z0-9._-]", "_", text) or "flight"
    counts: dict[str, int] = {}
    for n in raw.values():
        counts[n] = counts.get(n, 0) + 1
    return {b: n if counts[n] == 1 else f"{n}-{hashlib.sha1(str(b).encode()).hexdigest()[:8]}"
            for b, n in raw.items()}


def bag_megabytes(bag: Path) -> float:
    """The size of a bag's files (a bag folder: every file in it), MB."""
    if bag.is_file():
        return bag.stat().st_size / 1e6
    return sum(f.stat().st_size for f in bag.iterdir() if f.is_file()) / 1e6


def bag_mtime(bag: Path) -> float:
    """When the bag last changed: its newest file."""
    if bag.is_file():
        return bag.stat().st_mtime
    return max([f.stat().st_mtime for f in bag.iterdir() if f.is_file()] or
               [bag.stat().st_mtime])


# --------------------------------------------------------------------------- one flight

@dataclass(frozen=True)
class FlightTask:
    """One flight for the engine: everything its result depends on."""

    name: str
    bag: str
    args: argparse.Namespace


def analyze_task(task: FlightTask) -> dict:
    """Analyse one flight like ``flight-fdi analyze`` (runs on a worker): ``{"result": dict |
    None, "error": str | None, "seconds": float, "cpu_s": float, "page_faults": int}`` (wall
    and CPU time of the worker process, and its minor page faults, during the flight); never
    raises for a bad bag."""
    start, usage = time.perf_counter(), resource.getrusage(resource.RUSAGE_SELF)
    try:
        result, error = flight_result(task.bag, task.args), None
        json.dumps(result, allow_nan=False)  # what analyze --json would refuse
    except Exception as exc:  # a bad bag is a row with its error
        result, error = None, error_text(exc)
    end = resource.getrusage(resource.RUSAGE_SELF)
    return {"result": result, "error": error, "seconds": time.perf_counter() - start,
            "cpu_s": end.ru_utime + end.ru_stime - usage.ru_utime - usage.ru_stime,
            "page_faults": end.ru_minflt - usage.ru_minflt}


def flight_result(bag: str, args: argparse.Namespace) -> dict:
    """The result ``flight-fdi analyze BAG --json`` prints with these options: the 3-D
    model's (``cli.ins3d.analyze_bag``, as ``analyze --model ins3d`` runs it) or the
    single-axis models' (``cli.analyze.analyze_bag``)."""
    if getattr(args, "model", None) == "ins3d":
        from flight_fdi.cli.ins3d import analyze_bag as analyze_bag3d

        return analyze_bag3d(bag, args)[0]
    from flight_fdi.cli.analyze import analyze_bag

    return analyze_bag(bag, args)


def check_model_options(args: argparse.Namespace) -> None:
    """Refuse what ``flight-fdi analyze`` refuses before it reads a bag, once for the whole
    batch (CliError or CoreError, one line): options of the other model
    (``cli.ins3d.is_ins3d``); for ``--model ins3d``, a bad grade, gate or error-model option
    (``settings``, ``error_model_block``); for the single-axis models, a bad gate option
    (``cli.analyze.analysis_config``) or an unknown model (``core.models.get_model``). A grade
    file becomes its absolute path (the workers' and the fingerprint's)."""
    from flight_fdi.cli.analyze import analysis_config
    from flight_fdi.cli.ins3d import error_model_block, is_ins3d, settings
    from flight_fdi.core.models import get_model

    if is_ins3d(args):
        grade = settings(args)["grade"]
        if args.grade is not None:
            args.grade = grade
        error_model_block(args)
    else:
        analysis_config(args)
        get_model(args.model)


def error_text(exc: BaseException) -> str:
    """One line: the message of a user error, else the exception's type and message."""
    from flight_fdi.cli.main import _user_errors

    msg = " ".join(str(exc).split()) or type(exc).__name__
    return msg if isinstance(exc, _user_errors()) else f"{type(exc).__name__}: {msg}"


# --------------------------------------------------------------------------- the batch

def analysis_options(args: argparse.Namespace) -> dict:
    """The options of ``analyze`` that change a result (the ones add_analysis_options
    declares, whatever they are), as plain data."""
    from flight_fdi.cli.analyze import add_analysis_options

    probe = argparse.ArgumentParser(add_help=False)
    add_analysis_options(probe)
    dests = sorted(a.dest for a in probe._actions if a.dest not in RUN_OPTIONS)
    return {d: _plain(getattr(args, d, None)) for d in dests}


def option_flags(args: argparse.Namespace) -> list[str]:
    """The analysis options of ``args`` that differ from their defaults, as command-line
    arguments (for the report command shown on the fleet page)."""
    from flight_fdi.cli.analyze import add_analysis_options

    probe = argparse.ArgumentParser(add_help=False)
    add_analysis_options(probe)
    defaults = probe.parse_args([])
    out: list[str] = []
    for a in probe._actions:
        if not a.option_strings or a.dest in RUN_OPTIONS:
            continue
        value = getattr(args, a.dest, None)
        if value == getattr(defaults, a.dest):
            continue
        flag = a.option_strings[-1]
        if isinstance(a, argparse.BooleanOptionalAction):  # --latency / --no-latency
            out.append(a.option_strings[0] if value else flag)
        elif a.nargs == 0:
            out.append(flag)
        else:
            for v in value if isinstance(value, (list, tuple)) else [value]:
                out += [flag, str(v)]
    return out


def _plain(v: Any) -> Any:
    if isinstance(v, (list, tuple)):
        return [_plain(x) for x in v]
    return v if v is None or isinstance(v, (bool, int, float, str)) else str(v)


@dataclass
class BatchResult:
    rows: list[dict]
    analysed: int = 0
    skipped: int = 0
    failed: int = 0
    elapsed_s: float = 0.0
    engine: str = ""
    seconds: list[float] = field(default_factory=list)  # per analysed flight, on its worker
    cpu_s: list[float] = field(default_factory=list)  # the same flights' CPU on the worker
    page_faults: list[int] = field(default_factory=list)  # ... and minor page faults


class Batch:
    """The flights of one ``flight-fdi batch`` and its output folder."""

    def __init__(self, inputs: Iterable[str], out: str | Path, args: argparse.Namespace,
                 force: bool = False) -> None:
        self.out = Path(out)
        self.flights_dir = self.out / "flights"
        # what each task carries (not the list of inputs: 10^4 paths in every task)
        self.args = argparse.Namespace(**{k: v for k, v in vars(args).items()
                                          if k not in ("func", "inputs")})
        self.args.jobs = 1  # parallel over flights, not inside one
        check_model_options(self.args)
        self.options = analysis_options(self.args)
        if self.args.model == "ins3d" and self.args.grade and Path(self.args.grade).is_file():
            # a grade file: its contents, not only its name, decide whether to analyse again
            self.options["grade_file_sha1"] = hashlib.sha1(
                Path(self.args.grade).read_bytes()).hexdigest()
        bags, self.problems = find_bags(inputs)
        if not bags and not self.problems:
            raise BatchError("no inputs")
        self.names = flight_names(bags)
        self.force = force or self._options_changed()
        self._plan: tuple[dict[str, dict], list[FlightTask]] | None = None

    def result_path(self, name: str) -> Path:
        return self.flights_dir / f"{name}.json"

    def _options_changed(self) -> bool:
        try:
            before = json.loads((self.out / "batch.json").read_text())["options"]
        except (OSError, ValueError, KeyError, TypeError):
            return False
        return before != self.options

    def up_to_date(self, bag: Path, name: str) -> dict | None:
        """The stored result of ``bag`` when it is newer than the bag, from this bag, with
        today's options; else None."""
        path = self.result_path(name)
        if self.force or not path.is_file():
            return None
        try:
            if path.stat().st_mtime <= bag_mtime(bag):
                return None
            doc = json.loads(path.read_text())
        except (OSError, ValueError):
            return None
        return doc if isinstance(doc, dict) and doc.get("bag") == str(bag) else None

    def plan(self) -> tuple[dict[str, dict], list[FlightTask]]:
        """(summary rows of the flights up to date, the tasks of the others): what the next
        :meth:`run` does (it takes this plan, made once)."""
        if self._plan is None:
            rows: dict[str, dict] = {}
            tasks: list[FlightTask] = []
            for bag, name in sorted(self.names.items(), key=lambda kv: kv[1]):
                done = self.up_to_date(bag, name)
                if done is not None:
                    rows[name] = summary_row(name, done, bag=str(bag))
                else:
                    tasks.append(FlightTask(name, str(bag), self.args))
            self._plan = (rows, tasks)
        return self._plan

    def estimated_work(self, reports: str | None = None,
                       enough: float = float("inf")) -> tuple[int, float]:
        """(tasks, estimated serial wall seconds) of the next run: the flights to analyse
        (:meth:`plan`; ``ANALYSIS_S_PER_MB`` of their bags) and, with ``reports`` (--reports),
        the flights whose report it may make (``REPORT_S`` each and their analysis again). The
        bags' sizes are summed until the estimate passes ``enough``."""
        per_mb = ANALYSIS_S_PER_MB_3D if self.args.model == "ins3d" else ANALYSIS_S_PER_MB
        bags = {name: bag for bag, name in self.names.items()}
        jobs = [(bags[t.name], 0.0) for t in self.plan()[1]]
        if reports:
            wanted = (set(bags) if reports in ("all", "faults")
                      else {n.strip() for n in reports.split(",")} & set(bags))
            jobs += [(bags[n], REPORT_S) for n in sorted(wanted) if not self._report_fresh(n)]
        work = 0.0
        for bag, extra in jobs:
            if work > enough:
                break
            work += extra + per_mb * bag_megabytes(bag)
        return len(jobs), work

    def _report_fresh(self, name: str) -> bool:
        index = self.out / "reports" / name / "index.html"
        result = self.result_path(name)
        try:
            return index.stat().st_mtime > result.stat().st_mtime
        except OSError:
            return False

    def run(self, engine: Engine, progress: bool = False,
            say: Callable[[str], None] = lambda s: None,
            on_flight: Callable[[dict], None] | None = None) -> BatchResult:
        """Analyse every flight that is not up to date; write results, summary and fleet page
        (also when interrupted: what finished is kept). ``on_flight`` gets the summary row of
        each flight analysed (or failed) in this run, as it arrives."""
        try:
            self.flights_dir.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise BatchError(f"cannot create {self.flights_dir}: {exc.strerror}") from None
        start = time.perf_counter()
        done_rows, tasks = self.plan()
        self._plan = None          # (a second run plans again)
        rows = dict(done_rows)
        for text, why in self.problems:
            name = re.sub(r"[^A-Za-z0-9._-]", "_", Path(text).name).strip("_.") or "input"
            while name in rows or name in self.names.values():
                name += "-input"
            rows[name] = summary_row(name, None, error=why, bag=text)
        res = BatchResult(rows=[], skipped=len(self.names) - len(tasks), engine=engine.describe(),
                          failed=len(self.problems))
        say(f"batch: {len(self.names)} flight(s), {res.skipped} up to date, {len(tasks)} to "
            f"analyse; running on {res.engine}")

        def arrived(i: int, out: dict | None, err: BaseException | None) -> None:
            task = tasks[i]
            if err is not None:  # the engine lost it (e.g. it killed every worker it ran on)
                out = {"result": None, "error": error_text(err), "seconds": None}
            if out["result"] is not None:
                _write_json(self.result_path(task.name), out["result"])
                res.analysed += 1
                res.seconds.append(out["seconds"])
                res.cpu_s.append(out["cpu_s"])
                res.page_faults.append(out["page_faults"])
            else:
                res.failed += 1
            rows[task.name] = summary_row(task.name, out["result"], error=out["error"],
                                          bag=task.bag)
            if on_flight is not None:
                on_flight(rows[task.name])

        try:
            engine.run(analyze_task, tasks, progress=progress, desc="batch", unit="flight",
                       on_outcome=arrived)
        finally:
            res.rows = [rows[k] for k in sorted(rows)]
            res.elapsed_s = time.perf_counter() - start
            self.write_outputs(res)
        return res

    def write_outputs(self, res: BatchResult) -> None:
        from .fleet import write_fleet_page, write_summary_csv

        write_summary_csv(res.rows, self.out / "summary.csv")
        write_fleet_page(res.rows, self.out, self.reports_of(res.rows),
                         report_options=option_flags(self.args),
                         note=f"{res.analysed} analysed, {res.skipped} up to date, "
                              f"{res.failed} failed in the last run ({res.elapsed_s:.1f} s on "
                              f"{res.engine}).")
        _write_json(self.out / "batch.json", {
            "options": self.options, "flights": len(res.rows), "analysed": res.analysed,
            "skipped": res.skipped, "failed": res.failed, "elapsed_s": res.elapsed_s,
            "engine": res.engine}, indent=1)

    def reports_of(self, rows: list[dict]) -> dict[str, str]:
        """flight -> its report page (relative to the output folder), for the reports that
        exist."""
        out = {}
        for r in rows:
            index = self.out / "reports" / r["flight"] / "index.html"
            result = self.result_path(r["flight"])
            if index.is_file() and result.is_file() \
                    and index.stat().st_mtime > result.stat().st_mtime:
                out[r["flight"]] = index.relative_to(self.out).as_posix()
        return out


def _write_json(path: Path, doc: Any, indent: int | None = None) -> None:
    """Write atomically (a reader never sees half a file; a rerun replaces, never appends)."""
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(json.dumps(doc, allow_nan=False, indent=indent) + "\n", encoding="utf-8")
    os.replace(tmp, path)
