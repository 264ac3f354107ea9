"""The command line's error-model options of ``--model ins3d`` (``--vertical``,
``--latency/--no-latency``, ``--reference-markov``, ``--initial-attitude``): the analysis runs
with them (the numbers of ``analyze_ins3d`` called with them), each wins over the same key of
the bag's ``error_model`` block, ``run`` passes them to filter_node (its recording and the
result record them), and a bad value is one line (docs/ins3d.md, "The contract description")."""
from __future__ import annotations

import json
import math
import shutil
from dataclasses import replace
from pathlib import Path

import pytest
import yaml

from flight_fdi.bagio.ins3d_input import (ERROR_MODEL, error_model_options, error_model_used,
                                          model_options_with, read_ins3d)
from flight_fdi.cli.main import main
from flight_fdi.core.ins3d.analysis import analyze_ins3d
from flight_fdi.core.ins3d_result import ins3d_result
from flight_fdi.schema import validate_result

#: the bag's own block in (b) and (c): every key but initial_attitude
BLOCK = {"vertical": "damped", "latency": False, "reference_markov": None}


@pytest.fixture(scope="module")
def bags(tmp_path_factory):
    """{"plain": a 100-s simulated 3-D bag (description without a block), "block": a copy
    whose description has BLOCK}."""
    root = tmp_path_factory.mktemp("ins3d_opts")
    plain = root / "plain"
    assert main(["simulate", str(plain), "--model", "ins3d", "--duration", "100", "--seed",
                 "5", "--fault", "gyro:step:t=40,mag=30deg/h,axis=x"]) == 0
    return {"plain": plain, "block": _with_description(plain, root / "block",
                                                       {ERROR_MODEL: BLOCK})}


def _with_description(bag: Path, out: Path, changes: dict | None) -> Path:
    """A copy of ``bag`` whose description has ``changes`` (None: no description at all)."""
    shutil.copytree(bag, out)
    meta = out / "metadata.yaml"
    doc = yaml.safe_load(meta.read_text())
    custom = doc["rosbag2_bagfile_information"]["custom_data"]
    if changes is None:
        del custom["flight_fdi.sim3d"]
    else:
        custom["flight_fdi.sim3d"] = json.dumps({**json.loads(custom["flight_fdi.sim3d"]),
                                                 **changes})
    meta.write_text(yaml.safe_dump(doc))
    return out


def _cli(capsys, *argv: str) -> dict:
    assert main([*argv, "--model", "ins3d", "--json"]) in (0, 3)
    res = json.loads(capsys.readouterr().out)
    validate_result(res)
    return res


def _close(a, b, where="", rel=1e-9):
    """Equal structure and text, numbers to ``rel``."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), where
        for k in a:
            _close(a[k], b[k], f"{where}.{k}", rel)
    elif isinstance(a, list):
        assert isinstance(b, list) and len(a) == len(b), where
        for i, (x, y) in enumerate(zip(a, b)):
            _close(x, y, f"{where}[{i}]", rel)
    elif isinstance(a, float) and not isinstance(b, bool):
        assert b == pytest.approx(a, rel=rel, abs=1e-300) or (math.isnan(a) and math.isnan(b)), \
            where
    else:
        assert a == b, where


def _assert_same_analysis(res: dict, bag: Path, **options) -> None:
    """``res`` has the numbers of ``analyze_ins3d`` called directly with ``options``."""
    inp = read_ins3d(bag)
    direct = ins3d_result(analyze_ins3d(inp.steps, inp.refs, grade="navigation", rows=3,
                                        **options), str(bag))
    for key in ("in_flight", "post_flight", "ins3d", "samples", "duration_s", "channel"):
        _close(res[key], direct[key], key)


def test_an_option_gives_the_analysis_with_it(bags, capsys):
    """(a) ``--vertical free``: the numbers of analyze_ins3d(vertical="free") on the same input,
    and not those of the bag's own vertical channel (its baro loop)."""
    res = _cli(capsys, "analyze", str(bags["plain"]), "--vertical", "free")
    _assert_same_analysis(res, bags["plain"], vertical="free")
    assert res["source"]["error_model"] == {"vertical": "free", "latency": True,
                                            "reference_markov": [0.02, 0.03, 30.0],
                                            "initial_attitude": "levelled"}
    assert res["source"]["error_model_overrides"] == ["vertical"]
    before = _cli(capsys, "analyze", str(bags["plain"]))
    assert before["source"]["error_model"]["vertical"] == "loop"
    assert before["source"]["error_model_overrides"] == []
    # the baro loop's states (height error, its integral, the baro bias) are gone
    assert {"dh", "int_dh", "b_aid"} <= set(before["ins3d"]["states"])
    assert not {"dh", "int_dh", "b_aid"} & set(res["ins3d"]["states"])


