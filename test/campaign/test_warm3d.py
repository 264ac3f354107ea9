"""``batch --model ins3d`` warms its workers with the 3-D kernels: the engine gets the 3-D warm
(the single-axis one for the other models), and after it a 3-D flight, analysed as a batch task,
loads no compiled kernel of its own (numba's cache debug lines)."""
from __future__ import annotations

import os
import subprocess
import sys

import pytest

from flight_fdi.cli.main import main


@pytest.mark.parametrize("model, warm", [("ins3d", "warm_analysis3d"),
                                         ("ins_channel", "warm_analysis")])
def test_the_batch_engine_warms_its_workers_for_the_model(tmp_path, monkeypatch, model, warm):
    from flight_fdi.campaign import engine, worker

    given = []

    class Recording(engine.Engine):
        def __init__(self, spec=None, warm=None):
            given.append(warm)
            super().__init__(spec, warm)

    monkeypatch.setattr(engine, "Engine", Recording)
    code = main(["batch", str(tmp_path / "no_such_bag"), "--out", str(tmp_path / "out"),
                 "--model", model, "--workers", "1", "--no-progress", "--json"])
    assert code == 0  # (the missing bag is a row)
    assert given == [getattr(worker, warm)]


_FLIGHT_AFTER_WARM = """
import argparse, sys
from flight_fdi.campaign.batch import FlightTask, analyze_task
from flight_fdi.campaign.worker import warm_analysis3d
from flight_fdi.cli.main import build_parser

args = build_parser("batch").parse_args(["batch", sys.argv[1], "--out", "x", "--model", "ins3d"])
args = argparse.Namespace(**{k: v for k, v in vars(args).items() if k not in ("func", "inputs")})
args.jobs = 1
warm_analysis3d()
print("--- flight", flush=True)
out = analyze_task(FlightTask("f", sys.argv[1], args))
print("error:", out["error"], flush=True)
"""


@pytest.mark.timeout(300)
def test_after_the_3d_warm_a_3d_flight_loads_no_compiled_code(tmp_path):
    bag = tmp_path / "flight3d"
    assert main(["simulate", str(bag), "--model", "ins3d", "--duration", "60", "--seed",
                 "3"]) == 0
    env = {**os.environ, "NUMBA_DEBUG_CACHE": "1", "FLIGHT_FDI_THREADS": "1"}
    proc = subprocess.run([sys.executable, "-c", _FLIGHT_AFTER_WARM, str(bag)],
                          capture_output=True, text=True, timeout=280, env=env)
    assert proc.returncode == 0, proc.stderr[-2000:]
    before, after = proc.stdout.split("--- flight")
    assert "data loaded" in before  # (the debug lines are there)
    assert after.strip().endswith("error: None"), after[-2000:]
    loaded = [ln for ln in after.splitlines() if "data loaded" in ln or "saved" in ln]
    assert not loaded, loaded
