"""The input contract of ``flight-fdi analyze``: any topic names, TwistStamped /
TwistWithCovarianceStamped / Odometry for either input, frames, input profiles, redundant
references, every unused sample counted and printed, --fail-on-fault."""
from __future__ import annotations

import json

import numpy as np
import pytest

import craft
from flight_fdi.bagio import BagError, read_flight
from flight_fdi.bagio.inputs import InputSpec, load_profile
from flight_fdi.cli.main import main
from flight_fdi.schema import validate_result

RENAMED = ["--ins-topic", "/xsens/twist", "--reference-topic", "/gps/vel"]


@pytest.fixture(scope="module")
def fault_flight():
    return craft.flight(300.0, ("accel:step:t=150,mag=2mg",))


def _analyze(capsys, bag, *args, rc=0):
    got = main(["analyze", str(bag), "--json", "--jobs", "1", *map(str, args)])
    out, err = capsys.readouterr()
    assert got == rc, err
    res = json.loads(out)
    validate_result(res)
    return res


@pytest.mark.parametrize("ins_type, ref_type", [
    (craft.TWIST, craft.TWIST_COV), (craft.ODOM, craft.TWIST_COV), (craft.TWIST_COV, craft.ODOM),
    (craft.ODOM, craft.TWIST), (craft.TWIST, craft.TWIST)])
def test_renamed_topics_and_every_message_type(tmp_path, capsys, fault_flight, ins_type,
                                               ref_type):
    bag = craft.write(tmp_path / "b", fault_flight, "/xsens/twist", ins_type, ("/gps/vel",),
                      ref_type, yaw_rate=0.01)  # Odometry: body-frame twists of a turning body
    res = _analyze(capsys, bag, *RENAMED)
    f = res["post_flight"]["fault"]
    assert (f["sensor"], f["kind"], f["axis"]) == ("accelerometer", "step", "x")
    assert abs(f["onset_s"] - 150.0) < 3.0 and f["magnitude_eng"] == pytest.approx(2.0, rel=0.1)
    assert set(res["input"]) == {"/xsens/twist", "/gps/vel"}
    assert res["input"]["/xsens/twist"]["type"] == ins_type
    assert res["input"]["/gps/vel"]["type"] == ref_type
    assert res["source"]["ins_topic"] == "/xsens/twist"
    if ref_type == craft.TWIST:
        assert res["input"]["/gps/vel"]["covariance"].startswith("model R")
    # the same velocities in another type give the same statistic (Odometry: after rotation)
    ref = craft.write(tmp_path / "ref", fault_flight, "/xsens/twist", craft.TWIST, ("/gps/vel",),
                      craft.TWIST_COV)
    base = _analyze(capsys, ref, *RENAMED)
    if ref_type != craft.TWIST:  # (TwistStamped: the model's R = the simulated variance too)
        assert f["statistic"] == pytest.approx(base["post_flight"]["fault"]["statistic"],
                                               rel=1e-6)


