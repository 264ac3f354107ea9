"""bagio.mcapscan: one walk of the MCAP records (``_records``) for the data section, the
channel records in a chunk and a chunk without message indexes; the messages of the latter are
located in that one walk and their heads read with numpy (as those of an indexed chunk).

Checked against the independent ``mcap`` library (indexed and not, several chunks, an
empty payload), and on corrupt chunks: a message record shorter than its head (22 bytes) is
one line (before: read as a negative payload length), a record overrunning the chunk too.
"""
from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest

from flight_fdi.bagio import cdr, mcapscan
from flight_fdi.bagio.errors import BagError


def _write(path: Path, indexed: bool, n: int = 500, compressed: bool = True) -> None:
    from mcap.writer import CompressionType, IndexType, Writer

    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=3000, index_types=IndexType.ALL if indexed else IndexType.NONE,
                   compression=CompressionType.ZSTD if compressed else CompressionType.NONE)
        w.start(profile="ros2", library="test")
        sid = w.register_schema(name=cdr.TWIST_STAMPED, encoding="ros2msg", data=b"")
        chans = [w.register_channel(topic=t, message_encoding="cdr", schema_id=sid)
                 for t in ("/a", "/b", "/c")]
        for i in range(n):
            data = b"" if i == 7 else cdr.encode(cdr.TWIST_STAMPED, np.array([i]), "f" * (i % 4),
                                                 np.full((1, 6), float(i)))[0]
            # receive times not in file order on /b: sorted by the scanner (ties in file order)
            log = 5000 - i if i % 3 == 1 else 1000 + i // 2
            w.add_message(channel_id=chans[i % 3], log_time=log, publish_time=0, data=data,
                          sequence=i)
        w.finish()


def _library(path: Path) -> dict[str, list]:
    from mcap.reader import make_reader

    want: dict[str, list] = {}
    with open(path, "rb") as fh:
        for _, channel, message in make_reader(fh).iter_messages(log_time_order=True):
            want.setdefault(channel.topic, []).append((message.log_time, bytes(message.data)))
    return want


def test_records_walks_every_record_in_order():
    recs = b"".join(bytes([op]) + struct.pack("<Q", len(body)) + body
                    for op, body in ((4, b"abc"), (5, b""), (9, b"x" * 20)))
    assert list(mcapscan._records(recs, 0, len(recs))) == [(4, 9, 12), (5, 21, 21),
                                                            (9, 30, 50)]
    # the last one overruns a shorter end: yielded as it is, the caller decides
    assert list(mcapscan._records(recs, 0, 40))[-1] == (9, 30, 50)


@pytest.mark.parametrize("indexed", [True, False])
def test_the_scan_equals_the_mcap_library(tmp_path, indexed):
    path = tmp_path / "f.mcap"
    _write(path, indexed)
    got = mcapscan.scan(str(path), {"/a", "/b", "/absent"}, "f")
    want = _library(path)
    for topic in ("/a", "/b"):
        m = got[topic]
        assert m.log_ns.tolist() == [t for t, _ in want[topic]]
        assert [bytes(m.payloads[i]) for i in range(len(m.log_ns))] == [d for _, d in want[topic]]
    assert len(got["/absent"].log_ns) == 0 and b"" in [d for _, d in want["/b"]]


def _first_message(data: bytearray) -> int:
    """Offset of the first message record inside the (uncompressed) first chunk."""
    pos = 8
    while data[pos] != mcapscan.OP_CHUNK:
        pos += 9 + struct.unpack_from("<Q", data, pos + 1)[0]
    comp_len = struct.unpack_from("<I", data, pos + 9 + 28)[0]
    at = pos + 9 + 32 + comp_len + 8          # the chunk's records
    while data[at] != mcapscan.OP_MESSAGE:
        at += 9 + struct.unpack_from("<Q", data, at + 1)[0]
    return at


def test_a_message_record_shorter_than_its_head_is_one_line(tmp_path):
    path = tmp_path / "f.mcap"
    _write(path, indexed=False, compressed=False)
    data = bytearray(path.read_bytes())
    at = _first_message(data)
    length = struct.unpack_from("<Q", data, at + 1)[0]
    # a 10-byte message record, then a record of an unknown opcode filling the rest: the walk
    # stays aligned, the message's head is not all there
    struct.pack_into("<Q", data, at + 1, 10)
    data[at + 19] = 0x80
    struct.pack_into("<Q", data, at + 20, length - 10 - 9)
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"^bag 'f': .* has a corrupt message record$"):
        mcapscan.scan(str(path), {"/a", "/b"}, "f")


def test_a_record_overrunning_its_chunk_is_one_line(tmp_path):
    path = tmp_path / "f.mcap"
    _write(path, indexed=False, compressed=False)
    data = bytearray(path.read_bytes())
    at = _first_message(data)
    struct.pack_into("<Q", data, at + 1, 10 ** 6)       # runs past the chunk's records
    path.write_bytes(bytes(data))
    with pytest.raises(BagError, match=r"has a corrupt chunk \(records overrun it\)$"):
        mcapscan.scan(str(path), {"/a"}, "f")
