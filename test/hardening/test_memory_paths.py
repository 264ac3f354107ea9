"""The memory-bounding paths that the 10-hour analysis takes (``bench/memory_10h.py``) give the
same numbers as the one-piece paths that short flights take.

* ``cdr.decode`` gathers in blocks of messages (the index arrays of one piece are ~100 bytes per
  message); an error still names the message's index in the whole series;
* ``mcapscan`` decompresses every chunk into one buffer (the records are never held twice);
* a record longer than ``GLR_CONCURRENT_MAX_STEPS`` runs GLR before the backward pass instead of
  beside it.

Each is checked bit for bit (the block size or the limit made small) against the other path.
"""
from __future__ import annotations

import numpy as np
import pytest

from flight_fdi.bagio import BagError, cdr


def test_blocked_cdr_decode_equals_one_piece_and_names_the_message(monkeypatch):
    rng = np.random.default_rng(5)
    n = 1000
    stamps = rng.integers(-(10**18), 10**18, n)
    twist = rng.normal(size=(n, 6))
    cov = rng.normal(size=(n, 36))
    frames = ["", "map", "base_link_with_a_longer_name"]
    payloads = []
    for k in range(n):  # frame_ids of different lengths: the doubles move
        payloads += cdr.encode(cdr.TWIST_COV_STAMPED, stamps[k:k + 1], frames[k % 3],
                               twist[k:k + 1], cov[k])
    one = cdr.decode(cdr.TWIST_COV_STAMPED, payloads, twist_cols=[0, 4], cov_cols=[0, 7, 35])
    from flight_fdi.bagio.cdr import series

    monkeypatch.setattr(series, "_BLOCK", 7)
    blocked = cdr.decode(cdr.TWIST_COV_STAMPED, payloads, twist_cols=[0, 4], cov_cols=[0, 7, 35])
    for a, b in zip(one, blocked):
        np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(blocked[0], stamps)
    np.testing.assert_array_equal(blocked[1], twist[:, [0, 4]])
    np.testing.assert_array_equal(blocked[2], cov[:, [0, 7, 35]])
    payloads[523] = payloads[523][:20]
    with pytest.raises(BagError, match="message #523: 20 bytes is too short"):
        cdr.decode(cdr.TWIST_COV_STAMPED, payloads)


def _flight(N: int = 3000, **model_params):
    from flight_fdi.core.kalman import run_forward
    from flight_fdi.core.models import ins_channel

    rng = np.random.default_rng(9)
    t = np.arange(N) * 0.1
    z = rng.normal(0.0, 0.1, (N, 1))
    z[2000:, 0] += 0.002 * (t[2000:] - t[2000])  # a ramp: GLR and the seed method have work
    model = ins_channel(**model_params)
    return model, run_forward(model, t, z)


def test_glr_before_the_backward_pass_gives_the_same_analysis(monkeypatch):
    from flight_fdi.core import analysis

    model, fwd = _flight()
    beside = analysis.analyze_forward(model, fwd)
    monkeypatch.setattr(analysis, "GLR_CONCURRENT_MAX_STEPS", 100)
    before = analysis.analyze_forward(model, fwd)
    assert before.summary == beside.summary
    assert before.summary["post_flight"]["glr"]["hypothesis"] != "none"


def test_single_buffer_mcap_scan_equals_the_generic_reader(tmp_path):
    from flight_fdi.bagio import flight, reader
    from flight_fdi.cli.main import main

    bag = tmp_path / "bag"
    assert main(["simulate", str(bag), "--duration", "60", "--compression", "zstd",
                 "--fault", "ref:outliers:t=10,end=50,mag=3,freq=0.2"]) == 0
    r = reader.open_bag(bag)
    try:
        topics = {flight.INS_TOPIC, flight.REF_TOPIC, flight.TRUTH_TOPIC}
        fast = reader.read_raw(r, bag, topics)
        generic = reader.read_raw_generic(r, bag, topics)
    finally:
        r.close()
    for t in topics:
        np.testing.assert_array_equal(fast[t].log_ns, generic[t].log_ns)
        assert len(fast[t].payloads) == len(generic[t].payloads) > 0
        assert all(fast[t].payloads[i] == generic[t].payloads[i]
                   for i in range(len(fast[t].payloads)))