def test_default_topics_missing_is_one_line_naming_the_options(tmp_path, capsys, fault_flight):
    bag = craft.write(tmp_path / "b", fault_flight, "/xsens/twist", craft.TWIST, ("/gps/vel",))
    assert main(["analyze", str(bag)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "no messages on /ins/velocity" in err[0]
    assert "/gps/vel, /xsens/twist" in err[0] and "--ins-topic" in err[0]


def test_odometry_child_frame_is_rotated_and_header_frame_is_not(tmp_path, fault_flight):
    bag = craft.write(tmp_path / "b", fault_flight, "/odom", craft.ODOM, ("/gps/vel",),
                      yaw_rate=0.02)
    rotated = read_flight(bag, spec=InputSpec(ins_topic="/odom", reference_topics=("/gps/vel",)))
    np.testing.assert_allclose(rotated.v_ins, fault_flight.v_ins[:, 0], atol=1e-9)
    assert "rotated into 'map'" in rotated.series[0].frame
    as_is = read_flight(bag, spec=InputSpec(ins_topic="/odom", reference_topics=("/gps/vel",),
                                            odometry_twist_frame="header"))
    assert np.max(np.abs(as_is.v_ins - fault_flight.v_ins[:, 0])) > 1.0
    assert "odometry_twist_frame: header" in as_is.series[0].frame


def test_nav_frame_maps_channel_names_to_axes(tmp_path, fault_flight):
    bag = craft.write(tmp_path / "b", fault_flight)
    for frame, name, col in (("enu", "east", 0), ("enu", "north", 1), ("ned", "north", 0),
                             ("ned", "east", 1)):
        d = read_flight(bag, spec=InputSpec(nav_frame=frame, channel=name))
        assert d.channel == "xy"[col]
        np.testing.assert_array_equal(d.v_ins, fault_flight.v_ins[:, col])
    with pytest.raises(BagError, match="channel must be one of x, y, north, east .ned."):
        InputSpec(nav_frame="ned", channel="up")


def test_input_profiles(tmp_path, capsys, fault_flight, repo_root):
    bag = craft.write(tmp_path / "b", fault_flight, "/xsens/twist", craft.ODOM,
                      ("/gps1/vel", "/gps2/vel"), yaw_rate=0.01)
    prof = tmp_path / "p.yaml"
    prof.write_text("ins_topic: /xsens/twist\nreference_topics: [/gps1/vel, /gps2/vel]\n"
                    "nav_frame: ned\nchannel: north\n")
    res = _analyze(capsys, bag, "--input-profile", prof)
    assert res["source"]["nav_frame"] == "ned" and res["channel"] == "x"
    # (both references carry the same noise here, so their merged variance is too small:
    # the isolation may then call the fit unexplained; the best hypothesis is the true one)
    assert res["post_flight"]["glr"]["hypothesis"] == "accel_bias_step"
    # redundant references with the same stamps: merged, every sample of both used
    assert res["input"]["/gps1/vel"]["used"] == res["input"]["/gps2/vel"]["used"] \
        == res["samples"]
    # options win over the profile
    other = _analyze(capsys, bag, "--input-profile", prof, "--channel", "east")
    assert other["channel"] == "y" and other["post_flight"]["glr"]["hypothesis"] == "none"
    # the shipped profiles load, and the sample bags' one reads the sample bags
    for p in sorted((repo_root / "config" / "inputs").glob("*.yaml")):
        InputSpec(**load_profile(p))
    nominal = _analyze(capsys, repo_root / "bags" / "nominal", "--input-profile",
                       repo_root / "config" / "inputs" / "sample_bags.yaml")
    assert nominal["post_flight"]["verdict"] == "no_fault"
    prof.write_text("ins_topic: /a\nbogus: 1\n")
    assert main(["analyze", str(bag), "--input-profile", str(prof)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "unknown key 'bogus'" in err[0]


def _bad_inputs_bag(path, fl):
    """Reference: 4 NaN, 3 repeated stamps, 2 zero stamps, 1 stamp 100 s late, 6 shuffled,
    5 invalid covariances (NaN), 10 before the INS record, 31 in a 3-s INS gap."""
    t_ref = fl.stamp_ref_ns.copy()
    v_ref = fl.v_ref.copy()
    v_ref[[100, 200, 300, 400], 0] = np.nan
    t_ref[[501, 601, 701]] = t_ref[[500, 600, 700]]
    t_ref[[800, 900]] = 0
    t_ref[1000] -= 100 * 10**9
    for a in (1100, 1102, 1104):
        t_ref[[a, a + 1]] = t_ref[[a + 1, a]]
    keep = (fl.t < 200.0) | (fl.t > 203.0)
    keep &= fl.t >= 1.0
    ins_stamps = np.where(keep, fl.stamp_ns, 0)  # stamp 0: dropped (zero_stamp), a gap
    var = np.full(t_ref.size, fl.sigma_ref ** 2)
    var[[1500, 1600, 1700, 1800, 1900]] = np.nan
    bag = craft.write(path, fl, ref_stamps=t_ref, ref_values=v_ref, ins_stamps=ins_stamps,
                      ref_var=var)
    return bag


def test_every_dropped_sample_is_counted_and_printed(tmp_path, capsys):
    fl = craft.flight(300.0, seed=4)
    bag = _bad_inputs_bag(tmp_path / "bad", fl)
    res = _analyze(capsys, bag)
    ins, ref = res["input"]["/ins/velocity"], res["input"]["/reference/velocity"]
    n_zero_ins = int(((fl.t >= 200.0) & (fl.t <= 203.0)).sum() + (fl.t < 1.0).sum())
    assert ins["dropped"] == {"non_finite": 0, "zero_stamp": n_zero_ins, "duplicate_stamp": 0,
                              "out_of_order": 0}
    d = ref["dropped"]
    assert d["non_finite"] == 4 and d["duplicate_stamp"] == 3 and d["zero_stamp"] == 2
    assert d["out_of_order"] == 1 and ref["reordered"] == 6
    assert d["outside_ins_record"] == 10  # reference stamps 0.0 .. 0.9 s, INS from 1.0 s
    assert d["ins_gap"] == 31 and d["invalid_covariance_replaced"] == 5  # 200.0 .. 203.0 s
    assert ref["used"] + sum(v for k, v in d.items() if k != "invalid_covariance_replaced") \
        == ref["messages"]
    assert main(["analyze", str(bag), "--jobs", "1"]) == 0
    out = capsys.readouterr().out
    warn = [ln for ln in out.splitlines() if ln.startswith("warning: ")]
    assert any("/ins/velocity" in w and "header stamp 0" in w for w in warn)
    for what in ("non-finite", "repeated header stamp", "header stamp 0",
                 "older than the reorder window", "outside the INS record", "INS gap",
                 "sorted by header stamp", "invalid covariance"):
        assert sum(what in w and "/reference/velocity" in w for w in warn) == 1, what


def test_fail_on_fault_exit_status(capsys, repo_root):
    assert main(["analyze", str(repo_root / "bags" / "accel_fault_500s"), "--fail-on-fault"]) \
        == 3
    assert main(["analyze", str(repo_root / "bags" / "nominal"), "--fail-on-fault"]) == 0
    assert main(["analyze", str(repo_root / "bags" / "accel_fault_500s")]) == 0
    capsys.readouterr()
