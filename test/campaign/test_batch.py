"""flight-fdi batch: finding bags, one result per flight equal to analyze's, the summary and
the fleet page, bad bags as rows, resuming; on a real 2-process Dask cluster."""
from __future__ import annotations

import argparse
import csv
import json
import os
import subprocess
import sys
from collections import Counter

import pytest

from flight_fdi.campaign.batch import Batch, find_bags, flight_names
from flight_fdi.campaign.engine import Engine, EngineSpec
from flight_fdi.campaign.summary import COLUMNS
from flight_fdi.cli.analyze import analyze_bag
from flight_fdi.cli.main import build_parser

from conftest import copy_fleet


def batch_args(*argv: str) -> argparse.Namespace:
    return build_parser("batch").parse_args(["batch", "IN", "--out", "OUT", *argv])


def make_fleet(short_bags, root):
    """fleet/a/flight_00..02, fleet/b/flight_00 (same name, other folder), a bag that is not
    one, and a lone .mcap file."""
    copy_fleet(short_bags, root / "fleet" / "a", 3)
    copy_fleet(short_bags, root / "fleet" / "b", 1)
    (root / "fleet" / "broken").mkdir()
    (root / "fleet" / "broken" / "broken.mcap").write_bytes(b"not an mcap file")
    mcap = next((short_bags["gyro"]).glob("*.mcap"))
    (root / "fleet" / "lone.mcap").write_bytes(mcap.read_bytes())
    return root / "fleet"


def test_find_bags_folders_globs_files_and_names(short_bags, tmp_path):
    fleet = make_fleet(short_bags, tmp_path)
    bags, problems = find_bags([str(fleet), str(fleet / "a" / "flight_01"),
                                str(tmp_path / "missing"), str(tmp_path / "nothing*")])
    names = sorted(flight_names(bags).values())
    assert names == ["a__flight_00", "a__flight_01", "a__flight_02", "b__flight_00",
                     "broken__broken", "lone"]  # flight_01 once, although named twice
    assert [p for p, _ in problems] == [str(tmp_path / "missing"), str(tmp_path / "nothing*")]
    # a glob; the same leaf name from two folders gets a hash, never a collision
    bags, problems = find_bags([str(fleet / "*" / "flight_00")])
    names = flight_names(bags)
    assert not problems and len(set(names.values())) == 2
    assert all(n.startswith("flight_00-") for n in names.values())


@pytest.fixture
def on_cluster(dask_cluster):
    with Engine(EngineSpec(scheduler=dask_cluster)) as engine:
        yield engine


def test_batch_results_summary_page_and_resume(short_bags, tmp_path, on_cluster):
    fleet = make_fleet(short_bags, tmp_path)
    out = tmp_path / "out"
    args = batch_args()
    batch = Batch([str(fleet), str(tmp_path / "missing")], out, args)
    res = batch.run(on_cluster)
    assert (res.analysed, res.skipped, res.failed) == (5, 0, 2)
    rows = {r["flight"]: r for r in res.rows}
    assert len(rows) == 7 and list(res.rows[0]) == list(COLUMNS)
    assert "cannot be opened" in rows["broken__broken"]["error"]
    assert "does not exist" in rows["missing"]["error"]
    # every good flight: its result is exactly what analyze gives for that bag
    inline = argparse.Namespace(**vars(args))
    inline.jobs = 1
    for name in ("a__flight_00", "a__flight_01", "a__flight_02", "b__flight_00", "lone"):
        doc = json.loads((out / "flights" / f"{name}.json").read_text())
        assert doc == analyze_bag(doc["bag"], inline)
        assert rows[name]["error"] is None and rows[name]["verdict"] is not None
    # accel, gyro (a gyro step, or ambiguous with an accelerometer ramp), nominal
    assert rows["a__flight_00"]["sensor"] == "accelerometer"
    assert "gyro" in rows["a__flight_01"]["sensor"].split("|")
    assert rows["a__flight_02"]["sensor"] is None
    # summary.csv: one row per flight, the same values
    with open(out / "summary.csv", newline="") as f:
        table = list(csv.DictReader(f))
    assert [t["flight"] for t in table] == sorted(rows)
    assert table[0].keys() == set(COLUMNS)
    by = {t["flight"]: t for t in table}
    assert float(by["a__flight_00"]["onset_s"]) == pytest.approx(rows["a__flight_00"]["onset_s"])
    # the fleet page: every flight, the counts, links to results, report commands
    page = (out / "index.html").read_text()
    for name in rows:
        assert name in page
    assert '<a href="flights/lone.json">lone</a>' in page
    assert "flight-fdi report flights/a__flight_00.json --out reports/a__flight_00" in page
    verdicts = Counter(r["verdict"] or "error" for r in res.rows)
    assert verdicts["failure"] >= 2 and verdicts["error"] == 2 and sum(verdicts.values()) == 7
    for verdict, n in verdicts.items():
        assert f"<td>{verdict}</td><td>{n}</td>" in page
    assert "<td>accelerometer</td><td>2</td>" in page

    # a second run: nothing to analyse; the bad bag is tried again
    again = Batch([str(fleet), str(tmp_path / "missing")], out, args).run(on_cluster)
    assert (again.analysed, again.skipped, again.failed) == (0, 5, 2)
    assert again.rows == res.rows
    # a bag newer than its result is analysed again, alone
    bag = fleet / "a" / "flight_02"
    future = (out / "flights" / "a__flight_02.json").stat().st_mtime + 10
    os.utime(next(bag.glob("*.mcap")), (future, future))
    seen = []
    third = Batch([str(fleet)], out, args).run(on_cluster, on_flight=seen.append)
    assert (third.analysed, third.skipped) == (1, 4)
    assert [r["flight"] for r in seen if r["error"] is None] == ["a__flight_02"]
    # other analysis options: every flight again
    fourth = Batch([str(fleet)], out, batch_args("--gate-probability", "1e-4")).run(on_cluster)
    assert (fourth.analysed, fourth.skipped) == (5, 0)


