"""An optional height reference in the 3-D input (``bagio.height_input``, ``read_ins3d(...,
height=HeightSpec(topic))``): the messages it reads (NavSatFix, FluidPressure, PointStamped)
decoded as rosbags serializes them, the ISA pressure altitude, the height row's known answer
(interpolated at the reference stamps, offset by the datum), and every bad message dropped and
counted in the input section -- a bad topic is one BagError line."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio import BagError, cdr, get_typestore
from flight_fdi.bagio.height_input import HeightSpec, dh_dp, isa_pressure, pressure_altitude
from flight_fdi.bagio.ins3d_input import input_section3d, read_ins3d
from flight_fdi.bagio.ins3d_payloads import height_payloads
from flight_fdi.bagio.writer import open_writer
from flight_fdi.core.ins3d.data import interpolate_height

EPOCH = 1_700_000_000 * 10**9


def _header(T, stamp_ns: int, frame: str):
    return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
        sec=int(stamp_ns // 10**9), nanosec=int(stamp_ns % 10**9)), frame_id=frame)


@pytest.mark.parametrize("little", [True, False])
def test_height_messages_decode_as_rosbags_serializes_them(little):
    store = get_typestore()
    T = store.types
    rng = np.random.default_rng(5)
    frames = ["", "b", "baro", "x" * 7, "ü" * 3]
    stamps = EPOCH + np.arange(len(frames)) * 10**8 + 7
    fp, pt, fix, want_status, want_kind = [], [], [], [], []
    v = rng.normal(size=(len(frames), 12))
    for k, frame in enumerate(frames):
        h = _header(T, int(stamps[k]), frame)
        fp.append(bytes(store.serialize_cdr(T[cdr.FLUID_PRESSURE](
            header=h, fluid_pressure=v[k, 0], variance=v[k, 1]), cdr.FLUID_PRESSURE,
            little_endian=little)))
        pt.append(bytes(store.serialize_cdr(T[cdr.POINT_STAMPED](
            header=h, point=T["geometry_msgs/msg/Point"](*v[k, :3])), cdr.POINT_STAMPED,
            little_endian=little)))
        status, kind = (-1, 0, 1, 2, 2)[k], (0, 1, 2, 3, 0)[k]
        fix.append(bytes(store.serialize_cdr(T[cdr.NAVSATFIX](
            header=h, status=T["sensor_msgs/msg/NavSatStatus"](status=status, service=4),
            latitude=v[k, 0], longitude=v[k, 1], altitude=v[k, 2],
            position_covariance=v[k, 3:12], position_covariance_type=kind), cdr.NAVSATFIX,
            little_endian=little)))
        want_status.append(status)
        want_kind.append(kind)
    s, vals = cdr.decode_doubles(cdr.FLUID_PRESSURE, fp, (0, 1))
    np.testing.assert_array_equal(s, stamps)
    np.testing.assert_array_equal(vals, v[:, :2])
    _, vals = cdr.decode_doubles(cdr.POINT_STAMPED, pt, (0, 1, 2))
    np.testing.assert_array_equal(vals, v[:, :3])
    _, vals = cdr.decode_doubles(cdr.NAVSATFIX, fix, range(12))
    np.testing.assert_array_equal(vals, v)
    status, kind = cdr.decode_navsatfix_flags(fix)
    assert status.tolist() == want_status and kind.tolist() == want_kind
    with pytest.raises(BagError, match="#1: .* too short"):
        cdr.decode_navsatfix_flags([fix[0], fix[1][:-1]])
    if little:   # the writer's messages are rosbags' (little endian), byte for byte
        got = height_payloads(cdr.FLUID_PRESSURE, stamps[:1], "baro", np.array([500.0]), 0.25)
        p = float(isa_pressure(500.0))
        ref = T[cdr.FLUID_PRESSURE](header=_header(T, int(stamps[0]), "baro"), fluid_pressure=p,
                                    variance=0.25 / float(dh_dp(p)) ** 2)
        assert got[0] == bytes(store.serialize_cdr(ref, cdr.FLUID_PRESSURE))
        got = height_payloads(cdr.POINT_STAMPED, stamps[:1], "baro", np.array([12.5]), 0.0)
        ref = T[cdr.POINT_STAMPED](header=_header(T, int(stamps[0]), "baro"),
                                   point=T["geometry_msgs/msg/Point"](0.0, 0.0, 12.5))
        assert got[0] == bytes(store.serialize_cdr(ref, cdr.POINT_STAMPED))


def test_isa_pressure_altitude_known_answers():
    # the ICAO standard atmosphere table: 101325 Pa at 0 m, 89874.6 Pa at 1 km, 22632.1 at 11 km
    np.testing.assert_allclose(isa_pressure([0.0, 1000.0, 11000.0]),
                               [101325.0, 89874.6, 22632.1], atol=0.05)
    h = np.array([-300.0, 0.0, 2500.0, 10000.0])
    np.testing.assert_allclose(pressure_altitude(isa_pressure(h)), h, atol=1e-8)
    p = isa_pressure(h)
    fd = (pressure_altitude(p + 0.5) - pressure_altitude(p - 0.5)) / 1.0
    np.testing.assert_allclose(dh_dp(p), fd, rtol=1e-6)
    assert np.isnan(pressure_altitude([0.0, -5.0, np.nan])).all()


def test_interpolation_between_samples_exact_stamps_and_gaps():
    t_h = np.array([0.0, 1.0, 2.0, 6.0])
    h, r = np.array([10.0, 12.0, 11.0, 0.0]), np.array([1.0, 3.0, 1.0, 1.0])
    hz, rz, ok = interpolate_height(np.array([-0.5, 0.0, 0.25, 1.0, 1.5, 4.0, 6.0, 6.5]), t_h, h, r,
                             max_gap=2.0)
    assert ok.tolist() == [False, True, True, True, True, False, True, False]
    np.testing.assert_allclose(hz[ok], [10.0, 10.5, 12.0, 11.5, 0.0])
    np.testing.assert_allclose(rz[ok], [1.0, 1.5, 3.0, 2.0, 1.0])


@pytest.fixture(scope="module")
def flight():
    """A 60-s simulated 3-D flight (navigation grade, baro INS)."""
    from flight_fdi.sim.ins3d import Sim3DConfig, simulate3d
    from flight_fdi.sim.trajectory import TrajectoryConfig
    return simulate3d(Sim3DConfig(trajectory=TrajectoryConfig(profile="cruise_turns",
                                                              duration_s=60.0, seed=2), seed=2))


def _bag(path, flight, height: tuple | None):
    """The flight's contract topics (IMU, velocity 20 Hz, fix 5 Hz, reference 10 Hz) and
    ``height`` = (topic, type, receive-order stamps ns, payloads)."""
    from flight_fdi.sim.bag3d import encode_topics
    series = encode_topics(flight, 20.0, 20.0, 5.0, 1.0, EPOCH // 10**9)
    if height is not None:
        series.append(height)
    with open_writer(path, storage="mcap") as bag:
        bag.write_series(series)
    return path


def _expected_z(flight, t_r, h_ref_at, t_first):
    """h_INS(t) - h_ref(t) - offset, the INS height interpolated from the 5-Hz /ins/fix."""
    t_fix, h_fix = flight.t[::20], flight.ins.h[::20]
    offset = np.interp(t_first, t_fix, h_fix) - h_ref_at(t_first)
    return np.interp(t_r, t_fix, h_fix) - h_ref_at(t_r) - offset


def test_the_height_row_known_answer_between_samples(flight, tmp_path):
    """PointStamped heights at 10 Hz, 0.05 s after the reference stamps, linear in time: the
    row is h_INS - h_ref, the reference offset to the INS height at its first sample (datum
    first), and the configured variance white^2 + Markov^2."""
    t_h = 0.05 + np.arange(0, 599) / 10.0
    h_of = lambda t: 3200.0 + 2.0 * t           # noqa: E731 (linear: interpolation is exact)
    stamps = EPOCH + np.round(t_h * 1e9).astype(np.int64)
    bag = _bag(tmp_path / "b", flight, ("/baro", cdr.POINT_STAMPED, stamps, height_payloads(
        cdr.POINT_STAMPED, stamps, "baro", h_of(t_h), 0.0)))
    spec = HeightSpec("/baro", sigma=0.2, markov=(0.3, 4.0))
    inp = read_ins3d(bag, height=spec)
    t_r = inp.refs.t
    assert t_r[0] > t_h[0] and t_r[-1] <= t_h[-1] and t_r.size == 598   # 0.1 .. 59.8 s
    np.testing.assert_allclose(inp.refs.z[:, 2], _expected_z(flight, t_r, h_of, t_h[0]),
                               atol=1e-9)
    np.testing.assert_allclose(inp.refs.r[:, 2], 0.2**2 + 0.3**2)
    assert inp.height.h0_sigma == pytest.approx(np.hypot(0.2, 0.3))
    plain = read_ins3d(bag)
    np.testing.assert_array_equal(inp.refs.z[:, :2], plain.refs.z[:598, :2])
    sec = input_section3d(inp)
    assert sec["/reference/velocity"]["dropped"] == {"outside_imu_record": 1, "no_height": 2}
    assert sec["/reference/velocity"]["used"] == 598
    assert sec["/baro"]["used"] == 599 and sec["/baro"]["variance"] == {
        "message": 0, "configured": 599}
    absolute = read_ins3d(bag, height=HeightSpec("/baro", datum="absolute"))
    assert absolute.height.offset_m == 0.0 and absolute.height.h0_sigma is None
    np.testing.assert_allclose(absolute.refs.z[:, 2] - inp.refs.z[:, 2], inp.height.offset_m,
                               atol=1e-9)
    opts = inp.height.options((0.02, 0.03, 30.0))
    assert opts == {"rows": 3, "position": True, "height_row": True, "v0_sigma_up": 1.0,
                    "h0_sigma": inp.height.h0_sigma, "ref_markov": (0.02, 0.3, 30.0, 4.0)}


def test_bad_height_messages_are_dropped_and_counted(flight, tmp_path):
    """NavSatFix heights at the reference stamps, in receive order: a NaN, a zero stamp, a
    repeated stamp, one 20 s late (beyond the reorder window), two swapped (sorted), a NO_FIX,
    3 s missing (the reference rows there lose their height), variances known and unknown."""
    t_h = np.arange(0, 601) / 10.0
    h = 3000.0 + 0.5 * np.sin(t_h / 7.0)
    var = np.full(t_h.size, 0.09)
    kind = np.full(t_h.size, 2)
    kind[::3] = 0                                   # UNKNOWN: the configured variance
    status = np.zeros(t_h.size, dtype=int)
    status[100] = -1                                # NO_FIX
    h[50] = np.nan
    gap = (t_h > 30.0) & (t_h < 33.05)              # 30.1 .. 33.0 s missing
    stamps = EPOCH + np.round(t_h * 1e9).astype(np.int64)
    stamps[60] = 0
    msgs = [cdr.encode_navsatfix(stamps[k:k + 1], "baro", int(status[k]), 1,
                                 np.array([[45.0, 7.0, h[k]]]), np.r_[np.ones(8), var[k]],
                                 int(kind[k]))[0] for k in range(t_h.size)]
    order = [k for k in range(t_h.size) if not gap[k]]
    i = order.index(200)
    order[i], order[i + 1] = order[i + 1], order[i]            # shuffled: sorted
    order.insert(order.index(70) + 1, 70)                      # repeated stamp
    order.insert(order.index(500) + 1, 70)                     # 43 s late: out of order
    payloads = [msgs[k] for k in order]
    receive = EPOCH + np.arange(len(order)) * 10**8            # the order written
    bag = _bag(tmp_path / "bad", flight, ("/fix_h", cdr.NAVSATFIX, receive, payloads))
    inp = read_ins3d(bag, height=HeightSpec("/fix_h", sigma=0.1, markov=None))
    sec = input_section3d(inp)["/fix_h"]
    assert sec["messages"] == len(order)
    assert sec["dropped"] == {"non_finite": 1, "zero_stamp": 1, "out_of_order": 1,
                              "duplicate_stamp": 1, "no_fix": 1, "outside_imu_record": 1}
    assert sec["reordered"] == 2 and sec["used"] == len(order) - 6
    ref = input_section3d(inp)["/reference/velocity"]
    # the reference rows without a height within 2 s: none (the gap is 3 s but the samples
    # around it are 3.1 s apart: every row in it is refused)
    assert ref["dropped"]["no_height"] == int(np.sum((t_h > 30.0) & (t_h < 33.1)))
    good = np.isfinite(h) & (status == 0) & ~gap & (stamps != 0)
    good[0] = False                                 # before the first IMU message
    assert sec["variance"]["message"] == int(np.sum(good & (kind == 2)))
    h_of = lambda t: np.interp(t, t_h[good], h[good])   # noqa: E731
    np.testing.assert_allclose(inp.refs.z[:, 2], _expected_z(flight, inp.refs.t, h_of, 0.1),
                               atol=1e-9)
    on_sample = np.isin(np.round(inp.refs.t * 10).astype(int), np.flatnonzero(good))
    expect_r = np.where(kind[np.round(inp.refs.t * 10).astype(int)] == 2, 0.09, 0.01)
    np.testing.assert_allclose(inp.refs.r[on_sample, 2], expect_r[on_sample])


def test_a_bad_height_topic_is_one_bag_error(flight, tmp_path):
    t_h = np.arange(0, 601) / 10.0
    stamps = EPOCH + np.round(t_h * 1e9).astype(np.int64)
    nan = height_payloads(cdr.POINT_STAMPED, stamps, "baro", np.full(t_h.size, np.nan), 0.0)
    bag = _bag(tmp_path / "nan", flight, ("/h", cdr.POINT_STAMPED, stamps, nan))
    for spec, needle in ((HeightSpec("/nope"), r"no height topic /nope \(topics: "),
                         (HeightSpec("/sim/truth"), "carries flight_fdi_msgs/msg/FilterState, "
                                                    "expected a height"),
                         (HeightSpec("/ins/fix"), "also a contract topic"),
                         (HeightSpec("/h"), "no usable height message inside the IMU record "
                                            r"\(601 messages; dropped: non_finite 601\)")):
        with pytest.raises(BagError, match=needle) as exc:
            read_ins3d(bag, height=spec)
        assert "\n" not in str(exc.value)
    for kw, needle in ((dict(sigma=0.0), "sigma must be a number > 0"),
                       (dict(markov=(0.4, -1.0)), "markov must be None or"),
                       (dict(datum="geoid"), "datum must be one of first, absolute"),
                       (dict(v0_sigma_up=float("nan")), "v0_sigma_up must be")):
        with pytest.raises(BagError, match=needle):
            HeightSpec("/h", **kw)
