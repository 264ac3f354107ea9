"""A study's per-flight records on disk, as JSON lines, and resuming a study from them.

The file (``flight-fdi montecarlo --records FILE``) holds a header line, then one record per
line in the order the flights finished::

    {"records": "flight_fdi.study/1", "study": {...the study's settings...}}
    {"index": 17, "kind": "accel", "sim_seed": ..., ...}
    ...

A record is written and flushed as soon as its flight finishes, so an interrupted study (Ctrl-C,
a lost machine, a killed job) keeps every finished flight. Opening the file again for the same
study (the same settings, compared as JSON) *resumes* it: the recorded flights are returned and
only the others need to run; a last line cut in the middle of writing is dropped. A file of
another study is an error (never overwritten silently); ``restart=True`` starts it anew.
Records are plain JSON (numbers round-trip exactly), so a resumed study's records equal those of
an uninterrupted run.
"""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any, Mapping

from .errors import EvalError

FORMAT = "flight_fdi.study/1"


def _plain(doc: Any) -> Any:
    """``doc`` as it reads back from JSON (tuples -> lists...)."""
    return json.loads(json.dumps(doc, allow_nan=False))


def _differences(study: dict, other: Any) -> str:
    """The settings in which two studies differ (the model first; at most 6 named)."""
    other = other if isinstance(other, dict) else {}
    changed = sorted((k for k in set(study) | set(other) if study.get(k) != other.get(k)),
                     key=lambda k: (k != "model", k))
    if not changed:
        return "its settings"
    named = [f"model ({other.get('model', 'channel')}, not {study.get('model', 'channel')})"
             if k == "model" else k for k in changed[:6]]
    return ", ".join(named) + (f" and {len(changed) - 6} more" if len(changed) > 6 else "")


def recorded_flights(done: Mapping[Any, dict], plan: Mapping[int, dict]) -> dict[int, dict]:
    """The records of ``done`` (a resumed study's, by flight index) checked against the study's
    ``plan`` (flight index -> the fields its record must hold, e.g. its kind and simulator
    seed): a record of a flight the study does not have, or with other values, means the file
    is of another study or plan -- an error, never a wrong result."""
    kept = {}
    for i, rec in done.items():
        want = plan.get(i) if isinstance(i, int) else None
        if want is None or any(rec.get(k) != v for k, v in want.items()):
            raise EvalError(f"recorded flight {i!r} is not a flight of this study (another "
                            "seed or plan)")
        kept[i] = rec
    return kept


def read_records(path: str | Path, key: str = "index") -> tuple[dict, list[dict]]:
    """The study settings of a records file and its complete records, in file order (a last
    line cut while it was written is left out); a file that is not one is an EvalError."""
    study, records, _ = _read_file(Path(path), key)
    return study, records


def _read_file(path: Path, key: str) -> tuple[dict, list[dict], int]:
    """(the header's study, the complete records, the byte offset after the last of them)."""
    try:
        data = path.read_bytes()
    except OSError as exc:
        raise EvalError(f"cannot read {path}: {exc.strerror}") from None
    lines = data.split(b"\n")
    complete, tail = lines[:-1], lines[-1]  # tail: b"" or a line cut in the middle
    head = _parse(path, complete[0] if complete else tail, 1)
    if not isinstance(head, dict) or head.get("records") != FORMAT:
        raise EvalError(f"{path} is not a study records file of this version (no "
                        f"'{FORMAT}' header line); use another file or restart it")
    records = []
    for n, line in enumerate(complete[1:], start=2):
        rec = _parse(path, line, n)
        if not isinstance(rec, dict) or key not in rec:
            raise EvalError(f"line {n} of {path} is not a record (no '{key}')")
        records.append(rec)
    return head.get("study"), records, len(data) - len(tail) if complete else 0


def _parse(path: Path, line: bytes, n: int) -> Any:
    try:
        return json.loads(line)
    except ValueError:
        raise EvalError(f"line {n} of {path} is not JSON; the file is damaged "
                        "(use another file or restart it)") from None


class RecordsFile:
    """The JSON-lines records of one study (``study``: its settings as plain data; ``key``:
    the record field that identifies a flight). Use as a context manager::

        with RecordsFile(path, config.describe()) as rec:
            done = rec.done            # {index: record} already on disk (resume)
            ...                        # run the others, rec.write(record) for each
    """

    def __init__(self, path: str | Path, study: dict, key: str = "index",
                 restart: bool = False) -> None:
        self.path = Path(path)
        self.study = _plain(study)
        self.key = key
        self.restart = restart
        self.done: dict[Any, dict] = {}
        self._stream = None

    def __enter__(self) -> "RecordsFile":
        self.open()
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    def open(self) -> dict[Any, dict]:
        """Read what the file holds for this study (resume) and open it for appending; a new,
        empty or restarted file gets the header. Returns :attr:`done`."""
        if not self.path.parent.is_dir():
            raise EvalError(f"cannot write {self.path}: directory '{self.path.parent}' does not "
                            "exist")
        good_end = 0
        if not self.restart and self.path.is_file() and self.path.stat().st_size > 0:
            good_end = self._read()
        try:
            if good_end:
                self._stream = self.path.open("r+", encoding="utf-8")
                self._stream.seek(good_end)
                self._stream.truncate()  # a last line cut while it was written
            else:
                self._stream = self.path.open("w", encoding="utf-8")
                self._write_line({"records": FORMAT, "study": self.study})
        except OSError as exc:
            raise EvalError(f"cannot write {self.path}: {exc.strerror}") from None
        return self.done

    def _read(self) -> int:
        """Fill :attr:`done` from the file; the byte offset after its last complete record."""
        study, records, good_end = _read_file(self.path, self.key)
        if study != self.study:
            raise EvalError(f"{self.path} holds the records of another study (differs in "
                            f"{_differences(self.study, study)}); use another file "
                            "or restart it")
        for rec in records:
            self.done.setdefault(rec[self.key], rec)
        return good_end

    def write(self, record: dict) -> None:
        """Append one record and flush it to the operating system."""
        self._write_line(record)

    def _write_line(self, doc: dict) -> None:
        self._stream.write(json.dumps(doc, allow_nan=False) + "\n")
        self._stream.flush()

    def close(self) -> None:
        if self._stream is not None:
            try:
                os.fsync(self._stream.fileno())
            except OSError:  # pragma: no cover - e.g. a pipe
                pass
            self._stream.close()
            self._stream = None
