"""What ``flight-fdi run --model ins3d`` checks before any node exists
(``bagio.ins3d_input.check_topics`` / ``check_messages``):

* the contract topics and their types from the bag's metadata.yaml (bagio's reader, no rosbags
  Reader: ~1 ms instead of ~0.03 s), with the messages of before -- the same as rosbags' listing
  gives for a bag it has to open (a lone .mcap file);
* every message of the contract topics, read raw by bagio's reader: a corrupt bag is one line
  and nothing is made (before: the player's rosbags iterator replayed what it made of it -- on a
  400-s bag with 5000 bytes overwritten, 18 891 of 22 003 messages with no error and values that
  crashed the filter with a traceback; on this 30-s bag, an ERROR log line, the recording made,
  then the error);
* the counts for the progress lines and the player's window are those messages.
"""
from __future__ import annotations

import shutil
from pathlib import Path

import harness  # noqa: F401  (private ROS domain)
import pytest

from flight_fdi.bagio.errors import BagError
from flight_fdi.bagio.ins3d_input import TOPICS, check_topics
from flight_fdi.cli.main import main

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def flight3d(tmp_path_factory) -> Path:
    """A 30-s 3-D flight (600 IMU, 601 INS velocity, 151 fix, 301 reference messages)."""
    path = tmp_path_factory.mktemp("check3d") / "flight"
    assert main(["simulate", str(path), "--model", "ins3d", "--duration", "30", "--seed",
                 "3"]) == 0
    return path


@pytest.fixture
def no_rosbags_reader(monkeypatch):
    """rosbags' Reader refuses to open anything (what must not need it, does not)."""
    from rosbags.rosbag2 import Reader

    def refuse(self):
        raise AssertionError("rosbags' Reader was opened")

    monkeypatch.setattr(Reader, "open", refuse)


def test_the_topics_are_checked_from_the_metadata(flight3d, no_rosbags_reader):
    assert check_topics(flight3d) == TOPICS
    assert check_topics(flight3d, {"ins_imu": "/ins/imu"}) == TOPICS
    with pytest.raises(BagError) as err:
        check_topics(flight3d, {"ins_imu": "/sim/fault"})
    assert str(err.value) == (f"bag '{flight3d}': /sim/fault carries std_msgs/msg/String, "
                              "expected sensor_msgs/msg/Imu")
    with pytest.raises(BagError) as err:
        check_topics(REPO / "bags" / "nominal")
    assert "no topic /ins/imu, /ins/fix (topics: " in str(err.value)
    assert str(err.value).endswith("-- a single-axis bag? --model ins3d needs the 3-D contract "
                                   "(docs/sim3d.md)")


def test_the_same_messages_where_rosbags_lists_the_topics(flight3d, tmp_path):
    """A lone .mcap file (no metadata.yaml): rosbags' listing, the same checks and lines."""
    (mcap,) = flight3d.glob("*.mcap")
    lone = tmp_path / "lone.mcap"
    shutil.copy(mcap, lone)
    assert check_topics(lone) == TOPICS
    for bag in (flight3d, lone):
        with pytest.raises(BagError) as err:
            check_topics(bag, {"ref_velocity": "/ins/velocity"})
        assert str(err.value).startswith("the ins3d input topics must be distinct")
        with pytest.raises(BagError) as err:
            check_topics(bag, {"ins_fix": "/nope"})
        assert str(err.value).startswith(f"bag '{bag}': no topic /nope (topics: /ins/fix, ")
    with pytest.raises(BagError) as err:
        check_topics(tmp_path / "none")
    assert str(err.value) == f"bag '{tmp_path / 'none'}' does not exist"


def test_check_messages_counts_every_message(flight3d, no_rosbags_reader):
    import yaml

    from flight_fdi.bagio.ins3d_input import check_messages

    names, counts = check_messages(flight3d)
    assert names == TOPICS
    meta = yaml.safe_load((flight3d / "metadata.yaml").read_text())
    listed = {t["topic_metadata"]["name"]: t["message_count"]
              for t in meta["rosbag2_bagfile_information"]["topics_with_message_count"]}
    assert counts == {t: listed[t] for t in TOPICS.values()}
    assert counts["/reference/velocity"] == 301 and counts["/ins/imu"] == 600


@pytest.mark.timeout(300)
def test_a_corrupt_bag_is_one_line_before_anything(flight3d, tmp_path, capfd):
    bad = tmp_path / "bad"
    shutil.copytree(flight3d, bad)
    (mcap,) = bad.glob("*.mcap")
    data = bytearray(mcap.read_bytes())
    middle = len(data) // 2
    data[middle:middle + 2000] = b"\x55" * 2000     # inside the compressed data
    mcap.write_bytes(bytes(data))
    out = tmp_path / "out"
    code = main(["run", str(bad), "--model", "ins3d", "--out", str(out), "--no-progress",
                 "--no-report"])
    err = capfd.readouterr().err
    assert code == 1
    assert err.count("\n") == 1 and err.startswith(f"flight-fdi run: error: bag '{bad}': ")
    assert "corrupt" in err and "Traceback" not in err
    assert not out.exists()    # no node, no recording