def test_the_options_win_over_the_bags_block(bags, capsys):
    """(b) the bag's block says damped, no latency, no Markov noise; the command line changes
    two of them and adds the fourth, the block's third key stays."""
    bag = bags["block"]
    res = _cli(capsys, "analyze", str(bag))
    assert res["source"]["error_model"] == {**BLOCK, "initial_attitude": "levelled"}
    _assert_same_analysis(res, bag, vertical="damped", latency=False, ref_markov=None)
    res = _cli(capsys, "analyze", str(bag), "--vertical", "free", "--latency",
               "--initial-attitude", "independent")
    assert res["source"]["error_model"] == {"vertical": "free", "latency": True,
                                            "reference_markov": None,
                                            "initial_attitude": "independent"}
    assert res["source"]["error_model_overrides"] == ["vertical", "latency",
                                                      "initial_attitude"]
    _assert_same_analysis(res, bag, vertical="free", latency=True, ref_markov=None,
                          aligned_prior=False)
    main(["analyze", str(bag), "--model", "ins3d", "--vertical", "free", "--latency"])
    assert "(from the command line: vertical, latency)" in capsys.readouterr().out


def test_the_merge_keeps_the_rest(bags):
    """The merge itself: the description's baro loop stays for a loop channel only, and an
    input without a description keeps the analysis defaults (not the ``damped`` channel of a
    described non-baro INS) for the keys not given."""
    inp = read_ins3d(bags["plain"])
    assert "loop" in model_options_with(inp, {"latency": False})
    assert model_options_with(inp, {"vertical": "free"}) == {"vertical": "free"}
    bare = replace(inp, description=None)
    assert model_options_with(bare, {"latency": False}) == {"latency": False}
    assert model_options_with(bare, {}) == {} == bare.model_options()
    full = {"vertical": "damped", "latency": False, "ref_markov": (0.1, 0.2, 5.0),
            "aligned_prior": False}
    assert error_model_options({ERROR_MODEL: error_model_used(full)}) == full


def test_run_passes_the_options_to_the_nodes(bags, tmp_path, capfd):
    """(c) ``run`` with an override of the bag's block: filter_node runs with it (its recording
    holds it), the result records it and has analyze's numbers with it. (capfd: the pipeline
    needs a real stderr.)"""
    from flight_fdi.nodes.ins3d_recording import read_recording3d

    bag, out = bags["block"], tmp_path / "run"
    opts = ("--vertical", "free", "--reference-markov", "0.05,0.04,20")
    res = _cli(capfd, "run", str(bag), "--out", str(out), "--no-report", "--no-progress",
               *opts)
    assert read_recording3d(out / "recording")["options"] == {
        "vertical": "free", "latency": False, "ref_markov": (0.05, 0.04, 20.0),
        "aligned_prior": True}
    assert res["source"]["error_model"] == {"vertical": "free", "latency": False,
                                            "reference_markov": [0.05, 0.04, 20.0],
                                            "initial_attitude": "levelled"}
    assert res["source"]["error_model_overrides"] == ["vertical", "reference_markov"]
    ref = _cli(capfd, "analyze", str(bag), *opts)
    assert res["source"] == ref["source"]
    for key in ("in_flight", "ins3d", "samples"):
        _close(res[key], ref[key], key)
    assert res["post_flight"]["verdict"] == ref["post_flight"]["verdict"]
    # a report of the run folder draws what the recording holds: an option there is refused
    assert main(["report", str(out), "--model", "ins3d", "--out", str(tmp_path / "rep"),
                 "--no-latency"]) == 1
    err = capfd.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "is a run folder" in err[0]


