"""Fuzzing bag reading: bytes of small valid bags are mutated and every reader is called.

Four simulated 30-s flights (mcap and sqlite3, with and without zstd) are written once. For
each example hypothesis draws edits of the storage file (a byte set, a bit flipped, bytes
overwritten -- e.g. a length field with 0xff.. --, inserted or deleted, the file truncated) or
of ``metadata.yaml``, applied to a copy; then ``read_flight``, ``read_messages`` (iterated to the
end) and ``flight-fdi analyze --json`` run in-process. The property: they
succeed, or fail with ``BagError`` carrying one sentence (one line); ``analyze`` exits 0, or 1
with one line on stderr (a ``BagError``, or the core's ``CoreError`` when the damaged bag still
reads but its data cannot be analysed). Never another exception.
"""
from __future__ import annotations

import contextlib
import io
import shutil
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from flight_fdi.bagio import BagError, bag_topics, read_flight, read_messages
from hardening import fuzzlib as fz

BAGS = [("mcap", "none"), ("mcap", "zstd"), ("sqlite3", "none"), ("sqlite3", "zstd")]


@pytest.fixture(scope="module")
def bags(tmp_path_factory) -> dict:
    from flight_fdi.cli.main import main

    root = tmp_path_factory.mktemp("fuzz_bags")
    out = {}
    for storage, compression in BAGS:
        path = root / f"{storage}_{compression}"
        assert main(["simulate", str(path), "--duration", "30", "--ins-rate", "10",
                     "--ref-rate", "2", "--truth-rate", "1", "--seed", "3", "--storage", storage,
                     "--compression", compression, "--fault",
                     "accel:step:t=15,mag=0.05"]) == 0
        data = next(p for p in path.iterdir() if p.suffix in (".mcap", ".db3"))
        out[(storage, compression)] = (path, data.name, data.stat().st_size)
    return out


edit = st.one_of(
    st.tuples(st.just("set"), st.floats(0, 1, exclude_max=True), st.integers(0, 255)),
    st.tuples(st.just("flip"), st.floats(0, 1, exclude_max=True), st.integers(0, 7)),
    st.tuples(st.just("write"), st.floats(0, 1, exclude_max=True),
              st.one_of(st.binary(min_size=1, max_size=16),
                        st.sampled_from([b"\xff" * 8, b"\x00" * 8, b"\xff\xff\xff\x7f",
                                         b"\x00\x00\x00\x80", b"\x01" + b"\x00" * 7]))),
    st.tuples(st.just("insert"), st.floats(0, 1, exclude_max=True), st.binary(min_size=1,
                                                                             max_size=64)),
    st.tuples(st.just("delete"), st.floats(0, 1, exclude_max=True), st.integers(1, 64)),
    st.tuples(st.just("truncate"), st.floats(0, 1, exclude_max=True), st.just(0)),
)
damage = st.tuples(st.sampled_from(["data"] * 9 + ["metadata.yaml"]),
                   st.lists(edit, min_size=1, max_size=6))


def mutate(blob: bytes, edits) -> bytes:
    b = bytearray(blob)
    for kind, where, arg in edits:
        if not b:
            break
        i = int(where * len(b))
        if kind == "set":
            b[i] = arg
        elif kind == "flip":
            b[i] ^= 1 << arg
        elif kind == "write":
            b[i:i + len(arg)] = arg
        elif kind == "insert":
            b[i:i] = arg
        elif kind == "delete":
            del b[i:i + arg]
        elif kind == "truncate":
            del b[i:]
    return bytes(b)


def one_sentence(exc: BaseException) -> None:
    text = str(exc)
    assert text and "\n" not in text, f"not one line: {text!r}"


def read_everything(path: Path) -> bool:
    """The readers on ``path`` (each opens the bag anew): success or BagError (one line),
    nothing else. True when ``read_flight`` succeeded."""
    ok = True
    for call in (lambda: read_flight(path, channel="x"),
                 lambda: sum(1 for _ in read_messages(path))):
        try:
            call()
        except BagError as exc:
            one_sentence(exc)
            ok = False
    return ok


def analyze(path: Path) -> None:
    from flight_fdi.cli.main import main

    err = io.StringIO()
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(err):
        code = main(["analyze", str(path), "--json"])
    lines = err.getvalue().strip().splitlines()
    if code == 0:
        return
    assert code == 1 and len(lines) == 1 and lines[0].startswith("flight-fdi analyze: error: "), \
        (code, err.getvalue())


@pytest.mark.parametrize("storage, compression", BAGS)
def test_damaged_bags_fail_with_one_bag_error_or_read(bags, tmp_path, storage, compression):
    src, data_name, _ = bags[(storage, compression)]
    assert read_everything(src) and bag_topics(src)  # the undamaged bag reads
    outcomes = {"read": 0, "error": 0}

    @settings(max_examples=30, **fz.SETTINGS)
    @given(damage)
    def run(d):
        target, edits = d
        bag = tmp_path / "bag"
        if bag.exists():
            shutil.rmtree(bag)
        shutil.copytree(src, bag)
        name = data_name if target == "data" else target
        (bag / name).write_bytes(mutate((bag / name).read_bytes(), edits))
        outcomes["read" if read_everything(bag) else "error"] += 1
        analyze(bag)

    run()
    assert outcomes["error"] > 0  # the damage was noticed at least sometimes
