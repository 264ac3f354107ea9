"""A short 3-D contract bag (simulated once per session; ~400 s, the first turn at ~303 s), and
one ``run --model ins3d`` of it (the node pipeline and its report, ~8 s) that the tests which only
read its outputs share."""
from __future__ import annotations

import contextlib
import io
import json
import os
import sys
import tempfile
from pathlib import Path
from typing import NamedTuple

import pytest

from flight_fdi.cli.main import main


@pytest.fixture(scope="session")
def bag3d(tmp_path_factory):
    out = tmp_path_factory.mktemp("ins3d") / "gyro_x"
    assert main(["simulate", str(out), "--model", "ins3d", "--duration", "400", "--seed", "2",
                 "--fault", "gyro:step:t=150,mag=3deg/h,axis=x"]) == 0
    return out


class Run3d(NamedTuple):
    """``flight-fdi run BAG3D --model ins3d --out FOLDER --json --no-progress --fail-on-fault``:
    its exit status, what it printed (the result JSON) and its folder (recording, result.json,
    report/). Read only: a test that changes a file copies the folder first."""
    rc: int
    stdout: str
    folder: Path


def stdout_of(argv: list[str]) -> tuple[int, str]:
    """``main(argv)``'s exit status and everything written to standard output, by Python or by
    C code on file descriptor 1 (what ``capfd`` sees; a session fixture cannot use it)."""
    sys.stdout.flush()
    saved = os.dup(1)
    py = io.StringIO()
    with tempfile.TemporaryFile() as fd_out:
        os.dup2(fd_out.fileno(), 1)
        try:
            with contextlib.redirect_stdout(py):
                rc = main(argv)
        finally:
            os.dup2(saved, 1)
            os.close(saved)
        fd_out.seek(0)
        return rc, fd_out.read().decode() + py.getvalue()


@pytest.fixture(scope="session")
def run3d(bag3d, tmp_path_factory) -> Run3d:
    folder = tmp_path_factory.mktemp("run3d") / "run"
    rc, out = stdout_of(["run", str(bag3d), "--model", "ins3d", "--out", str(folder), "--json",
                         "--no-progress", "--fail-on-fault"])
    return Run3d(rc, out, folder)
