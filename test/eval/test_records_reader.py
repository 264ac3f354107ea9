"""read_records: the one reader of a study's records file (RecordsFile resumes from it, the
evaluation tools render partial studies from it)."""
from __future__ import annotations

import json

import pytest

from flight_fdi.eval.errors import EvalError
from flight_fdi.eval.records import RecordsFile, read_records


def test_reads_the_header_and_complete_records_and_drops_a_cut_line(tmp_path):
    path = tmp_path / "r.jsonl"
    with RecordsFile(path, {"seed": 3}) as rec:
        rec.write({"index": 4, "x": 1.5})
        rec.write({"index": 0, "x": -2.0})
    with path.open("a") as f:
        f.write('{"index": 7, "x"')                   # a line cut while it was written
    study, records = read_records(path)
    assert study == {"seed": 3}
    assert records == [{"index": 4, "x": 1.5}, {"index": 0, "x": -2.0}]
    with RecordsFile(path, {"seed": 3}) as rec:         # resuming truncates the cut line
        assert set(rec.done) == {4, 0}
    assert path.read_text().endswith('"x": -2.0}\n')


def test_a_file_that_is_not_a_records_file_is_an_error(tmp_path):
    path = tmp_path / "r.jsonl"
    path.write_text(json.dumps({"index": 1}) + "\n")
    with pytest.raises(EvalError, match="not a study records file"):
        read_records(path)
    path.write_text(json.dumps({"records": "flight_fdi.study/1", "study": {}}) + "\n{oops\n")
    with pytest.raises(EvalError, match="line 2 .* not JSON"):
        read_records(path)