def run_cli(*argv: str, timeout: float = 180, env: dict | None = None):
    return subprocess.run([sys.executable, "-m", "flight_fdi.cli.main", *argv],
                          capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})})


@pytest.mark.slow
def test_cli_batch_on_the_embedded_local_cluster(short_bags, tmp_path):
    out = tmp_path / "out"
    r = run_cli("batch", *(str(b) for b in short_bags.values()), "--out", str(out),
                "--workers", "2", "--json", "--no-progress", "--fail-on-fault")
    assert r.returncode == 3, r.stderr[-2000:]  # analyze's status for a declared fault
    doc = json.loads(r.stdout)
    assert doc["analysed"] == 3 and doc["failed"] == 0
    assert "local Dask cluster (2 workers)" in doc["engine"]
    assert sorted(f["flight"] for f in doc["flights"]) == ["accel", "gyro", "nominal"]
    assert "Traceback" not in r.stderr


def test_cli_errors_are_one_line(tmp_path, free_port):
    r = run_cli("batch", str(tmp_path / "none*"), "--out", str(tmp_path / "o"), "--workers",
                "1", "--no-progress")
    # an input that gives no bag is a row; the batch still writes its outputs
    assert r.returncode == 0 and "no path matches" in r.stderr
    assert (tmp_path / "o" / "summary.csv").is_file()
    r = run_cli("batch", str(tmp_path), "--out", str(tmp_path / "o"), "--scheduler",
                f"tcp://127.0.0.1:{free_port()}", env={"FLIGHT_FDI_DASK_TIMEOUT": "2"})
    assert r.returncode == 1
    assert r.stderr.strip().count("\n") == 0 and "cannot reach the Dask scheduler" in r.stderr
    r = run_cli("batch", str(tmp_path), "--out", str(tmp_path / "o"), "--workers", "0")
    assert r.returncode == 1 and r.stderr.count("\n") == 1 and "workers" in r.stderr


@pytest.mark.slow
def test_reports_on_demand(short_bags, tmp_path):
    out = tmp_path / "out"
    args = batch_args()
    with Engine(EngineSpec(workers=1)) as engine:
        batch = Batch([str(short_bags["accel"]), str(short_bags["nominal"])], out, args)
        res = batch.run(engine)
        from flight_fdi.campaign.reports import make_reports

        assert make_reports(batch, res, engine, "faults") == []
    assert (out / "reports" / "accel" / "index.html").is_file()
    assert (out / "reports" / "accel" / "glr.png").is_file()
    assert not (out / "reports" / "nominal").exists()
    page = (out / "index.html").read_text()
    assert '<a href="reports/accel/index.html">report</a>' in page
    assert "flight-fdi report flights/nominal.json" in page
