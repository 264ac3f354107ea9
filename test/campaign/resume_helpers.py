"""Helpers of the resume tests of both studies (test_resume.py, test_resume3d.py)."""
from __future__ import annotations

import json
from typing import Callable

import pytest

from flight_fdi.eval.records import RecordsFile


class Interrupt(Exception):
    """Stands for Ctrl-C in the middle of a study."""


def interrupted_file(path, settings: dict, run_study: Callable, after: int) -> list[int]:
    """Run a study (``run_study(on_record=..., done=...)``) with its records in ``path`` under
    the header ``settings``, stopped (as Ctrl-C would) after ``after`` flights; the indices
    recorded."""
    seen: list[int] = []
    with RecordsFile(path, settings) as rec:
        def write_then_stop(record: dict) -> None:
            rec.write(record)
            seen.append(record["index"])
            if len(seen) == after:
                raise Interrupt
        with pytest.raises(Interrupt):
            run_study(on_record=write_then_stop, done=rec.done)
    return seen


def lines(path) -> list[dict]:
    return [json.loads(x) for x in path.read_text().splitlines()]
