"""``make setup``'s warm-up (``flight_fdi.warmup.warm_voter``) compiles every signature of the
voter's kernels (core/voter_kernel.py) that ``flight-fdi vote`` runs: with the bundled threshold
table (prefilter and sequential detector), a sequential table and a "grow" (step detector) table
of the real excerpt. Before: the voter's kernels were not warmed, and a user's first vote (and
the test suite) compiled them. Checked by the kernels' compiled signatures, so the answer does
not depend on what numba's on-disk cache already holds."""
from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

DATA = Path(__file__).parent / "data" / "mimu"

_WARM_THEN_VOTE = """
import contextlib, io, json, sys
from flight_fdi.cli.main import main
from flight_fdi.core import voter_kernel
from flight_fdi.warmup import warm_voter

KERNELS = ("tail_means", "step_deviation", "cusum")
def signatures():
    return {k: sorted(map(str, getattr(voter_kernel, k).signatures)) for k in KERNELS}

bag, data, *tables = sys.argv[1:]
warm_voter()
warmed = signatures()
with contextlib.redirect_stdout(io.StringIO()):
    assert main(["imu-csv", bag, data]) == 0
    for table in tables:
        assert main(["vote", bag, *(["--thresholds", table] if table else []), "--json"]) == 0
print(json.dumps({"warmed": warmed, "after": signatures()}))
"""


def test_a_vote_compiles_nothing_the_warm_up_did_not(tmp_path):
    tables = ["", DATA / "thresholds_seq_without_vertical_path_9.json",
              DATA / "thresholds_grow_without_vertical_path_9.json"]
    proc = subprocess.run([sys.executable, "-c", _WARM_THEN_VOTE, str(tmp_path / "bag"),
                           str(DATA), *map(str, tables)],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    doc = json.loads(proc.stdout.splitlines()[-1])
    assert all(doc["warmed"].values()), doc["warmed"]     # each kernel warmed
    assert doc["after"] == doc["warmed"]                  # and the votes added no signature
