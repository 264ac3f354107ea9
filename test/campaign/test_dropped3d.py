"""The dropped samples of a 3-D flight: what the 3-D input leaves out (references outside the IMU
record, ``bagio.ins3d_input.input_section3d``) in the result's ``input`` section, and so in
``batch``'s summary.csv (``dropped_samples``, empty for 3-D flights before)."""
from __future__ import annotations

import csv

import pytest
import yaml

from flight_fdi.campaign.summary import summary_row
from flight_fdi.cli.main import main


@pytest.fixture(scope="module")
def bag3d(tmp_path_factory):
    """A 30-s 3-D flight: 600 IMU messages from 0.05 s, 301 references from 0 s."""
    path = tmp_path_factory.mktemp("dropped3d") / "flight"
    assert main(["simulate", str(path), "--model", "ins3d", "--duration", "30", "--seed",
                 "3"]) == 0
    return path


def test_the_3d_input_counts_the_references_it_leaves_out(bag3d):
    from flight_fdi.bagio.ins3d_input import (TOPICS, TYPES, Ins3dInput, input_section3d,
                                              read_ins3d)

    meta = yaml.safe_load((bag3d / "metadata.yaml").read_text())["rosbag2_bagfile_information"]
    counts = {t["topic_metadata"]["name"]: t["message_count"]
              for t in meta["topics_with_message_count"]}
    inp = read_ins3d(bag3d)
    section = input_section3d(inp)
    assert set(section) == set(TOPICS.values())
    for role, topic in TOPICS.items():
        entry = section[topic]
        assert (entry["role"], entry["type"], entry["messages"]) == \
            (role, TYPES[role], counts[topic])
    ref = section["/reference/velocity"]
    assert ref["used"] == inp.refs.t.size == counts["/reference/velocity"] - 1
    assert ref["dropped"] == {"outside_imu_record": 1}   # the reference at 0 s
    assert all(section[t]["dropped"] == {} and section[t]["used"] == counts[t]
               for t in ("/ins/imu", "/ins/velocity", "/ins/fix"))
    # the summary row's dropped_samples: the sum over the section, as for single-axis results
    row = summary_row("f", {"post_flight": {"verdict": "no_fault", "fault": None},
                            "input": section})
    assert row["dropped_samples"] == 1
    # an input not read from a bag has no section
    assert input_section3d(Ins3dInput(inp.steps, inp.refs, inp.q)) is None


def test_batch_fills_dropped_samples_for_3d_flights(bag3d, tmp_path, capsys):
    """batch's summary.csv counts the dropped reference (before: empty for 3-D flights), and
    the flight's result is still analyze --json's, schema-valid with its input section."""
    import json

    from flight_fdi.bagio.ins3d_input import input_section3d, read_ins3d
    from flight_fdi.schema import validate_result

    out = tmp_path / "out"
    assert main(["batch", str(bag3d), "--out", str(out), "--model", "ins3d", "--workers", "1",
                 "--no-progress", "--json"]) == 0
    with open(out / "summary.csv", newline="") as f:
        (row,) = list(csv.DictReader(f))
    assert row["error"] == "" and row["dropped_samples"] == "1"
    (flight,) = (out / "flights").glob("*.json")
    result = json.loads(flight.read_text())
    assert result["input"] == input_section3d(read_ins3d(bag3d))
    validate_result(result)
    capsys.readouterr()
    assert main(["analyze", str(bag3d.resolve()), "--model", "ins3d", "--json", "--jobs",
                 "1"]) == 0
    assert json.loads(capsys.readouterr().out) == result


def test_the_schema_knows_every_role_and_drop_reason():
    """The result schema's ``topic_input`` accepts the roles and drop reasons of both input
    sections (single-axis and 3-D), and nothing else."""
    from flight_fdi.bagio.inputs import DROP_REASONS
    from flight_fdi.bagio.ins3d_input import DROP_REASONS3D, TOPICS
    from flight_fdi.schema import load

    entry = load()["$defs"]["topic_input"]["properties"]
    assert set(entry["role"]["enum"]) == {"ins", "reference", *TOPICS}
    assert set(entry["dropped"]["propertyNames"]["enum"]) == {*DROP_REASONS, *DROP_REASONS3D}