def test_run_takes_the_vertical_channel_as_analyze_does(bags, tmp_path, capfd):
    """A bag whose description says the INS is not baro-aided and has no error_model block:
    ``analyze`` models its vertical channel as ``damped`` (``description_vertical``); ``run``
    gave filter_node its default ``loop`` (the two disagreed, sessions 12-13); now the same."""
    bag = _with_description(bags["plain"], tmp_path / "free", {"vertical": "free"})
    out = tmp_path / "run"
    res = _cli(capfd, "run", str(bag), "--out", str(out), "--no-report", "--no-progress")
    ref = _cli(capfd, "analyze", str(bag))
    assert ref["source"]["error_model"]["vertical"] == "damped"
    assert res["source"] == ref["source"]
    for key in ("in_flight", "ins3d", "samples"):
        _close(res[key], ref[key], key)
    assert res["post_flight"]["verdict"] == ref["post_flight"]["verdict"]


def test_a_result_json_is_reanalysed_with_its_overrides(bags):
    """``report RESULT.json`` takes the options the result was analysed with (only those the
    command line gave: the rest comes from the bag's block again); an option given wins."""
    import argparse

    from flight_fdi.cli.ins3d import error_model_block, settings_of_result

    used = {"vertical": "free", "latency": False, "reference_markov": [0.05, 0.04, 20.0],
            "initial_attitude": "levelled"}
    src = {"error_model": used, "error_model_overrides": ["vertical", "reference_markov"]}
    args = argparse.Namespace(grade=None, rows=None, ins_topic=None, imu_topic=None,
                              fix_topic=None, reference_topic=None, vertical="damped",
                              latency=None, reference_markov=None, initial_attitude=None)
    settings_of_result(args, src)
    assert error_model_block(args) == {"vertical": "damped",
                                       "reference_markov": [0.05, 0.04, 20.0]}


@pytest.mark.parametrize("argv, needle", [
    (["--vertical", "upside"], "--vertical 'upside': must be one of damped, free, loop"),
    (["--initial-attitude", "guessed"],
     "--initial-attitude 'guessed': must be one of levelled, independent"),
    (["--reference-markov", "0.02,0,30"], "--reference-markov '0.02,0,30': must be null or"),
    (["--reference-markov", "0.02,0.03"], "give SIGMA_H,SIGMA_V,TAU or none"),
    (["--reference-markov", "a,b,c"], "got ['a', 'b', 'c']"),
    (["--reference-markov", "inf,1,1"], "all > 0, got [inf, 1.0, 1.0]"),
])
def test_a_bad_value_is_one_line(bags, tmp_path, capsys, argv, needle):
    """(d) exit 1, one line naming the option, before the bag is read and before any node."""
    for cmd, extra in (("analyze", []), ("run", ["--out", str(tmp_path / "o")])):
        rc = main([cmd, str(bags["block"]), "--model", "ins3d", *extra, *argv])
        err = capsys.readouterr().err.strip().splitlines()
        assert rc == 1 and len(err) == 1 and needle in err[0], err
        assert err[0].startswith(f"flight-fdi {cmd}: error: ")
    assert not (tmp_path / "o").exists()


def test_the_options_need_the_3d_model_and_a_value(capsys):
    """(d) with the single-axis model: one line; a value after --latency: argparse, exit 2."""
    for argv in (["--vertical", "free"], ["--no-latency"], ["--reference-markov", "none"],
                 ["--initial-attitude", "levelled"]):
        assert main(["analyze", "bags/nominal", *argv]) == 1
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].endswith("applies only to --model ins3d"), err
    with pytest.raises(SystemExit) as exc:
        main(["analyze", "bags/nominal", "--model", "ins3d", "--latency=yes"])
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "Traceback" not in err and err.strip().splitlines()[-1].endswith(
        "argument --latency/--no-latency: ignored explicit argument 'yes'")


def test_the_help_names_the_checked_values_and_defaults():
    """--help shows the values the check accepts and analyze_ins3d's defaults."""
    import inspect

    from flight_fdi.bagio.ins3d_input import INITIAL_ATTITUDE
    from flight_fdi.cli.main import build_parser
    from flight_fdi.core.ins3d.model import VERTICAL

    sub = build_parser("analyze")._subparsers._group_actions[0].choices["analyze"]
    text = " ".join(sub.format_help().split())
    assert "{" + ",".join(VERTICAL) + "}" in text
    assert "{" + ",".join(INITIAL_ATTITUDE) + "}" in text
    mk = inspect.signature(analyze_ins3d).parameters["ref_markov"].default
    assert "else " + ",".join(f"{v:g}" for v in mk) + ")" in text
    assert inspect.signature(analyze_ins3d).parameters["latency"].default is True
    assert inspect.signature(analyze_ins3d).parameters["aligned_prior"].default is True
