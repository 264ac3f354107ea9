"""The streaming assembler with a height reference (``Ins3dAssembler(height=HeightRule(...))``,
what filter_node's ins3d mode runs with ``ins3d_height_topic``) against the bag reader
(``read_ins3d(..., height=HeightSpec(...))``): the same rows bit for bit -- heights between the
reference stamps, a gap longer than the rule's (those rows dropped), a sample before the IMU
record, the datum offset and prior -- also when the heights arrive late."""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio import cdr
from flight_fdi.bagio.height_input import HeightSpec, decode_height
from flight_fdi.bagio.ins3d_input import read_ins3d
from flight_fdi.bagio.ins3d_payloads import height_payloads
from flight_fdi.bagio.writer import open_writer
from flight_fdi.core.ins3d.stream import HEIGHT, HeightRule, Ins3dAssembler
from flight_fdi.sim.bag3d import encode_topics

from .streams import T0_NS, assert_rows_are, flight, topic_messages

SPEC = HeightSpec("/baro", sigma=0.1, markov=(0.3, 4.0))


@pytest.fixture(scope="module")
def data(tmp_path_factory):
    """A 60-s flight's contract messages and heights (10 Hz, 0.03 s after the reference
    stamps, two before the IMU record, none over 20.0-23.0 s, known variances on every other
    one) -- as messages and as a bag read by ``read_ins3d``."""
    fl = flight(60.0, 4)
    t_h = np.concatenate([[0.01], 0.03 + np.arange(600) / 10.0])
    t_h = t_h[(t_h < 20.0) | (t_h > 23.0)]
    h = 3000.0 + 0.3 * t_h + np.sin(t_h)
    var = np.where(np.arange(t_h.size) % 2 == 0, 0.2, 0.0)        # 0: unknown
    stamps = T0_NS + np.round(t_h * 1e9).astype(np.int64)
    payloads = height_payloads(cdr.FLUID_PRESSURE, stamps, "baro", h, var)
    bag = tmp_path_factory.mktemp("hstream") / "b"
    series = encode_topics(fl, 20.0, 20.0, 5.0, 1.0, T0_NS // 10**9)
    with open_writer(bag, storage="mcap") as w:
        w.write_series(series + [("/baro", cdr.FLUID_PRESSURE, stamps, payloads)])
    inp = read_ins3d(bag, height=SPEC)
    # the heights as the bag gives them (through the pressure): decoded as the node does
    _, h_dec, var_dec, _ = decode_height(cdr.FLUID_PRESSURE, payloads, "baro")
    heights = [(int(s), HEIGHT, (float(a), float(b))) for s, a, b in zip(stamps, h_dec, var_dec)]
    return topic_messages(fl), heights, inp


@pytest.mark.parametrize("delay_s", [0.0, 0.6])
def test_the_height_rows_equal_the_bag_readers(data, delay_s):
    msgs, heights, inp = data
    stream = sorted([(ns, 0, k, v) for ns, k, v in msgs]
                    + [(ns + int(delay_s * 1e9), 1, k, v) for ns, k, v in heights],
                    key=lambda e: e[:2])
    asm = Ins3dAssembler(wait_s=1.0, height=HeightRule(SPEC.max_gap_s, True, SPEC.variance()))
    events = []
    for arrival, _, key, vals in stream:
        ns = arrival - (int(delay_s * 1e9) if key == HEIGHT else 0)
        got = asm.add(key, ns, *vals)
        assert not isinstance(got, str), got
        events += got
    events += asm.finish()
    assert_rows_are(events, inp.refs)
    hi = inp.height
    assert asm.offset == hi.offset_m and asm.h0_sigma == hi.h0_sigma == pytest.approx(
        np.sqrt(0.2))                          # the first sample in the record: a known one
    # 20.0 .. 23.0 s (no pair within 2 s), 0.1 s (before the first height in the record) and
    # 60.0 s (after the last)
    assert asm.no_height == hi.ref_no_height == 33
    assert asm.height_outside == hi.dropped["outside_imu_record"] == 2   # 0.01, 0.03 s
    assert asm.height_from_message == hi.from_message
    assert asm.late == 0
